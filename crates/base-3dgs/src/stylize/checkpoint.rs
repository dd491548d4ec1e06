//! Checkpoints of a stylization run in `<out>/checkpoint/`: the parameters (`gaussians.ply`),
//! the optimizer state (`adam.bin`), and in `state.json` the step, the exact position of the
//! patch stream, the resolved configuration and the losses so far. A checkpoint is written into
//! a fresh folder that then replaces the previous one, so a crash leaves the old one whole.

use std::path::{Path, PathBuf};

use gs_core::GaussianSet;
use rand_chacha::rand_core::SeedableRng;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use style_loss::StyleRng;

use super::outputs::{read_json, write_atomic, write_json, StepLosses};
use super::StylizeError;
use gs_core::ply::{read_ply, write_ply, PlyFormat, PlyGaussians};

/// The checkpoint folder inside the output folder.
pub const CHECKPOINT_DIR: &str = "checkpoint";
const PARAMS: &str = "gaussians.ply";
const ADAM: &str = "adam.bin";
const STATE: &str = "state.json";

/// Configuration fields that may change when a run is resumed: they do not change the
/// trajectory of the parameters (`out` may be spelled differently; the checkpoint is in it).
pub const RESUMABLE_CHANGES: [&str; 4] = ["steps", "checkpoint_every", "preview_views", "out"];

/// Everything needed to continue a run exactly where it stopped.
#[derive(Clone, Debug)]
pub struct Checkpoint {
    /// Steps taken.
    pub step: u64,
    /// The parameters after `step` steps.
    pub gaussians: GaussianSet,
    /// [`gs_core::adam::Adam::save_state`] bytes.
    pub adam_state: Vec<u8>,
    /// The patch stream, positioned after `step` steps.
    pub rng: StyleRng,
    /// The resolved configuration of the run, as JSON.
    pub config: Value,
    /// The losses of steps `1..=step`.
    pub losses: Vec<StepLosses>,
}

/// The position of a ChaCha8 stream: seed, stream and word position.
#[derive(Serialize, Deserialize)]
struct RngState {
    /// The 32-byte seed, hexadecimal.
    seed: String,
    stream: u64,
    /// The word position (a u128), decimal.
    word_pos: String,
}

#[derive(Serialize, Deserialize)]
struct State {
    step: u64,
    rng: RngState,
    config: Value,
    losses: Vec<StepLosses>,
}

/// The checkpoint folder of the output folder `out`.
pub fn checkpoint_dir(out: &Path) -> PathBuf {
    out.join(CHECKPOINT_DIR)
}

/// Where [`save`] parks the previous checkpoint while it moves the new one in.
fn parked_dir(out: &Path) -> PathBuf {
    out.join(format!("{CHECKPOINT_DIR}.old"))
}

/// Puts back a checkpoint that a save interrupted between its two renames (a crash or a second
/// Ctrl-C) left only in the parked folder, so it is found again. Call before looking for one.
pub fn recover_interrupted_save(out: &Path) -> Result<(), StylizeError> {
    let (dir, old) = (checkpoint_dir(out), parked_dir(out));
    if !dir.exists() && old.exists() {
        std::fs::rename(&old, &dir).map_err(|source| StylizeError::Io { path: old, source })?;
    }
    Ok(())
}

/// Saves `checkpoint` into `<out>/checkpoint/`, replacing the previous one only once the new
/// one is complete.
pub fn save(out: &Path, checkpoint: &Checkpoint) -> Result<(), StylizeError> {
    recover_interrupted_save(out)?;
    let dir = checkpoint_dir(out);
    let tmp = out.join(format!("{CHECKPOINT_DIR}.tmp"));
    let old = parked_dir(out);
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| StylizeError::Io { path, source }
    };
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(io(&tmp))?;
    }
    std::fs::create_dir_all(&tmp).map_err(io(&tmp))?;
    write_ply(
        &tmp.join(PARAMS),
        &PlyGaussians::new(checkpoint.gaussians.clone()),
        PlyFormat::BinaryLittleEndian,
    )?;
    write_atomic(&tmp.join(ADAM), &checkpoint.adam_state)?;
    let rng = &checkpoint.rng;
    let state = State {
        step: checkpoint.step,
        rng: RngState {
            seed: rng.get_seed().iter().map(|b| format!("{b:02x}")).collect(),
            stream: rng.get_stream(),
            word_pos: rng.get_word_pos().to_string(),
        },
        config: checkpoint.config.clone(),
        losses: checkpoint.losses.clone(),
    };
    write_json(&tmp.join(STATE), &state)?;
    if dir.exists() {
        if old.exists() {
            std::fs::remove_dir_all(&old).map_err(io(&old))?;
        }
        std::fs::rename(&dir, &old).map_err(io(&dir))?;
    }
    std::fs::rename(&tmp, &dir).map_err(io(&dir))?;
    if old.exists() {
        std::fs::remove_dir_all(&old).map_err(io(&old))?;
    }
    Ok(())
}

