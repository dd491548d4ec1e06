//! `clipgaussian-video stylize` against a float64 replay of the authors' video loop
//! (`scripts/make_video_replay_fixture.py`: CLIPGaussian's `Video/train_style.py` on VeGaS, with
//! INRIA's rasterizer transcribed in PyTorch), on a 3-frame clip with partly transparent pixels
//! and a model whose renders exceed 1 (the video loop does not clamp them).
//!
//! The replay takes this run's random draws (the view and the patch crops and warps of every
//! update, `draws.json`) and its text direction; everything else (frames and mirrors, cameras,
//! frame times, the folded Gaussians of each frame, render, losses, Adam on the colours) is the
//! authors'. After 1 and 10 updates the colours must agree to float32 noise, and every other
//! group must not have moved.

use std::path::{Path, PathBuf};

use base_vegas::folded::FoldedGaussians;
use base_vegas::model_file::read_model;
use base_vegas::stylize::{run, VideoStylizeConfig};
use candle_core::{DType, Device};
use gs_stylize::test_support::{
    assert_replay_draws, replay_draws, replay_settings, save_replay_draws, update_error,
};
use gs_stylize::{RunOptions, StyleSettings};
use serde_json::Value;
use style_loss::test_models::{write_tiny_models, TinyModelFiles};

/// The run's seed, and what its draws depend on: views (3 frames and their mirrors), frame
/// size, patches, updates.
const SEED: u64 = 5;
const VIEWS: usize = 6;
const WIDTH: usize = 64;
const HEIGHT: usize = 48;
const UPDATES: u64 = 10;

fn replay_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/authors_replay")
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
    let draws = replay_draws(
        &settings(&write_tiny_models(dir.path())),
        VIEWS,
        HEIGHT,
        WIDTH,
    );
    save_replay_draws(&replay_dir(), &draws);
}

#[test]
fn the_replay_used_this_runs_draws() {
    let dir = tempfile::tempdir().unwrap();
    let ours = replay_draws(
        &settings(&write_tiny_models(dir.path())),
        VIEWS,
        HEIGHT,
        WIDTH,
    );
    assert_replay_draws(
        &replay_dir().join("draws.json"),
        &ours,
        "regenerate the replay (cargo test -p base-vegas --test authors_replay -- --ignored \
         write_replay_draws, then scripts/make_video_replay_fixture.py)",
    );
}

/// Stylizes the fixture's clip with its model for `updates` updates.
fn our_run(updates: u64, dir: &Path, tiny: &TinyModelFiles) -> FoldedGaussians {
    let config = VideoStylizeConfig {
        video: Some(replay_dir().join("frames")),
        model: Some(replay_dir().join("model.ply")),
        out: Some(dir.join(format!("run-{updates}"))),
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
    let replay: Value =
        serde_json::from_str(&std::fs::read_to_string(replay_dir().join("replay.json")).unwrap())
            .unwrap();
    let reference =
        candle_core::safetensors::load(replay_dir().join("reference.safetensors"), &Device::Cpu)
            .unwrap();
    let (start, _) = read_model(&replay_dir().join("model.ply")).unwrap();
    let tolerance = replay["tolerance"].as_f64().unwrap();
    let mut report = Vec::new();
    let mut worst = 0f64;
    for updates in [1, UPDATES] {
        let ours = our_run(updates, dir.path(), &tiny);
        let r = reference[&format!("after_{updates}.sh_dc")]
            .flatten_all()
            .and_then(|t| t.to_dtype(DType::F64))
            .and_then(|t| t.to_vec1::<f64>())
            .unwrap();
        let error = update_error(&start.params().sh_dc, &ours.params().sh_dc, &r);
        report.push(format!("after {updates}: sh_dc {error:.2e}"));
        worst = worst.max(error);
        let (mut frozen, mut moved) = (start.params().clone(), ours.params().clone());
        frozen.sh_dc.clear();
        moved.sh_dc.clear();
        assert_eq!(moved, frozen, "a group other than the colours moved");
        assert_eq!(ours.time_logits(), start.time_logits());
    }
    println!("{}", report.join("\n"));
    assert!(
        worst < tolerance,
        "the run differs from the authors' loop by up to {worst:.2e} of an update (tolerance \
         {tolerance:.0e}):\n{}",
        report.join("\n")
    );
}
