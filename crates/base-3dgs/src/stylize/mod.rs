//! 3D stylization (CLIPGaussian stage 2): fine-tune a trained 3DGS scene with the style loss
//! and write the stylized PLY, before/after pictures, the loss log and its plot. The run itself
//! (objective, optimizer, checkpoints, loss log) is [`gs_stylize`]'s; this module adds the 3D
//! inputs and outputs.
//!
//! - [`config`]: the 3D run configuration and its paper defaults.
//! - [`run`](mod@run): loading the PLY and the dataset, stylizing, writing the PLY and previews.
//! - `model_views`: the views and ground truths of a run given only the model.

pub mod config;
mod model_views;
pub mod run;

pub use config::SceneStylizeConfig;
pub use gs_stylize::{Override, RunOptions, StyleSettings, StylizeError};
pub use run::{run, SceneStylizeError, SceneSummary, MODEL_PLY};
