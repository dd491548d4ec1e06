//! What the command-line tests of the modality binaries share (feature `test-support`): running
//! a binary and asserting that it succeeded or failed, and the `stylize` flags of the tiny
//! random-weight models (`style_loss::test_models`).

use std::path::Path;
use std::process::{Command, Output};

use style_loss::test_models::TinyModelFiles;

/// Runs `cmd`, asserting that it succeeds (the message shows its stderr); its output.
///
/// # Panics
/// If the program cannot be started or fails.
pub fn succeeds(cmd: &mut Command) -> Output {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("{cmd:?} did not start: {e}"));
    assert!(
        out.status.success(),
        "{:?} failed:\n{}",
        cmd,
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// Runs `cmd`, asserting that it fails; its stderr.
///
/// # Panics
/// If the program cannot be started or succeeds.
pub fn fails(cmd: &mut Command) -> String {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("{cmd:?} did not start: {e}"));
    assert!(!out.status.success(), "{cmd:?} should fail");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// `path` as a command-line argument.
///
/// # Panics
/// If the path is not UTF-8.
pub fn path_str(path: &Path) -> &str {
    path.to_str().expect("a UTF-8 path")
}

/// Adds the `stylize` flags of the tiny models in `models` to `cmd`: their files, VGG's tiny
/// widths, three patches of 16 pixels and the prompt "a red fire".
pub fn tiny_style_flags(cmd: &mut Command, models: &TinyModelFiles) {
    cmd.args(["--clip-config", path_str(&models.clip_config)])
        .args(["--clip-weights", path_str(&models.clip_weights)])
        .args(["--tokenizer", path_str(&models.tokenizer)])
        .args(["--vgg-weights", path_str(&models.vgg_weights)])
        .args(["--set", "vgg_widths=[4,8,16,32,32]"])
        .args(["--set", "patch_size=16", "--set", "num_patches=3"])
        .args(["--style-prompt", "a red fire"]);
}
