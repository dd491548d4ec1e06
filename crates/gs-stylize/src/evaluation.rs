//! The paper's CLIP metrics (CLIP-S, CLIP-SIM, CLIP-CONS, CLIP-F; CLIP ViT-L/14, x100) of
//! renders against their ground truths, for every modality's `eval`: the prompts are checked
//! first ([`check_prompts`]), CLIP's files found next ([`resolve_clip`]), and the pictures,
//! paired by index with consecutive entries being consecutive views, scored last ([`score`]).

use std::path::{Path, PathBuf};

use candle_core::{Device, Tensor};
use gs_core::Image;
use serde::Serialize;
use style_loss::image_layout::hwc_to_tensor;
use style_loss::metrics::{evaluate_pairs, StyleReference};
use style_loss::weight_resolution::{CLIP_TOKENIZER, CLIP_VIT_L_14_WEIGHTS};
use style_loss::{ClipConfig, ClipModel, ClipTokenizer, StyleLossError};

use crate::config::check_prompt;
use crate::picture::load_picture;
use crate::weights::{resolve_all, MissingWeights, WeightRequest};
use crate::StyleSettings;

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
        "{} and {} hold different pictures: only in the renders: [{}]; only in the ground \
         truths: [{}]",
        renders.display(),
        ground_truths.display(),
        only_renders.join(", "),
        only_ground_truths.join(", ")
    )]
    Unmatched {
        /// The renders folder.
        renders: PathBuf,
        /// The ground-truth folder.
        ground_truths: PathBuf,
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
    /// A renders folder holding another number of pictures than its reference has views.
    #[error(
        "{} holds {found} pictures but {reference} has {expected}{detail}: pass the folder the \
         render of that reference wrote",
        renders.display()
    )]
    Count {
        /// The renders folder.
        renders: PathBuf,
        /// Pictures found there.
        found: usize,
        /// The reference (ground-truth folder, video or split) it is scored against.
        reference: String,
        /// Views of the reference.
        expected: usize,
        /// The names missing and unexpected, where the names are known (`" (missing: ...)"`),
        /// else empty.
        detail: String,
    },
    /// A render whose size is not its ground truth's.
    #[error(
        "{render}: the render is {}x{} but its ground truth {truth} is {}x{}: render at the \
         ground truth's size (the same --max-width and -r)",
        render_size.0, render_size.1, truth_size.0, truth_size.1
    )]
    Size {
        /// The render (file, or frame of a folder).
        render: String,
        /// Its width and height, pixels.
        render_size: (usize, usize),
        /// Its ground truth.
        truth: String,
        /// The ground truth's width and height, pixels.
        truth_size: (usize, usize),
    },
    /// A picture that could not be read.
    #[error("{0}")]
    Image(#[from] gs_core::GsError),
    /// The style image, which does not decode.
    #[error("style image: {0}")]
    StyleImage(#[source] gs_core::GsError),
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

/// The scores' file of an evaluation: `eval`'s default `--out`, and what a batch job that is
/// asked for metrics writes into its folder.
pub const METRICS_JSON: &str = "metrics.json";

/// The style the renders are scored against.
#[derive(Clone, Debug, PartialEq)]
pub enum Style {
    /// A text prompt.
    Prompt(String),
    /// A picture.
    Image(PathBuf),
}

impl Style {
    /// The style a run was given (its picture when it has one, else its prompt).
    pub fn of_run(settings: &StyleSettings) -> Self {
        Self::given(
            settings.style_image.as_ref(),
            settings.style_prompt.as_ref(),
        )
    }

    /// The style of a picture `image` and a prompt `prompt` of which one is given: the picture
    /// when it is.
    pub(crate) fn given(image: Option<&PathBuf>, prompt: Option<&String>) -> Self {
        match (image, prompt) {
            (Some(image), _) => Self::Image(image.clone()),
            (None, prompt) => Self::Prompt(prompt.cloned().unwrap_or_default()),
        }
    }
}

/// What renders are scored with: the style, the neutral prompt of CLIP-SIM and CLIP's files.
#[derive(Clone, Debug, PartialEq)]
pub struct Scoring {
    /// The style.
    pub style: Style,
    /// The neutral prompt of CLIP-SIM (a run's source prompt).
    pub source_prompt: String,
    /// CLIP's files (ViT-L/14, the paper's evaluation model, where `None`).
    pub clip: ClipFiles,
}

impl Scoring {
    /// The scoring of a run's output: its style and source prompt, with the CLIP of `clip`
    /// (not the run's own CLIP, which guided the stylization).
    pub fn of_run(settings: &StyleSettings, clip: ClipFiles) -> Self {
        Self {
            style: Style::of_run(settings),
            source_prompt: settings.source_prompt.clone(),
            clip,
        }
    }
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

impl Metrics {
    /// The scores as lines for the terminal (`n/a` for the two that need two views).
    pub fn lines(&self) -> String {
        let optional = |v: Option<f64>| v.map_or("n/a (one view)".into(), |v| format!("{v:.4}"));
        format!(
            "views:     {}\nCLIP-S:    {:.4}\nCLIP-SIM:  {:.4}\nCLIP-CONS: {}\nCLIP-F:    {}\n",
            self.views,
            self.clip_s,
            self.clip_sim,
            optional(self.clip_cons),
            optional(self.clip_f)
        )
    }
}

/// File extensions (lower case) of the pictures a renders or ground-truth folder holds.
pub const PICTURE_EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

/// The picture names (files with an extension of [`PICTURE_EXTENSIONS`], any case) in `dir`,
/// sorted.
pub fn picture_names(dir: &Path) -> Result<std::collections::BTreeSet<String>, EvalError> {
    let io = |source| EvalError::Io {
        path: dir.to_path_buf(),
        source,
    };
    if dir.exists() && !dir.is_dir() {
        return Err(io(std::io::Error::new(
            std::io::ErrorKind::NotADirectory,
            "a file, not a folder of pictures",
        )));
    }
    let mut names = std::collections::BTreeSet::new();
    for entry in std::fs::read_dir(dir).map_err(io)? {
        let path = entry.map_err(io)?.path();
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_lowercase())
            .unwrap_or_default();
        if path.is_file() && PICTURE_EXTENSIONS.contains(&ext.as_str()) {
            if let Some(name) = path.file_name() {
                names.insert(name.to_string_lossy().into_owned());
            }
        }
    }
    Ok(names)
}

/// Refuses a renders folder `renders` of `found` pictures scored against `reference` of
/// `expected` views.
pub fn check_count(
    renders: &Path,
    found: usize,
    reference: &str,
    expected: usize,
) -> Result<(), EvalError> {
    if found == expected {
        return Ok(());
    }
    Err(EvalError::Count {
        renders: renders.to_path_buf(),
        found,
        reference: reference.to_string(),
        expected,
        detail: String::new(),
    })
}

/// Refuses a renders folder `renders` whose pictures are not exactly `expected` (the names the
/// render of `reference` writes), naming the missing and the unexpected ones.
pub fn check_names(
    renders: &Path,
    expected: &std::collections::BTreeSet<String>,
    reference: &str,
) -> Result<(), EvalError> {
    let found = picture_names(renders)?;
    if &found == expected {
        return Ok(());
    }
    let list = |names: Vec<&String>| {
        names
            .iter()
            .map(|n| n.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let missing = list(expected.difference(&found).collect());
    let extra = list(found.difference(expected).collect());
    let detail = match (missing.is_empty(), extra.is_empty()) {
        (false, false) => format!(" (missing: {missing}; unexpected: {extra})"),
        (false, true) => format!(" (missing: {missing})"),
        _ => format!(" (unexpected: {extra})"),
    };
    Err(EvalError::Count {
        renders: renders.to_path_buf(),
        found: found.len(),
        reference: reference.to_string(),
        expected: expected.len(),
        detail,
    })
}

/// Refuses a render (its `(width, height)` in `rendered`, named `labels.0` in errors) whose size
/// is not its ground truth's (in `truths`, named `labels.1`), pair by pair; CLIP would
/// otherwise resize both and score pictures of different framing without a word.
pub fn check_sizes(
    labels: &[(String, String)],
    rendered: &[(usize, usize)],
    truths: &[(usize, usize)],
) -> Result<(), EvalError> {
    for ((render, truth), (&r, &t)) in labels.iter().zip(rendered.iter().zip(truths)) {
        if r != t {
            return Err(EvalError::Size {
                render: render.clone(),
                render_size: r,
                truth: truth.clone(),
                truth_size: t,
            });
        }
    }
    Ok(())
}

/// Refuses an empty style prompt or source prompt, as stylization does.
pub fn check_prompts(style: &Style, source_prompt: &str) -> Result<(), EvalError> {
    if let Style::Prompt(prompt) = style {
        check_prompt("style prompt", prompt).map_err(EvalError::Prompt)?;
    }
    check_prompt("source prompt", source_prompt).map_err(EvalError::Prompt)
}

/// CLIP's configuration and the paths of its weights and tokenizer, found.
#[derive(Clone, Debug)]
pub struct ResolvedClip {
    config: ClipConfig,
    weights: PathBuf,
    tokenizer: PathBuf,
}

/// Finds CLIP's files (`ClipFiles` entries, else the ViT-L/14 defaults); a missing one is
/// reported with the `eval` flag that passes it.
pub fn resolve_clip(clip_files: &ClipFiles) -> Result<ResolvedClip, EvalError> {
    let config = match &clip_files.config {
        Some(path) => ClipConfig::from_json_file(path)?,
        None => ClipConfig::vit_l_14(),
    };
    let mut found = resolve_all(&[
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
    let tokenizer = found.remove(1);
    Ok(ResolvedClip {
        config,
        weights: found.remove(0),
        tokenizer,
    })
}

/// Scores `count` pairs (`[1, 3, h, w]` pictures: a render and its ground truth, in view order)
/// that `pair` gives by index, asked for in order a few at a time so that only their CLIP
/// embeddings are held, for `style` (a style picture is composited over `background`) and the
/// neutral prompt `source_prompt`, with the CLIP of `clip`.
pub fn score(
    clip: &ResolvedClip,
    count: usize,
    pair: impl FnMut(usize) -> Result<(Tensor, Tensor), EvalError>,
    style: &Style,
    source_prompt: &str,
    background: [f32; 3],
) -> Result<Metrics, EvalError> {
    let style_image;
    let reference = match style {
        Style::Prompt(prompt) => StyleReference::Prompt(prompt),
        Style::Image(path) => {
            style_image =
                load_picture(path, background, &Device::Cpu).map_err(EvalError::StyleImage)?;
            StyleReference::Image(&style_image)
        }
    };
    let tokenizer = ClipTokenizer::from_file(&clip.tokenizer)?;
    let model = ClipModel::load(&clip.config, &clip.weights, &Device::Cpu)?;
    let scores = evaluate_pairs(&model, &tokenizer, reference, source_prompt, count, pair)?;
    Ok(Metrics {
        views: count,
        clip_s: scores.s,
        clip_sim: scores.sim,
        clip_cons: scores.cons,
        clip_f: scores.f,
    })
}

/// Scores `renders` against `truths` (paired by index, consecutive entries consecutive views;
/// `labels` names each pair's files in errors) after the cheap checks: the prompts, then the
/// sizes, then CLIP's files. A style picture is composited over `background`.
pub fn score_images(
    renders: &[Image],
    truths: &[Image],
    labels: &[(String, String)],
    scoring: &Scoring,
    background: [f32; 3],
) -> Result<Metrics, EvalError> {
    check_prompts(&scoring.style, &scoring.source_prompt)?;
    if renders.len() != truths.len() {
        return Err(StyleLossError::Input {
            name: "ground truths".into(),
            reason: format!("{} for {} renders", truths.len(), renders.len()),
        }
        .into());
    }
    let size = |f: &Image| (f.width as usize, f.height as usize);
    check_sizes(
        labels,
        &renders.iter().map(size).collect::<Vec<_>>(),
        &truths.iter().map(size).collect::<Vec<_>>(),
    )?;
    let clip = resolve_clip(&scoring.clip)?;
    let tensor = |f: &Image| {
        let (h, w) = (f.height as usize, f.width as usize);
        hwc_to_tensor(&f.data, h, w, &Device::Cpu).map_err(EvalError::from)
    };
    score(
        &clip,
        renders.len(),
        |i| Ok((tensor(&renders[i])?, tensor(&truths[i])?)),
        &scoring.style,
        &scoring.source_prompt,
        background,
    )
}

/// Writes `metrics` as pretty JSON to `path` ([`gs_core::fs::write_atomic`]).
pub fn write_metrics(path: &Path, metrics: &Metrics) -> Result<(), EvalError> {
    let text = serde_json::to_string_pretty(metrics).expect("metrics serialize") + "\n";
    gs_core::fs::write_atomic(path, text.as_bytes()).map_err(|source| EvalError::Io {
        path: path.to_path_buf(),
        source,
    })
}
