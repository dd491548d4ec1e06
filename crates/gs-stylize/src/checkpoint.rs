//! Checkpoints of a stylization run in `<out>/checkpoint/`: the model's parameter groups
//! (`params.bin`), the optimizer state (`adam.bin`), and in `state.json` the step, the exact
//! position of the patch stream, the resolved configuration and the losses so far. A checkpoint
//! is written into a fresh folder that then replaces the previous one, so a crash leaves the old
//! one whole.
//!
//! A run that took all its steps saves a last checkpoint of the final step; once the modality
//! has written its outputs it marks the checkpoint finished ([`mark_finished`], a file
//! `finished` holding the step). A finished checkpoint does not hold the output folder: a new
//! run may start there (and discards it, [`discard_finished`]), and resuming it continues only
//! with more steps than it took.
//!
//! `params.bin`, little-endian: the magic `GSPARAMS`, a `u32` version (1), a `u32` group count,
//! then per group a `u32` name length, the UTF-8 name, a `u64` value count and the `f32` values.

use std::io::Write;
use std::path::{Path, PathBuf};

use gs_core::model::BaseModel;
use rand_chacha::rand_core::SeedableRng;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use style_loss::StyleRng;

use crate::outputs::{read_json, write_atomic, write_json, StepLosses};
use crate::StylizeError;

/// The checkpoint folder inside the output folder.
pub const CHECKPOINT_DIR: &str = "checkpoint";
const PARAMS: &str = "params.bin";
const ADAM: &str = "adam.bin";
const STATE: &str = "state.json";
const FINISHED: &str = "finished";
const PARAMS_MAGIC: &[u8; 8] = b"GSPARAMS";
const PARAMS_VERSION: u32 = 1;

/// Configuration fields that may change when a run is resumed: they do not change the
/// trajectory of the parameters (`device` only within float rounding: a checkpoint of either
/// device resumes on the other). `out` (the output folder, which holds the checkpoint, may be
/// spelled differently) and `preview_views` are the modalities' names of those fields.
pub const RESUMABLE_CHANGES: [&str; 7] = [
    "steps",
    "checkpoint_every",
    "preview_every",
    "preview_views",
    "out",
    "device",
    "view_cache_mb",
];

/// One parameter group of a model ([`BaseModel::group_names`] and its values).
#[derive(Clone, Debug, PartialEq)]
pub struct ParamGroup {
    /// The group name.
    pub name: String,
    /// Its values.
    pub values: Vec<f32>,
}

/// Everything needed to continue a run exactly where it stopped.
#[derive(Clone, Debug)]
pub struct Checkpoint {
    /// Steps taken.
    pub step: u64,
    /// The model's parameter groups after `step` steps, in [`BaseModel::group_names`] order.
    pub params: Vec<ParamGroup>,
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

/// The parameter groups of `model`, copied (mutable access is how [`BaseModel`] lends them).
pub fn model_params<M: BaseModel>(model: &M) -> Vec<ParamGroup> {
    model
        .groups()
        .into_iter()
        .map(|group| ParamGroup {
            name: group.name.to_string(),
            values: group.values.to_vec(),
        })
        .collect()
}

/// Copies `params` into `model` when it has the same groups (names and lengths; each saved group
/// goes to the model's group of its name, in whatever order they were saved);
/// otherwise changes nothing and returns every difference, named.
pub fn restore_params<M: BaseModel>(model: &mut M, params: &[ParamGroup]) -> Result<(), String> {
    let names = model.group_names();
    let saved: Vec<&str> = params.iter().map(|p| p.name.as_str()).collect();
    let model_names: Vec<&str> = names.iter().map(String::as_str).collect();
    if sorted(&saved) != sorted(&model_names) {
        return Err(format!(
            "parameter groups [{}], the model has [{}]",
            saved.join(", "),
            names.join(", ")
        ));
    }
    let by_name = |name: &str| {
        params
            .iter()
            .find(|p| p.name == name)
            .expect("the names were compared")
    };
    let differ: Vec<String> = names
        .iter()
        .zip(model.group_lens())
        .map(|(name, len)| (by_name(name), len))
        .filter(|(p, len)| p.values.len() != *len)
        .map(|(p, len)| format!("{} has {} values, the model {len}", p.name, p.values.len()))
        .collect();
    if !differ.is_empty() {
        return Err(differ.join("; "));
    }
    for (dst, name) in model.groups_mut().into_iter().zip(&names) {
        dst.copy_from_slice(&by_name(name).values);
    }
    Ok(())
}

/// `list`, sorted.
fn sorted<'a>(list: &[&'a str]) -> Vec<&'a str> {
    let mut list = list.to_vec();
    list.sort_unstable();
    list
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
/// one is complete (the new one is not [finished](mark_finished)).
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
    let written = write_files(&tmp, checkpoint);
    if written.is_err() {
        // A full disk, say: no half-written checkpoint is left beside the last good one.
        let _ = std::fs::remove_dir_all(&tmp);
    }
    written?;
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

