//! The paper's CLIP metrics (CLIP-S, CLIP-SIM, CLIP-CONS, CLIP-F) of a folder of renders
//! against a folder of ground truths: pictures are paired by file name and taken in file-name
//! order (CLIP-CONS and CLIP-F use consecutive pairs in that order). The cheap checks come
//! first (the prompts, as stylization checks them; the folders; the model files), the pictures
//! and CLIP after.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use candle_core::{Device, Tensor};
use gs_stylize::config::check_prompt;
use gs_stylize::picture::load_picture;
use gs_stylize::weights::{resolve_all, MissingWeights, WeightRequest};
use serde::Serialize;
use style_loss::metrics::{evaluate, StyleReference};
use style_loss::weight_resolution::{CLIP_TOKENIZER, CLIP_VIT_L_14_WEIGHTS};
use style_loss::{ClipConfig, ClipModel, ClipTokenizer, StyleLossError};

/// File extensions (lower case) of the pictures a folder is searched for.
const IMAGE_EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

/// Why an evaluation could not run.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// A folder or file that could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The folder or file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The folders do not hold the same picture names.
    #[error(
        "the folders hold different pictures: only in the renders: [{}]; only in the ground \
         truths: [{}]",
        only_renders.join(", "),
        only_ground_truths.join(", ")
    )]
    Unmatched {
        /// Names present in the renders folder only.
        only_renders: Vec<String>,
        /// Names present in the ground-truth folder only.
        only_ground_truths: Vec<String>,
    },
    /// The folders hold no picture.
    #[error("no picture (.png, .jpg, .jpeg) in {}", path.display())]
    Empty {
        /// The renders folder.
        path: PathBuf,
    },
    /// A picture that could not be read.
    #[error("{0}")]
    Image(#[from] gs_core::GsError),
    /// An empty style or source prompt.
    #[error("{0}")]
    Prompt(String),
    /// CLIP's files that cannot be found.
    #[error("{0}")]
    Weights(#[from] MissingWeights),
    /// Loading CLIP or the tokenizer, or computing the metrics.
    #[error("{0}")]
    Clip(Box<StyleLossError>),
}

impl From<StyleLossError> for EvalError {
    fn from(e: StyleLossError) -> Self {
        Self::Clip(Box::new(e))
    }
}

/// The style the renders are scored against.
#[derive(Clone, Debug, PartialEq)]
pub enum Style {
    /// A text prompt.
    Prompt(String),
    /// A picture.
    Image(PathBuf),
}

/// The CLIP model files; `None` resolves the ViT-L/14 defaults (see
/// [`style_loss::weight_resolution`]); a missing one is reported with the flag of
/// `clipgaussian-3d eval` that passes it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ClipFiles {
    /// CLIP `config.json` (ViT-L/14 when `None`).
    pub config: Option<PathBuf>,
    /// CLIP weights, safetensors.
    pub weights: Option<PathBuf>,
    /// CLIP `tokenizer.json`.
    pub tokenizer: Option<PathBuf>,
}

/// The scores as written to JSON, each x100; CLIP-CONS and CLIP-F are `null` for one view.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Metrics {
    /// How many render / ground-truth pairs were scored.
    pub views: usize,
    /// CLIP-S.
    pub clip_s: f64,
    /// CLIP-SIM.
    pub clip_sim: f64,
    /// CLIP-CONS.
    pub clip_cons: Option<f64>,
    /// CLIP-F.
    pub clip_f: Option<f64>,
}

/// Orders names as people number views: runs of digits compare by value, so `r_2` comes before
/// `r_10` (CLIP-CONS and CLIP-F pair each view with the next one in this order).
fn natural_key(name: &str) -> Vec<(String, u128)> {
    let mut key = Vec::new();
    let mut text = String::new();
    let mut chars = name.chars().peekable();
    while let Some(c) = chars.next() {
        if c.is_ascii_digit() {
            let mut digits = c.to_string();
            while let Some(d) = chars.next_if(|d| d.is_ascii_digit()) {
                digits.push(d);
            }
            let value = digits.parse::<u128>().unwrap_or(u128::MAX);
            key.push((std::mem::take(&mut text), value));
        } else {
            text.push(c);
        }
    }
    key.push((text, 0));
    key
}

