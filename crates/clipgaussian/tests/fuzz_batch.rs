//! The batch's readers against mutations of a planned `jobs.json` and of a manifest, through
//! gs-core's fuzz harness, each case run by the `clipgaussian` binary as a user runs it (`batch
//! status`, `batch plan`): no panic (exit 101), an error naming the file.

#[path = "../../gs-core/tests/fuzz/mod.rs"]
mod fuzz;

// The example that writes the tiny batch; its `main` is the example's own.
#[allow(dead_code)]
#[path = "../examples/tiny_batch.rs"]
mod tiny_batch;

use std::path::Path;
use std::process::Command;

/// Runs `clipgaussian` with `args`: `Ok` on success, the error output otherwise; a panic fails
/// the test.
fn clipgaussian(args: &[&std::ffi::OsStr]) -> Result<(), String> {
    let out = Command::new(env!("CARGO_BIN_EXE_clipgaussian"))
        .args(args)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    match out.status.code() {
        Some(0) => Ok(()),
        Some(101) | None => panic!("{args:?} panicked or was killed: {stderr}"),
        Some(_) => Err(stderr),
    }
}

/// The tiny manifest with every path absolute (the fuzzed copy is read from another folder).
fn absolute_manifest(dir: &Path) -> serde_json::Value {
    let path = tiny_batch::write(dir, 2).unwrap();
    let mut manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    for list in ["inputs", "styles"] {
        for entry in manifest[list].as_array_mut().unwrap() {
            for field in ["picture", "style_image"] {
                if let Some(name) = entry[field].as_str() {
                    entry[field] = dir.join(name).display().to_string().into();
                }
            }
        }
    }
    manifest
}

#[test]
fn jobs_json_survives_mutations() {
    let dir = tempfile::tempdir().unwrap();
    let manifest = dir.path().join("absolute.json");
    std::fs::write(&manifest, absolute_manifest(dir.path()).to_string()).unwrap();
    let batch = dir.path().join("batch");
    let os = |p: &Path| p.as_os_str().to_owned();
    clipgaussian(&[
        "batch".as_ref(),
        "plan".as_ref(),
        &os(&manifest),
        "--out".as_ref(),
        &os(&batch),
    ])
    .unwrap();
    let valid = std::fs::read(batch.join("jobs.json")).unwrap();
    let refused = fuzz::fuzz("jobs.json", &valid, 51, |path| {
        clipgaussian(&[
            "batch".as_ref(),
            "status".as_ref(),
            &os(path.parent().unwrap()),
        ])
    });
    assert!(refused > 0);
}

#[test]
fn manifests_survive_mutations() {
    let dir = tempfile::tempdir().unwrap();
    let valid = absolute_manifest(dir.path()).to_string();
    let refused = fuzz::fuzz("manifest.json", valid.as_bytes(), 52, |path| {
        let out = path.parent().unwrap().join("batch");
        clipgaussian(&[
            "batch".as_ref(),
            "plan".as_ref(),
            path.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
        ])
    });
    assert!(refused > 0);
}