/// Writes the files of `checkpoint` into the folder `dir`.
fn write_files(dir: &Path, checkpoint: &Checkpoint) -> Result<(), StylizeError> {
    let params = dir.join(PARAMS);
    gs_core::fs::write_atomic_with(&params, |w| write_params(w, &checkpoint.params)).map_err(
        |source| StylizeError::Io {
            path: params.clone(),
            source,
        },
    )?;
    write_atomic(&dir.join(ADAM), &checkpoint.adam_state)?;
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
    write_json(&dir.join(STATE), &state)
}

/// The step at which the run of `out` finished, when its checkpoint is marked finished
/// ([`mark_finished`]: the file `finished` whose first line is the step); `None` when there is
/// no checkpoint or it is not finished.
pub fn finished_step(out: &Path) -> Option<u64> {
    let text = std::fs::read_to_string(checkpoint_dir(out).join(FINISHED)).ok()?;
    text.lines().next()?.trim().parse().ok()
}

/// Marks the checkpoint of `out`, saved at `step`, as that of a finished run, once its outputs
/// are written (see the module documentation). Nothing happens when there is no checkpoint (a
/// run with `checkpoint_every = 0`).
pub fn mark_finished(out: &Path, step: u64) -> Result<(), StylizeError> {
    let dir = checkpoint_dir(out);
    if !dir.is_dir() {
        return Ok(());
    }
    let text = format!("{step}\nthe run finished at this step and wrote its outputs\n");
    write_atomic(&dir.join(FINISHED), text.as_bytes())
}

/// Removes the checkpoint of `out` when it is [finished](mark_finished): a new run in `out`
/// must not leave a finished checkpoint of an earlier run beside its own outputs. An
/// unfinished checkpoint is kept.
pub fn discard_finished(out: &Path) -> Result<(), StylizeError> {
    let dir = checkpoint_dir(out);
    if finished_step(out).is_some() {
        std::fs::remove_dir_all(&dir).map_err(|source| StylizeError::Io { path: dir, source })?;
    }
    Ok(())
}

/// Loads the checkpoint in `<out>/checkpoint/` (after [`recover_interrupted_save`]); whether
/// its parameters fit a model is [`restore_params`]'s check.
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
    let read = |name: &str| {
        std::fs::read(dir.join(name)).map_err(|source| StylizeError::Io {
            path: dir.join(name),
            source,
        })
    };
    let adam_state = read(ADAM)?;
    let params = read_params(&read(PARAMS)?).map_err(|e| bad(format!("{PARAMS}: {e}")))?;
    let seed = decode_seed(&state.rng.seed).ok_or_else(|| {
        bad(format!(
            "{STATE}: the rng seed is not 64 hexadecimal digits"
        ))
    })?;
    let word_pos: u128 = state
        .rng
        .word_pos
        .parse()
        .map_err(|e| bad(format!("{STATE}: bad rng word position: {e}")))?;
    let mut rng = StyleRng::from_seed(seed);
    rng.set_stream(state.rng.stream);
    rng.set_word_pos(word_pos);
    if state.losses.len() as u64 != state.step {
        return Err(bad(format!(
            "{STATE}: {} logged losses for {} steps",
            state.losses.len(),
            state.step
        )));
    }
    Ok(Checkpoint {
        step: state.step,
        params,
        adam_state,
        rng,
        config: state.config,
        losses: state.losses,
    })
}

/// Writes `params` in the `params.bin` layout (see the module documentation).
fn write_params(w: &mut impl Write, params: &[ParamGroup]) -> std::io::Result<()> {
    w.write_all(PARAMS_MAGIC)?;
    w.write_all(&PARAMS_VERSION.to_le_bytes())?;
    w.write_all(&(params.len() as u32).to_le_bytes())?;
    for p in params {
        w.write_all(&(p.name.len() as u32).to_le_bytes())?;
        w.write_all(p.name.as_bytes())?;
        w.write_all(&(p.values.len() as u64).to_le_bytes())?;
        for v in &p.values {
            w.write_all(&v.to_le_bytes())?;
        }
    }
    Ok(())
}

