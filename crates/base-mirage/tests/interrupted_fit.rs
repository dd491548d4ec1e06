//! Ctrl-C during the fit of a stylization run: the shared driver stops the fit, reports it as
//! an interrupted fit (exit code 130 in the binaries) and leaves no output folder behind.

use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use base_mirage::stylize::{run, PictureStylizeConfig, PictureStylizeError};
use gs_stylize::test_support::replay_settings;
use gs_stylize::{RunOptions, StyleSettings, StylizeError};
use style_loss::test_models::write_tiny_models;

#[test]
fn a_fit_stopped_by_ctrl_c_is_reported_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let tiny = write_tiny_models(dir.path());
    let out = dir.path().join("out");
    let config = PictureStylizeConfig {
        out: Some(out.clone()),
        fit_gaussians: 64,
        fit_steps: 40,
        style: replay_settings(StyleSettings::paper_2d(), &tiny, 0, 3),
        ..PictureStylizeConfig::default()
    };
    let options = RunOptions {
        resume: false,
        progress: false,
        stop: Arc::new(AtomicBool::new(true)),
    };
    let err = run(&config, &options).unwrap_err();
    assert!(
        matches!(
            &err,
            PictureStylizeError::Stylize(StylizeError::InterruptedFit { what }) if what == "the picture"
        ),
        "{err}"
    );
    assert_eq!(
        err.to_string(),
        "interrupted while fitting the picture; nothing was written"
    );
    assert!(!out.exists(), "nothing is written when the fit is stopped");
}
