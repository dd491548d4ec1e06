//! 3D stylization (CLIPGaussian stage 2): fine-tune a trained 3DGS scene with the style loss
//! and write the stylized PLY, before/after pictures, the loss log and its plot.
//!
//! - [`config`]: the run configuration, its defaults and `field=value` overrides.
//! - [`run`](mod@run): loading the inputs, building the objective and the optimizer, training.
//! - [`checkpoint`]: saved parameters, optimizer and patch stream, to resume a run exactly.
//! - [`outputs`]: the files a run writes, each through a temporary name and a rename.
//! - [`loss_plot`]: the loss curve as a picture.

pub mod checkpoint;
pub mod config;
pub mod loss_plot;
pub mod outputs;
pub mod run;

use std::path::PathBuf;

pub use config::{Override, StylizeConfig};
pub use run::{run, RunOptions, RunSummary};

/// Why a stylization could not run; each names the file or field at fault.
#[derive(Debug, thiserror::Error)]
pub enum StylizeError {
    /// A configuration that does not parse or has an invalid value.
    #[error("configuration: {0}")]
    Config(String),
    /// The input PLY.
    #[error("PLY: {0}")]
    Ply(#[from] gs_core::ply::PlyError),
    /// The dataset.
    #[error("dataset {}: {source}", path.display())]
    Dataset {
        /// The dataset folder.
        path: PathBuf,
        /// What was wrong in it.
        source: Box<crate::dataset::DatasetError>,
    },
    /// An input that does not fit the others (patch size, preview views, style image).
    #[error("{0}")]
    Input(String),
    /// Loading CLIP, VGG or the tokenizer, or computing the style direction.
    #[error("style loss: {0}")]
    Style(Box<style_loss::StyleLossError>),
    /// The optimizer or an image operation of gs-core.
    #[error("{0}")]
    Core(#[from] gs_core::GsError),
    /// Training stopped with an error.
    #[error("training: {0}")]
    Train(Box<gs_core::train::TrainError<style_loss::StyleLossError>>),
    /// A file that could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A checkpoint that is missing, damaged, or from a different run.
    #[error("checkpoint {}: {message}", path.display())]
    Checkpoint {
        /// The checkpoint folder.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The run was stopped (Ctrl-C) after `step`; a checkpoint of that step was written.
    #[error(
        "interrupted after step {step}; the checkpoint is in {}: run the same command again \
         with --resume to continue",
        checkpoint::checkpoint_dir(out).display()
    )]
    Interrupted {
        /// The last step taken.
        step: u64,
        /// The output folder.
        out: PathBuf,
    },
}

impl From<style_loss::StyleLossError> for StylizeError {
    fn from(e: style_loss::StyleLossError) -> Self {
        Self::Style(Box::new(e))
    }
}

impl From<gs_core::train::TrainError<style_loss::StyleLossError>> for StylizeError {
    fn from(e: gs_core::train::TrainError<style_loss::StyleLossError>) -> Self {
        Self::Train(Box::new(e))
    }
}