/// The next `n` bytes of `rest`, or an error saying they were cut off in `what`.
fn take<'a>(rest: &mut &'a [u8], n: usize, what: &str) -> Result<&'a [u8], String> {
    if rest.len() < n {
        return Err(format!("truncated in {what}"));
    }
    let (head, tail) = rest.split_at(n);
    *rest = tail;
    Ok(head)
}

/// Reads the `params.bin` layout; an error says what is wrong where.
fn read_params(bytes: &[u8]) -> Result<Vec<ParamGroup>, String> {
    let mut rest = bytes;
    let r = &mut rest;
    if take(r, PARAMS_MAGIC.len(), "the magic")? != PARAMS_MAGIC {
        return Err("not a parameter file (no GSPARAMS magic)".into());
    }
    let u32_at = |b: &[u8]| u32::from_le_bytes(b.try_into().expect("4 bytes"));
    let version = u32_at(take(r, 4, "the version")?);
    if version != PARAMS_VERSION {
        return Err(format!(
            "version {version}, this build reads {PARAMS_VERSION}"
        ));
    }
    let count = u32_at(take(r, 4, "the group count")?);
    let mut params = Vec::new();
    for g in 0..count {
        let name_len = u32_at(take(r, 4, &format!("group {g}"))?) as usize;
        let name = String::from_utf8(take(r, name_len, &format!("group {g}'s name"))?.to_vec())
            .map_err(|_| format!("group {g}'s name is not UTF-8"))?;
        let len = u64::from_le_bytes(take(r, 8, &name)?.try_into().expect("8 bytes"));
        let size = usize::try_from(len)
            .ok()
            .and_then(|n| n.checked_mul(4))
            .ok_or_else(|| format!("{name}: {len} values is too many"))?;
        let values = take(r, size, &name)?
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
            .collect();
        params.push(ParamGroup { name, values });
    }
    if !rest.is_empty() {
        return Err(format!("{} bytes after the last group", rest.len()));
    }
    Ok(params)
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

/// Configuration fields added after checkpoints were first written, with the value that runs as
/// the earlier versions ran: a saved configuration without the field matches that value.
pub const ADDED_FIELDS: [(&str, &str); 1] = [("vgg_precision", "f32")];

/// The fields, other than [`RESUMABLE_CHANGES`], whose values differ between the saved and the
/// current configuration (both JSON objects), sorted. A field of [`ADDED_FIELDS`] that the saved
/// configuration lacks counts as its earlier value.
pub fn changed_fields(saved: &Value, current: &Value) -> Vec<String> {
    let empty = serde_json::Map::new();
    let saved = saved.as_object().unwrap_or(&empty);
    let current = current.as_object().unwrap_or(&empty);
    let mut keys: Vec<&String> = saved.keys().chain(current.keys()).collect();
    keys.sort();
    keys.dedup();
    keys.into_iter()
        .filter(|k| !RESUMABLE_CHANGES.contains(&k.as_str()))
        .filter(|k| {
            let earlier = ADDED_FIELDS
                .iter()
                .find(|(name, _)| name == k)
                .map(|(_, value)| Value::String(value.to_string()));
            let saved = saved.get(*k).cloned().or(earlier);
            saved.as_ref() != current.get(*k)
        })
        .cloned()
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use gs_core::model::BaseModel;
    use gs_core::GaussianSet;
    use rand_chacha::rand_core::RngCore;

    #[test]
    fn parameters_and_the_patch_stream_position_round_trip_exactly() {
        let dir = tempfile::tempdir().unwrap();
        let mut rng = style_loss::style_rng(5);
        for _ in 0..37 {
            rng.next_u32();
        }
        let mut model = GaussianSet::zeros(3, 1);
        model.means[4] = -1.5e-7;
        model.sh_rest[2] = f32::MAX;
        let checkpoint = Checkpoint {
            step: 1,
            params: model_params(&model),
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
        save(dir.path(), &checkpoint).unwrap();
        save(dir.path(), &checkpoint).unwrap();
        let mut back = load(dir.path()).unwrap();
        assert_eq!(back.step, 1);
        assert_eq!(back.params, checkpoint.params);
        let mut restored = GaussianSet::zeros(3, 1);
        restore_params(&mut restored, &back.params).unwrap();
        assert_eq!(restored, model);
        assert_eq!(back.adam_state, vec![1, 2, 3]);
        assert_eq!(back.losses, checkpoint.losses);
        let expected: Vec<u32> = (0..10).map(|_| rng.next_u32()).collect();
        let got: Vec<u32> = (0..10).map(|_| back.rng.next_u32()).collect();
        assert_eq!(got, expected);

        let params = checkpoint_dir(dir.path()).join(PARAMS);
        let mut bytes = std::fs::read(&params).unwrap();
        bytes.pop();
        std::fs::write(&params, bytes).unwrap();
        let e = load(dir.path()).unwrap_err().to_string();
        assert!(e.contains("params.bin") && e.contains("truncated"), "{e}");
    }

    #[test]
    fn a_finished_mark_names_the_step_and_a_new_save_clears_it() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path();
        mark_finished(out, 3).unwrap();
        assert!(
            !checkpoint_dir(out).exists(),
            "no checkpoint, nothing to mark"
        );
        let checkpoint = Checkpoint {
            step: 3,
            params: model_params(&GaussianSet::zeros(2, 0)),
            adam_state: Vec::new(),
            rng: style_loss::style_rng(1),
            config: serde_json::json!({}),
            losses: Vec::new(),
        };
        let losses: Vec<StepLosses> = (1..=3)
            .map(|step| StepLosses {
                step,
                view: 0,
                total: 1.0,
                terms: Default::default(),
            })
            .collect();
        let checkpoint = Checkpoint {
            losses,
            ..checkpoint
        };
        save(out, &checkpoint).unwrap();
        assert_eq!(finished_step(out), None);
        discard_finished(out).unwrap();
        assert!(
            checkpoint_dir(out).exists(),
            "an unfinished checkpoint stays"
        );
        mark_finished(out, 3).unwrap();
        assert_eq!(finished_step(out), Some(3));
        assert_eq!(load(out).unwrap().step, 3);
        save(out, &checkpoint).unwrap();
        assert_eq!(finished_step(out), None, "a new save is not finished");
        mark_finished(out, 3).unwrap();
        discard_finished(out).unwrap();
        assert!(!checkpoint_dir(out).exists());
    }

    #[test]
    fn parameters_of_another_model_are_refused_with_the_differences_named() {
        let params = model_params(&GaussianSet::zeros(3, 1));
        let mut other = GaussianSet::zeros(4, 1);
        let before = other.clone();
        let e = restore_params(&mut other, &params).unwrap_err();
        assert!(
            e.contains("means has 9 values, the model 12") && e.contains("sh_rest"),
            "{e}"
        );
        assert_eq!(other, before);
        let e = restore_params(&mut other, &params[1..]).unwrap_err();
        assert!(
            e.contains("[scales,") && e.contains("[means, scales"),
            "{e}"
        );
    }

    /// Saved groups find the model's groups by name, in whatever order they were saved.
    #[test]
    fn parameters_saved_in_another_order_restore_by_name() {
        let mut source = GaussianSet::zeros(3, 1);
        for (i, group) in source.groups_mut().into_iter().enumerate() {
            group.fill(i as f32 + 1.0);
        }
        let mut params = model_params(&source);
        params.reverse();
        let mut restored = GaussianSet::zeros(3, 1);
        restore_params(&mut restored, &params).unwrap();
        assert_eq!(restored, source);
    }

    #[test]
    fn changed_fields_ignore_the_step_count_and_name_the_rest() {
        let saved = serde_json::json!({"steps": 10, "seed": 1, "feature_lr": 0.01});
        let current = serde_json::json!({"steps": 20, "seed": 2, "feature_lr": 0.01});
        assert_eq!(changed_fields(&saved, &current), ["seed"]);
    }

    #[test]
    fn a_checkpoint_saved_before_a_field_was_added_resumes_with_its_earlier_value() {
        let saved = serde_json::json!({"steps": 10, "clip_precision": "f32"});
        let current =
            serde_json::json!({"steps": 10, "clip_precision": "f32", "vgg_precision": "f32"});
        assert!(changed_fields(&saved, &current).is_empty());
        let current =
            serde_json::json!({"steps": 10, "clip_precision": "f32", "vgg_precision": "bf16"});
        assert_eq!(changed_fields(&saved, &current), ["vgg_precision"]);
        // A field that is not new is still a change when it is missing.
        let current = serde_json::json!({"steps": 10, "clip_precision": "f32", "seed": 0});
        assert_eq!(changed_fields(&saved, &current), ["seed"]);
    }
}