/// Loads the checkpoint in `<out>/checkpoint/` (after [`recover_interrupted_save`]).
pub fn load(out: &Path) -> Result<Checkpoint, StylizeError> {
    recover_interrupted_save(out)?;
    let dir = checkpoint_dir(out);
    let bad = |message: String| StylizeError::Checkpoint {
        path: dir.clone(),
        message,
    };
    if !dir.join(STATE).is_file() {
        return Err(bad(format!(
            "no {STATE}: there is no checkpoint to resume from (run without --resume)"
        )));
    }
    let state: State = read_json(&dir.join(STATE))?;
    let adam_state = std::fs::read(dir.join(ADAM)).map_err(|source| StylizeError::Io {
        path: dir.join(ADAM),
        source,
    })?;
    let gaussians = read_ply(&dir.join(PARAMS))?.gaussians;
    let seed = decode_seed(&state.rng.seed).ok_or_else(|| bad("bad rng seed".into()))?;
    let word_pos: u128 = state
        .rng
        .word_pos
        .parse()
        .map_err(|e| bad(format!("bad rng word position: {e}")))?;
    let mut rng = StyleRng::from_seed(seed);
    rng.set_stream(state.rng.stream);
    rng.set_word_pos(word_pos);
    if state.losses.len() as u64 != state.step {
        return Err(bad(format!(
            "{} logged losses for {} steps",
            state.losses.len(),
            state.step
        )));
    }
    Ok(Checkpoint {
        step: state.step,
        gaussians,
        adam_state,
        rng,
        config: state.config,
        losses: state.losses,
    })
}

fn decode_seed(hex: &str) -> Option<[u8; 32]> {
    if hex.len() != 64 {
        return None;
    }
    let mut seed = [0u8; 32];
    for (i, byte) in seed.iter_mut().enumerate() {
        *byte = u8::from_str_radix(hex.get(2 * i..2 * i + 2)?, 16).ok()?;
    }
    Some(seed)
}

/// The fields, other than [`RESUMABLE_CHANGES`], whose values differ between the saved and the
/// current configuration (both JSON objects), sorted.
pub fn changed_fields(saved: &Value, current: &Value) -> Vec<String> {
    let empty = serde_json::Map::new();
    let saved = saved.as_object().unwrap_or(&empty);
    let current = current.as_object().unwrap_or(&empty);
    let mut keys: Vec<&String> = saved.keys().chain(current.keys()).collect();
    keys.sort();
    keys.dedup();
    keys.into_iter()
        .filter(|k| !RESUMABLE_CHANGES.contains(&k.as_str()))
        .filter(|k| saved.get(*k) != current.get(*k))
        .cloned()
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand_chacha::rand_core::RngCore;

    #[test]
    fn the_patch_stream_position_round_trips_exactly() {
        let dir = std::env::temp_dir().join(format!("stylize-ckpt-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut rng = style_loss::style_rng(5);
        for _ in 0..37 {
            rng.next_u32();
        }
        let checkpoint = Checkpoint {
            step: 1,
            gaussians: GaussianSet::zeros(3, 1),
            adam_state: vec![1, 2, 3],
            rng: rng.clone(),
            config: serde_json::json!({"steps": 4}),
            losses: vec![StepLosses {
                step: 1,
                view: 0,
                total: 0.5,
                terms: [("patch".to_string(), 0.5)].into(),
            }],
        };
        save(&dir, &checkpoint).unwrap();
        save(&dir, &checkpoint).unwrap();
        let mut back = load(&dir).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(back.step, 1);
        assert_eq!(back.gaussians, checkpoint.gaussians);
        assert_eq!(back.adam_state, vec![1, 2, 3]);
        assert_eq!(back.losses, checkpoint.losses);
        let expected: Vec<u32> = (0..10).map(|_| rng.next_u32()).collect();
        let got: Vec<u32> = (0..10).map(|_| back.rng.next_u32()).collect();
        assert_eq!(got, expected);
    }

    #[test]
    fn changed_fields_ignore_the_step_count_and_name_the_rest() {
        let saved = serde_json::json!({"steps": 10, "seed": 1, "feature_lr": 0.01});
        let current = serde_json::json!({"steps": 20, "seed": 2, "feature_lr": 0.01});
        assert_eq!(changed_fields(&saved, &current), ["seed"]);
    }
}
