//! The batch manifest: one modality, an optional configuration file, fields set in every job,
//! the inputs (scenes) and the styles, paired as a cross product (the default) or one to one.
//!
//! ```json
//! {
//!   "modality": "2d",
//!   "config": "../configs/2d-preview.json",
//!   "set": {"steps": 80},
//!   "inputs": [{"picture": "pictures/cat.png"}, {"picture": "pictures/dog.png"}],
//!   "styles": [{"style_prompt": "fire"}, {"style_image": "styles/starry.png"}],
//!   "pairing": "cross",
//!   "eval": {}
//! }
//! ```
//!
//! Inputs and styles are objects of the modality's configuration fields (as `--set` takes
//! them); relative paths are taken from the manifest's folder. `out` is the batch's (each job
//! writes `<batch>/<id>/`). Every entry is checked when the batch is planned: an unknown field,
//! a value of the wrong type, a missing file or a style that is neither a prompt nor a picture
//! is refused naming the entry and the field. `eval`, when given, has every job score its
//! output with the paper's CLIP metrics once it is stylized ([`EvalRequest`]).

use std::path::{Path, PathBuf};

use gs_stylize::evaluation::ClipFiles;
use gs_stylize::Override;
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use super::modality::{ModalityKind, PATH_FIELDS};

/// A manifest file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// `2d`, `video`, `3d` or `4d`.
    pub modality: ModalityKind,
    /// A configuration file of the modality (as `--config`); none: the modality's defaults.
    #[serde(default)]
    pub config: Option<PathBuf>,
    /// Fields set in every job (as `--set`).
    #[serde(default)]
    pub set: Map<String, Value>,
    /// The scenes, each an object of configuration fields (its input: `picture`, `video`,
    /// `data` or `model`, and any field of its own).
    pub inputs: Vec<Map<String, Value>>,
    /// The styles, each an object with `style_prompt` or `style_image` (and any field of its
    /// own, e.g. `source_prompt`).
    pub styles: Vec<Map<String, Value>>,
    /// How inputs and styles make jobs.
    #[serde(default)]
    pub pairing: Pairing,
    /// Score every job's output with the paper's CLIP metrics (none: no scores).
    #[serde(default)]
    pub eval: Option<EvalRequest>,
}

/// The evaluation a manifest asks of every job: the paper's CLIP metrics of its output
/// against its input (as the modality's `eval` computes them), written to the job's
/// `metrics.json`, with these CLIP files; an absent one is ViT-L/14's, the paper's evaluation
/// model, found as `eval` finds it. Relative paths are taken from the manifest's folder.
#[derive(Clone, Debug, Default, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct EvalRequest {
    /// CLIP's `config.json`.
    #[serde(default)]
    pub clip_config: Option<PathBuf>,
    /// CLIP's weights, safetensors.
    #[serde(default)]
    pub clip_weights: Option<PathBuf>,
    /// CLIP's `tokenizer.json`.
    #[serde(default)]
    pub tokenizer: Option<PathBuf>,
}

impl EvalRequest {
    /// The request with its files taken from `folder` and made absolute; an error names the
    /// field of a file that does not exist.
    pub fn resolved(&self, folder: &Path) -> Result<Self, String> {
        let file = |field: &str, path: &Option<PathBuf>| -> Result<Option<PathBuf>, String> {
            let Some(path) = path else { return Ok(None) };
            let path =
                std::path::absolute(folder.join(path)).map_err(|e| format!("eval.{field}: {e}"))?;
            if !path.is_file() {
                return Err(format!("eval.{field}: {} does not exist", path.display()));
            }
            Ok(Some(path))
        };
        Ok(Self {
            clip_config: file("clip_config", &self.clip_config)?,
            clip_weights: file("clip_weights", &self.clip_weights)?,
            tokenizer: file("tokenizer", &self.tokenizer)?,
        })
    }

    /// The CLIP files of the evaluation.
    pub fn clip_files(&self) -> ClipFiles {
        ClipFiles {
            config: self.clip_config.clone(),
            weights: self.clip_weights.clone(),
            tokenizer: self.tokenizer.clone(),
        }
    }
}

/// How a manifest's inputs and styles make jobs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Pairing {
    /// Every input with every style (`inputs x styles` jobs, input-major).
    #[default]
    Cross,
    /// Input k with style k (as many inputs as styles).
    Pairs,
}

/// One job of a manifest: its input and style entries and its resolved configuration
/// (without `out`).
#[derive(Clone, Debug)]
pub struct JobConfig {
    /// Index of its entry in `inputs`.
    pub input: usize,
    /// Index of its entry in `styles`.
    pub style: usize,
    /// The modality's whole configuration, as JSON.
    pub config: Value,
}

/// Reads the manifest at `path`; an error names the file (and, for JSON errors, the line).
pub fn read(path: &Path) -> Result<Manifest, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))
}

