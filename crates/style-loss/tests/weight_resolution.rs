//! Weight files are found by explicit path, environment variable, then Hugging Face cache;
//! otherwise the error says what to download and where to put it. Nothing is downloaded.

use std::ffi::OsString;
use std::path::{Path, PathBuf};

use style_loss::weight_resolution::{HubFile, CLIP_VIT_B_32_WEIGHTS};

/// A fresh empty directory under the system temp dir.
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("style-loss-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn touch(path: &Path) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, b"x").unwrap();
}

fn env_of(pairs: Vec<(&'static str, PathBuf)>) -> impl Fn(&str) -> Option<OsString> {
    move |name| {
        pairs
            .iter()
            .find(|(k, _)| *k == name)
            .map(|(_, v)| v.clone().into_os_string())
    }
}

const FILE: HubFile = CLIP_VIT_B_32_WEIGHTS;

#[test]
fn explicit_path_wins_and_must_exist() {
    let dir = scratch("explicit");
    let file = dir.join("weights.safetensors");
    touch(&file);
    let env = env_of(vec![]);
    assert_eq!(FILE.resolve_local_with(Some(&file), &env).unwrap(), file);
    let missing = dir.join("missing.safetensors");
    let err = FILE
        .resolve_local_with(Some(&missing), &env)
        .unwrap_err()
        .to_string();
    assert!(err.contains("missing.safetensors"), "{err}");
}

#[test]
fn environment_variable_then_cache() {
    let dir = scratch("env");
    let from_env = dir.join("from_env.safetensors");
    touch(&from_env);
    let env = env_of(vec![
        (FILE.env_var, from_env.clone()),
        ("HF_HUB_CACHE", dir.join("hub")),
    ]);
    assert_eq!(FILE.resolve_local_with(None, &env).unwrap(), from_env);

    let repo = dir
        .join("hub")
        .join("models--openai--clip-vit-base-patch32");
    std::fs::create_dir_all(repo.join("refs").join("refs").join("pr")).unwrap();
    std::fs::write(repo.join("refs").join("refs/pr/15"), "abc123\n").unwrap();
    let cached = repo
        .join("snapshots")
        .join("abc123")
        .join("model.safetensors");
    touch(&cached);
    let env = env_of(vec![("HF_HUB_CACHE", dir.join("hub"))]);
    assert_eq!(FILE.resolve_local_with(None, &env).unwrap(), cached);
    let env = env_of(vec![("HF_HOME", dir.clone())]);
    assert_eq!(FILE.resolve_local_with(None, &env).unwrap(), cached);
}

#[test]
fn nothing_found_names_repository_file_and_places() {
    let dir = scratch("none");
    let env = env_of(vec![("HF_HUB_CACHE", dir.join("hub"))]);
    let err = FILE.resolve_local_with(None, &env).unwrap_err().to_string();
    for needle in [
        "openai/clip-vit-base-patch32",
        "model.safetensors",
        "CLIPGAUSSIAN_CLIP_B32_WEIGHTS",
        "hub",
    ] {
        assert!(err.contains(needle), "missing {needle:?} in: {err}");
    }
}
