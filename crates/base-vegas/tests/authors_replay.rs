//! `clipgaussian-video stylize` against a float64 replay of the authors' video loop
//! (`scripts/make_video_replay_fixture.py`: CLIPGaussian's `Video/train_style.py` on VeGaS, with
//! INRIA's rasterizer transcribed in PyTorch), on a 3-frame clip with partly transparent pixels
//! and a model whose renders exceed 1 (the video loop does not clamp them).
//!
//! The replay takes this run's random draws (the view and the patch crops and warps of every
//! update, `draws.json`) and its text direction; everything else (frames and mirrors, cameras,
//! frame times, the folded Gaussians of each frame, render, losses, Adam on the colours) is the
//! authors'. After 1 and 10 updates the colours must agree to float32 noise, no Gaussian's
//! colour may be moved by one side and left in place by the other (named in the failure), and
//! every other group must not have moved; on two clips, the second with Gaussians past the
//! frame's right and bottom edges that INRIA's rasterizer still draws.

use std::path::{Path, PathBuf};

use base_vegas::folded::FoldedGaussians;
use base_vegas::model_file::read_model;
use base_vegas::stylize::{run, VideoStylizeConfig};
use candle_core::{DType, Device};
use gs_stylize::test_support::{
    assert_replay_draws, moved_by_one_side, replay_draws, replay_settings, save_replay_draws,
    update_error,
};
use gs_stylize::{RunOptions, StyleSettings};
use serde_json::Value;
use style_loss::test_models::{write_tiny_models, TinyModelFiles};

/// The run's seed, and what its draws depend on: views (3 frames and their mirrors), frame
/// size, patches, updates.
const SEED: u64 = 5;
const VIEWS: usize = 6;
const UPDATES: u64 = 10;

/// The replayed scenes: fixture folder, frame width and height. The second has Gaussians past
/// the frame's right and bottom edges that INRIA's rasterizer still draws, and partial tiles.
const SCENES: [(&str, usize, usize); 2] =
    [("authors_replay", 64, 48), ("authors_replay_edges", 70, 52)];

fn replay_dir(folder: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(folder)
}

fn settings(tiny: &TinyModelFiles) -> StyleSettings {
    replay_settings(StyleSettings::paper_video(), tiny, SEED, UPDATES)
}

/// Writes `draws.json`, the input of `scripts/make_video_replay_fixture.py`; run it (with
/// `--ignored`) when the random streams change, then the script.
#[test]
#[ignore = "writes the replay's input; run by hand before scripts/make_video_replay_fixture.py"]
fn write_replay_draws() {
    let dir = tempfile::tempdir().unwrap();
    let tiny = write_tiny_models(dir.path());
    for (folder, width, height) in SCENES {
        let draws = replay_draws(&settings(&tiny), VIEWS, height, width);
        save_replay_draws(&replay_dir(folder), &draws);
    }
}

#[test]
fn the_replay_used_this_runs_draws() {
    let dir = tempfile::tempdir().unwrap();
    let tiny = write_tiny_models(dir.path());
    for (folder, width, height) in SCENES {
        assert_replay_draws(
            &replay_dir(folder).join("draws.json"),
            &replay_draws(&settings(&tiny), VIEWS, height, width),
            "regenerate the replay (cargo test -p base-vegas --test authors_replay -- --ignored \
             write_replay_draws, then scripts/make_video_replay_fixture.py)",
        );
    }
}

/// Stylizes the clip of the fixture in `data` with its model for `updates` updates.
fn our_run(data: &Path, updates: u64, out: PathBuf, tiny: &TinyModelFiles) -> FoldedGaussians {
    let config = VideoStylizeConfig {
        video: Some(data.join("frames")),
        model: Some(data.join("model.ply")),
        out: Some(out),
        style: StyleSettings {
            steps: updates,
            ..settings(tiny)
        },
        ..VideoStylizeConfig::default()
    };
    run(&config, &RunOptions::default()).unwrap().model
}

#[test]
fn the_run_ends_where_the_authors_loop_ends() {
    let dir = tempfile::tempdir().unwrap();
    let tiny = write_tiny_models(dir.path());
    let mut report = Vec::new();
    let mut failures = Vec::new();
    for (folder, _, _) in SCENES {
        let data = replay_dir(folder);
        let replay: Value =
            serde_json::from_str(&std::fs::read_to_string(data.join("replay.json")).unwrap())
                .unwrap();
        let reference =
            candle_core::safetensors::load(data.join("reference.safetensors"), &Device::Cpu)
                .unwrap();
        let (start, _) = read_model(&data.join("model.ply")).unwrap();
        let tolerance = replay["tolerance"].as_f64().unwrap();
        for updates in [1, UPDATES] {
            let out = dir.path().join(format!("{folder}-{updates}"));
            let ours = our_run(&data, updates, out, &tiny);
            let r = reference[&format!("after_{updates}.sh_dc")]
                .flatten_all()
                .and_then(|t| t.to_dtype(DType::F64))
                .and_then(|t| t.to_vec1::<f64>())
                .unwrap();
            let (start_dc, ours_dc) = (&start.params().sh_dc, &ours.params().sh_dc);
            let error = update_error(start_dc, ours_dc, &r);
            let line = format!("{folder} after {updates}: sh_dc {error:.2e}");
            if error >= tolerance {
                failures.push(format!("{line} (tolerance {tolerance:.0e})"));
            }
            report.push(line);
            failures.extend(
                moved_by_one_side(start_dc, ours_dc, &r, 3, "colour")
                    .into_iter()
                    .map(|m| format!("{folder} after {updates}: {m}")),
            );
            let (mut frozen, mut moved) = (start.params().clone(), ours.params().clone());
            frozen.sh_dc.clear();
            moved.sh_dc.clear();
            assert_eq!(
                moved, frozen,
                "{folder}: a group other than the colours moved"
            );
            assert_eq!(ours.time_logits(), start.time_logits());
        }
    }
    println!("{}", report.join("\n"));
    assert!(
        failures.is_empty(),
        "the run differs from the authors' loop:\n{}",
        failures.join("\n")
    );
}
