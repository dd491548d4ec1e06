//! What the batch does per modality: resolve a job's configuration and run it, through the
//! modality crates' own `stylize::run` functions.

use std::error::Error;
use std::path::Path;

use gs_stylize::config::resolve_config;
use gs_stylize::drive::Modality;
use gs_stylize::evaluation::ClipFiles;
use gs_stylize::model_kind::{check_model, Binary};
use gs_stylize::{Override, RunOptions, StylizeError};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use serde_json::Value;

/// The four kinds of scene a batch stylizes (one per batch).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum ModalityKind {
    /// Pictures (MiraGe), as `clipgaussian-2d stylize`.
    #[serde(rename = "2d")]
    Picture,
    /// Videos (VeGaS), as `clipgaussian-video stylize`.
    #[serde(rename = "video")]
    Video,
    /// 3D scenes (3DGS), as `clipgaussian-3d stylize`.
    #[serde(rename = "3d")]
    Scene,
    /// Dynamic scenes (D-MiSo), as `clipgaussian-4d stylize`.
    #[serde(rename = "4d")]
    DynamicScene,
}

/// Configuration fields that name files or folders: relative paths in a manifest are taken
/// from the manifest's folder, and the files a job reads enter its id.
pub const PATH_FIELDS: [&str; 9] = [
    "picture",
    "video",
    "data",
    "model",
    "style_image",
    "clip_config",
    "clip_weights",
    "tokenizer",
    "vgg_weights",
];

impl ModalityKind {
    /// The manifest's name of the modality.
    pub fn name(self) -> &'static str {
        match self {
            Self::Picture => "2d",
            Self::Video => "video",
            Self::Scene => "3d",
            Self::DynamicScene => "4d",
        }
    }

    /// The configuration of `file` (a modality's JSON configuration, as `--config`) with
    /// `overrides` (as `--set`), checked field by field and given back as JSON.
    pub fn resolve(
        self,
        file: Option<&Path>,
        overrides: &[Override],
    ) -> Result<Value, StylizeError> {
        match self {
            Self::Picture => {
                resolved::<base_mirage::stylize::PictureStylizeConfig>(file, overrides)
            }
            Self::Video => resolved::<base_vegas::stylize::VideoStylizeConfig>(file, overrides),
            Self::Scene => resolved::<base_3dgs::stylize::SceneStylizeConfig>(file, overrides),
            Self::DynamicScene => {
                resolved::<base_dmiso::stylize::DynamicSceneStylizeConfig>(file, overrides)
            }
        }
    }

    /// Checks `config` (as [`ModalityKind::resolve`] gave it, with an `out`) as the modality's
    /// run checks it before any work: its own fields (required inputs, learning-rate groups,
    /// ranges) and the shared style settings (an empty prompt, a patch size of 0).
    pub fn check(self, config: &Value) -> Result<(), String> {
        match self {
            Self::Picture => check_as::<base_mirage::stylize::PictureStylizeConfig>(config),
            Self::Video => check_as::<base_vegas::stylize::VideoStylizeConfig>(config),
            Self::Scene => check_as::<base_3dgs::stylize::SceneStylizeConfig>(config),
            Self::DynamicScene => {
                check_as::<base_dmiso::stylize::DynamicSceneStylizeConfig>(config)
            }
        }
    }

    /// The binary whose runs this modality's jobs are.
    fn binary(self) -> Binary {
        match self {
            Self::Picture => Binary::Picture,
            Self::Video => Binary::Video,
            Self::Scene => Binary::Scene,
            Self::DynamicScene => Binary::DynamicScene,
        }
    }

    /// Refuses the file or folder `path` given as `field` (one of [`PATH_FIELDS`]) when the run
    /// could not read it as that: `data` a folder; `video` a file or a folder of frames;
    /// `model` a file or (4D) a folder, of this modality; pictures a file whose header gives a
    /// size; `clip_config` and `tokenizer` JSON files; weights safetensors files (their header
    /// parsed). Special files (`/dev/zero`) are refused everywhere.
    pub fn check_path(self, field: &str, path: &Path) -> Result<(), String> {
        let meta = std::fs::metadata(path).map_err(|e| format!("{}: {e}", path.display()))?;
        let is = |kind: &str| format!("{} is {kind}", path.display());
        if meta.is_dir() {
            return match field {
                "data" | "video" => Ok(()),
                "model" if self == Self::DynamicScene => Ok(()),
                _ => Err(is("a folder, not a file")),
            };
        }
        if !meta.is_file() {
            return Err(is("not a regular file"));
        }
        match field {
            "data" => Err(is("a file, not a dataset folder")),
            "video" => Ok(()),
            "model" => check_model(self.binary(), "model", path),
            "picture" | "style_image" => gs_core::image::picture_size(path)
                .map(drop)
                .map_err(|e| format!("{e} (not a picture)")),
            "clip_config" | "tokenizer" => {
                let text = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
                match serde_json::from_slice::<Value>(&text) {
                    Ok(Value::Object(_)) => Ok(()),
                    _ => Err(is("not a JSON object")),
                }
            }
            "clip_weights" | "vgg_weights" => safetensors_header(path, meta.len()),
            _ => Ok(()),
        }
    }

    /// Runs the stylization of `config` (as [`ModalityKind::resolve`] gave it) in this process.
    pub fn run(self, config: &Value, options: &RunOptions) -> Result<(), Box<dyn Error>> {
        match self {
            Self::Picture => {
                base_mirage::stylize::run(&parse(config)?, options)?;
            }
            Self::Video => {
                base_vegas::stylize::run(&parse(config)?, options)?;
            }
            Self::Scene => {
                base_3dgs::stylize::run(&parse(config)?, options)?;
            }
            Self::DynamicScene => {
                base_dmiso::stylize::run(&parse(config)?, options)?;
            }
        }
        Ok(())
    }

    /// Scores the finished run of `config` with the paper's CLIP metrics and the CLIP of
    /// `clip` (through the modality crate's `evaluation::evaluate_run`), as JSON.
    pub fn evaluate(
        self,
        config: &Value,
        clip: ClipFiles,
    ) -> Result<Value, Box<dyn Error + Send + Sync>> {
        fn json(metrics: impl Serialize) -> Value {
            serde_json::to_value(metrics).expect("metrics serialize")
        }
        Ok(match self {
            Self::Picture => json(base_mirage::evaluation::evaluate_run(
                &parse(config)?,
                clip,
            )?),
            Self::Video => json(base_vegas::evaluation::evaluate_run(&parse(config)?, clip)?),
            Self::Scene => json(base_3dgs::evaluation::evaluate_run(&parse(config)?, clip)?),
            Self::DynamicScene => {
                json(base_dmiso::evaluation::evaluate_run(&parse(config)?, clip)?)
            }
        })
    }
}

