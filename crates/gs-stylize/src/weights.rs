//! The model files a command reads (CLIP, its tokenizer, VGG-19), found with
//! [`style_loss::weight_resolution`]: the path given, then the environment variable, then the
//! Hugging Face cache, then a download when the binary is built with the `download` feature.
//! When some cannot be found, one error lists every missing file, each with the command-line
//! flag (and configuration field) that passes its path, which style-loss does not know.

use std::path::{Path, PathBuf};

use style_loss::weight_resolution::{
    HubFile, CLIP_TOKENIZER, CLIP_VIT_B_32_WEIGHTS, VGG19_WEIGHTS,
};
use style_loss::StyleLossError;

use crate::StyleSettings;

/// One model file to find: where it may be, the path given for it, and the flag that gives it.
#[derive(Clone, Copy, Debug)]
pub struct WeightRequest<'a> {
    /// The file of its Hugging Face repository, with its environment variable.
    pub hub: HubFile,
    /// The path given on the command line or in the configuration, if any.
    pub explicit: Option<&'a Path>,
    /// The flag that gives the path (e.g. `--clip-weights`).
    pub flag: &'static str,
    /// The configuration field that gives it, for a command that reads a configuration.
    pub field: Option<&'static str>,
}

/// Model files that could not be found: one line each, naming the file, the places tried and
/// how to provide it.
#[derive(Debug, thiserror::Error)]
#[error("{} model file(s) missing:\n- {}", .0.len(), .0.join("\n- "))]
pub struct MissingWeights(pub Vec<String>);

/// Finds every file of `requests`, in order; when any is missing, the error lists all the
/// missing ones.
pub fn resolve_all(requests: &[WeightRequest]) -> Result<Vec<PathBuf>, MissingWeights> {
    resolve_all_with(requests, true)
}

/// [`resolve_all`], downloading a missing file (where the build can) only when `download`.
fn resolve_all_with(
    requests: &[WeightRequest],
    download: bool,
) -> Result<Vec<PathBuf>, MissingWeights> {
    let mut found = Vec::new();
    let mut missing = Vec::new();
    let env = |name: &str| std::env::var_os(name);
    for r in requests {
        let result = if download {
            r.hub.resolve(r.explicit)
        } else {
            r.hub.resolve_local_with(r.explicit, &env)
        };
        match result {
            Ok(path) => found.push(path),
            Err(e) => missing.push(with_flag(&e, r)),
        }
    }
    if missing.is_empty() {
        Ok(found)
    } else {
        Err(MissingWeights(missing))
    }
}

/// A weight-lookup error of style-loss, saying which flag (and field) passes the file's path.
fn with_flag(e: &StyleLossError, request: &WeightRequest) -> String {
    let flag = request.flag;
    let field = request
        .field
        .map_or(String::new(), |f| format!(" (configuration field `{f}`)"));
    match e {
        StyleLossError::WeightsNotFound {
            repo,
            revision,
            file,
            env_var,
            tried,
        } => format!(
            "cannot find `{file}` of the Hugging Face repository `{repo}` (revision \
             `{revision}`). Tried: {tried}. Download it from https://huggingface.co/{repo} and \
             either pass its path with {flag}{field}, set the environment variable {env_var} \
             to it, or put it in the Hugging Face cache ($HF_HUB_CACHE, $HF_HOME/hub or \
             ~/.cache/huggingface/hub)"
        ),
        other => format!("{flag}: {other}"),
    }
}

/// The model files a stylization reads, found by [`resolve_weights`].
#[derive(Clone, Debug, PartialEq)]
pub struct WeightFiles {
    /// CLIP weights (safetensors).
    pub clip: PathBuf,
    /// CLIP's `tokenizer.json`.
    pub tokenizer: PathBuf,
    /// VGG-19 weights, when the content loss is on.
    pub vgg: Option<PathBuf>,
}

/// Finds the CLIP ViT-B/32, tokenizer and (when `lambda_content > 0`) VGG-19 files of
/// `settings` ([`resolve_all`]), downloading a missing one only when `download` (a run that has
/// already found another problem looks on this machine only). It runs before any long
/// preparation (a fit), so a missing file is reported at once, naming where to put it.
pub fn resolve_weights(
    settings: &StyleSettings,
    download: bool,
) -> Result<WeightFiles, MissingWeights> {
    let mut requests = vec![
        WeightRequest {
            hub: CLIP_VIT_B_32_WEIGHTS,
            explicit: settings.clip_weights.as_deref(),
            flag: "--clip-weights",
            field: Some("clip_weights"),
        },
        WeightRequest {
            hub: CLIP_TOKENIZER,
            explicit: settings.tokenizer.as_deref(),
            flag: "--tokenizer",
            field: Some("tokenizer"),
        },
    ];
    let content = settings.lambda_content > 0.0;
    if content {
        requests.push(WeightRequest {
            hub: VGG19_WEIGHTS,
            explicit: settings.vgg_weights.as_deref(),
            flag: "--vgg-weights",
            field: Some("vgg_weights"),
        });
    }
    let mut found = resolve_all_with(&requests, download)?.into_iter();
    let mut next = || found.next().expect("one path per request");
    Ok(WeightFiles {
        clip: next(),
        tokenizer: next(),
        vgg: content.then(next),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_missing_file_is_listed_with_its_flag() {
        let dir = tempfile::tempdir().unwrap();
        let there = dir.path().join("tokenizer.json");
        std::fs::write(&there, "{}").unwrap();
        let gone = dir.path().join("gone.safetensors");
        let request = |hub, explicit, flag| WeightRequest {
            hub,
            explicit,
            flag,
            field: (flag == "--clip-weights").then_some("clip_weights"),
        };
        let e = resolve_all(&[
            request(
                CLIP_VIT_B_32_WEIGHTS,
                Some(gone.as_path()),
                "--clip-weights",
            ),
            request(CLIP_TOKENIZER, Some(there.as_path()), "--tokenizer"),
            request(VGG19_WEIGHTS, Some(gone.as_path()), "--vgg-weights"),
        ])
        .unwrap_err()
        .to_string();
        assert!(e.starts_with("2 model file(s) missing:\n- "), "{e}");
        assert!(e.contains("gone.safetensors"), "{e}");
        assert!(
            e.contains("pass its path with --clip-weights (configuration field `clip_weights`)"),
            "{e}"
        );
        assert!(e.contains("with --vgg-weights, set"), "{e}");
        assert!(!e.contains("--tokenizer"), "{e}");
        let found = resolve_all(&[request(CLIP_TOKENIZER, Some(&there), "--tokenizer")]);
        assert_eq!(found.unwrap(), [there]);
    }
}
