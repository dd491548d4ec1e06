//! What the batch does per modality: resolve a job's configuration and run it, through the
//! modality crates' own `stylize::run` functions.

use std::error::Error;
use std::path::Path;

use gs_stylize::config::resolve_config;
use gs_stylize::evaluation::ClipFiles;
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

/// A configuration of type `C` from its JSON.
fn parse<C: DeserializeOwned>(config: &Value) -> Result<C, StylizeError> {
    serde_json::from_value(config.clone()).map_err(|e| StylizeError::Config(e.to_string()))
}