/// `C` resolved from `file` and `overrides`, as JSON.
fn resolved<C>(file: Option<&Path>, overrides: &[Override]) -> Result<Value, StylizeError>
where
    C: Serialize + DeserializeOwned + Default,
{
    let config: C = resolve_config(file, overrides)?;
    Ok(serde_json::to_value(config).expect("configurations serialize"))
}

/// Refuses a file of `length` bytes at `path` whose start is not a safetensors header: a
/// little-endian `u64` length, then that many bytes of a JSON object, within the file.
fn safetensors_header(path: &Path, length: u64) -> Result<(), String> {
    let refused = || {
        format!(
            "{} is not a safetensors file (its header does not parse)",
            path.display()
        )
    };
    let head = gs_core::fs::read_head(path, 8).map_err(|e| format!("{}: {e}", path.display()))?;
    let size = match head.get(..8) {
        Some(b) => u64::from_le_bytes(b.try_into().expect("8 bytes")),
        None => return Err(refused()),
    };
    // Real headers are kilobytes to a few megabytes.
    if size > (100 << 20) || size.saturating_add(8) > length {
        return Err(refused());
    }
    let head =
        gs_core::fs::read_head(path, 8 + size).map_err(|e| format!("{}: {e}", path.display()))?;
    match serde_json::from_slice::<Value>(&head[8..]) {
        Ok(Value::Object(_)) => Ok(()),
        _ => Err(refused()),
    }
}

/// [`ModalityKind::check`] of a configuration of type `C`.
fn check_as<C>(config: &Value) -> Result<(), String>
where
    C: DeserializeOwned + Modality,
    C::Error: std::fmt::Display,
{
    let config: C = parse(config).map_err(|e| e.to_string())?;
    config.check().map_err(|e| e.to_string())?;
    config.settings().validate().map_err(|e| e.to_string())
}

/// A configuration of type `C` from its JSON.
fn parse<C: DeserializeOwned>(config: &Value) -> Result<C, StylizeError> {
    serde_json::from_value(config.clone()).map_err(|e| StylizeError::Config(e.to_string()))
}