/// The jobs of `manifest`, whose relative paths are taken from `folder`, each checked and
/// resolved; an error names the entry and the field (`inputs[1].picture: ...`).
pub fn expand(manifest: &Manifest, folder: &Path) -> Result<Vec<JobConfig>, String> {
    if manifest.inputs.is_empty() || manifest.styles.is_empty() {
        return Err("inputs and styles: give at least one of each".into());
    }
    let config = manifest.config.as_ref().map(|c| folder.join(c));
    if let Some(c) = &config {
        if !c.is_file() {
            return Err(format!("config: {} does not exist", c.display()));
        }
    }
    let set = entry(manifest.modality, "set", &manifest.set, folder)?;
    let inputs = manifest
        .inputs
        .iter()
        .enumerate()
        .map(|(i, e)| entry(manifest.modality, &format!("inputs[{i}]"), e, folder))
        .collect::<Result<Vec<_>, _>>()?;
    let styles = manifest
        .styles
        .iter()
        .enumerate()
        .map(|(i, e)| {
            let name = format!("styles[{i}]");
            check_style(&name, e)?;
            entry(manifest.modality, &name, e, folder)
        })
        .collect::<Result<Vec<_>, _>>()?;
    // Each entry alone first, so that an unknown field or a bad value is named by its entry.
    let modality = manifest.modality;
    for (name, fields) in std::iter::once(("set".to_string(), &set))
        .chain(
            inputs
                .iter()
                .enumerate()
                .map(|(i, e)| (format!("inputs[{i}]"), e)),
        )
        .chain(
            styles
                .iter()
                .enumerate()
                .map(|(i, e)| (format!("styles[{i}]"), e)),
        )
    {
        let overrides = overrides(&[fields]);
        modality
            .resolve(config.as_deref(), &overrides)
            .map_err(|e| format!("{name}: {e}"))?;
    }
    let pairs: Vec<(usize, usize)> = match manifest.pairing {
        Pairing::Cross => (0..inputs.len())
            .flat_map(|i| (0..styles.len()).map(move |s| (i, s)))
            .collect(),
        Pairing::Pairs if inputs.len() == styles.len() => {
            (0..inputs.len()).map(|i| (i, i)).collect()
        }
        Pairing::Pairs => {
            return Err(format!(
                "pairing \"pairs\": {} inputs and {} styles; give as many of each, or pairing \
                 \"cross\"",
                inputs.len(),
                styles.len()
            ))
        }
    };
    pairs
        .into_iter()
        .map(|(input, style)| {
            let mut fields = vec![&set, &inputs[input], &styles[style]];
            // One style: a style picture clears a prompt the configuration may give, and the
            // other way round.
            let other = Map::from_iter([(
                if styles[style]
                    .get("style_image")
                    .is_some_and(|v| !v.is_null())
                {
                    "style_prompt"
                } else {
                    "style_image"
                }
                .to_string(),
                Value::Null,
            )]);
            fields.push(&other);
            let config = modality
                .resolve(config.as_deref(), &overrides(&fields))
                .map_err(|e| format!("inputs[{input}] with styles[{style}]: {e}"))?;
            Ok(JobConfig {
                input,
                style,
                config,
            })
        })
        .collect()
}

/// The overrides of `entries`' fields, in order (a later entry's field wins).
fn overrides(entries: &[&Map<String, Value>]) -> Vec<Override> {
    entries
        .iter()
        .flat_map(|e| e.iter().map(|(k, v)| Override::new(k.clone(), v.clone())))
        .collect()
}

/// The entry `fields` named `name` with its relative paths taken from `folder`; an error for
/// an `out` field or a path that does not exist or is not of its kind for `modality`
/// ([`ModalityKind::check_path`]).
fn entry(
    modality: ModalityKind,
    name: &str,
    fields: &Map<String, Value>,
    folder: &Path,
) -> Result<Map<String, Value>, String> {
    let mut out = Map::new();
    for (field, value) in fields {
        if field == "out" {
            return Err(format!(
                "{name}.out: the batch chooses each job's output folder (<batch>/<id>/)"
            ));
        }
        let value = match value {
            Value::String(path) if PATH_FIELDS.contains(&field.as_str()) => {
                let path = folder.join(path);
                if !path.exists() {
                    return Err(format!("{name}.{field}: {} does not exist", path.display()));
                }
                modality
                    .check_path(field, &path)
                    .map_err(|e| format!("{name}.{field}: {e}"))?;
                Value::String(path.display().to_string())
            }
            other => other.clone(),
        };
        out.insert(field.clone(), value);
    }
    Ok(out)
}

/// Refuses a style entry that gives neither or both of a prompt and a picture.
fn check_style(name: &str, fields: &Map<String, Value>) -> Result<(), String> {
    let given = |k: &str| fields.get(k).is_some_and(|v| !v.is_null());
    match (given("style_prompt"), given("style_image")) {
        (true, false) | (false, true) => Ok(()),
        (false, false) => Err(format!(
            "{name}: give style_prompt (a text) or style_image (a picture)"
        )),
        (true, true) => Err(format!(
            "{name}: give style_prompt or style_image, not both"
        )),
    }
}

/// A short name of entry `fields` for tables: the file name of its first path, its prompt, or
/// `name`.
pub fn label(name: &str, fields: &Map<String, Value>) -> String {
    for field in ["picture", "video", "data", "model", "style_image"] {
        if let Some(Value::String(path)) = fields.get(field) {
            let path = Path::new(path);
            return path.file_name().map_or_else(
                || path.display().to_string(),
                |n| n.to_string_lossy().into(),
            );
        }
    }
    match fields.get("style_prompt") {
        Some(Value::String(prompt)) => prompt.clone(),
        _ => name.to_string(),
    }
}