/// The picture names (files with an extension of [`IMAGE_EXTENSIONS`], any case) in `dir`.
fn picture_names(dir: &Path) -> Result<BTreeSet<String>, EvalError> {
    let io = |source| EvalError::Io {
        path: dir.to_path_buf(),
        source,
    };
    let mut names = BTreeSet::new();
    for entry in std::fs::read_dir(dir).map_err(io)? {
        let path = entry.map_err(io)?.path();
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_lowercase())
            .unwrap_or_default();
        if path.is_file() && IMAGE_EXTENSIONS.contains(&ext.as_str()) {
            if let Some(name) = path.file_name() {
                names.insert(name.to_string_lossy().into_owned());
            }
        }
    }
    Ok(names)
}

/// The names present in both folders in natural order (`r_2` before `r_10`); an error naming
/// every picture that is in one folder only, or when there is none.
pub fn matching_names(renders: &Path, ground_truths: &Path) -> Result<Vec<String>, EvalError> {
    let r = picture_names(renders)?;
    let g = picture_names(ground_truths)?;
    if r != g {
        return Err(EvalError::Unmatched {
            only_renders: r.difference(&g).cloned().collect(),
            only_ground_truths: g.difference(&r).cloned().collect(),
        });
    }
    if r.is_empty() {
        return Err(EvalError::Empty {
            path: renders.to_path_buf(),
        });
    }
    let mut names: Vec<String> = r.into_iter().collect();
    names.sort_by_cached_key(|n| (natural_key(n), n.clone()));
    Ok(names)
}

/// Scores the renders in `renders` against the pictures of the same names in `ground_truths`
/// (see the module documentation), transparent pixels over `background`, with the neutral
/// prompt `source_prompt`.
pub fn evaluate_folders(
    renders: &Path,
    ground_truths: &Path,
    style: &Style,
    source_prompt: &str,
    clip_files: &ClipFiles,
    background: [f32; 3],
) -> Result<Metrics, EvalError> {
    if let Style::Prompt(prompt) = style {
        check_prompt("style prompt", prompt).map_err(EvalError::Prompt)?;
    }
    check_prompt("source prompt", source_prompt).map_err(EvalError::Prompt)?;
    let names = matching_names(renders, ground_truths)?;
    let config = match &clip_files.config {
        Some(path) => ClipConfig::from_json_file(path)?,
        None => ClipConfig::vit_l_14(),
    };
    let found = resolve_all(&[
        WeightRequest {
            hub: CLIP_VIT_L_14_WEIGHTS,
            explicit: clip_files.weights.as_deref(),
            flag: "--clip-weights",
            field: None,
        },
        WeightRequest {
            hub: CLIP_TOKENIZER,
            explicit: clip_files.tokenizer.as_deref(),
            flag: "--tokenizer",
            field: None,
        },
    ])?;
    let (weights, tokenizer) = (&found[0], &found[1]);
    let load_all = |dir: &Path| -> Result<Vec<Tensor>, EvalError> {
        names
            .iter()
            .map(|n| load_picture(&dir.join(n), background, &Device::Cpu).map_err(EvalError::from))
            .collect()
    };
    let rendered = load_all(renders)?;
    let truths = load_all(ground_truths)?;
    let style_image;
    let reference = match style {
        Style::Prompt(prompt) => StyleReference::Prompt(prompt),
        Style::Image(path) => {
            style_image = load_picture(path, background, &Device::Cpu)?;
            StyleReference::Image(&style_image)
        }
    };
    let tokenizer = ClipTokenizer::from_file(tokenizer)?;
    let clip = ClipModel::load(&config, weights, &Device::Cpu)?;
    let scores = evaluate(
        &clip,
        &tokenizer,
        reference,
        source_prompt,
        &rendered,
        &truths,
    )?;
    Ok(Metrics {
        views: names.len(),
        clip_s: scores.s,
        clip_sim: scores.sim,
        clip_cons: scores.cons,
        clip_f: scores.f,
    })
}

/// Writes `metrics` as pretty JSON to `path` ([`gs_core::fs::write_atomic`]).
pub fn write_metrics(path: &Path, metrics: &Metrics) -> Result<(), EvalError> {
    let text = serde_json::to_string_pretty(metrics).expect("metrics serialize") + "\n";
    gs_core::fs::write_atomic(path, text.as_bytes()).map_err(|source| EvalError::Io {
        path: path.to_path_buf(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn natural_order_puts_numbered_views_in_sequence() {
        let mut names = vec![
            "r_10.png",
            "r_2.png",
            "r_1.png",
            "r_100.png",
            "a.png",
            "r_02.png",
        ];
        names.sort_by_cached_key(|n| (natural_key(n), n.to_string()));
        assert_eq!(
            names,
            [
                "a.png",
                "r_1.png",
                "r_02.png",
                "r_2.png",
                "r_10.png",
                "r_100.png"
            ]
        );
    }
}
