//! [`StylizeError`]: why a stylization could not run, each variant naming the file, field or
//! flag at fault and keeping the error behind it as its source; [`RunError`]: a modality's run,
//! the failures every modality shares and the modality's own.

use std::path::PathBuf;

use crate::{checkpoint, weights, writable};

/// Why a modality's run failed: the failures every modality shares, and the modality's own
/// (`E`: its input's, its model file's, its outputs'), shown as they are.
#[derive(Debug, thiserror::Error)]
pub enum RunError<E: std::error::Error + 'static> {
    /// A configuration value out of its range.
    #[error("configuration: {0}")]
    Config(String),
    /// A model file that does not fit the run's inputs.
    #[error("model {}: {reason}", path.display())]
    ModelMismatch {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// The fit of the base model.
    #[error("{0}")]
    Fit(#[from] gs_wgpu::FitError),
    /// The stylization.
    #[error("{0}")]
    Stylize(#[from] StylizeError),
    /// A sequence of renders written as frames, a GIF or a video.
    #[error("{0}")]
    Output(#[from] crate::animation::AnimationError),
    /// A dataset of posed pictures.
    #[error("{0}")]
    Dataset(#[from] gs_core::dataset::DatasetError),
    /// The modality's own failure.
    #[error(transparent)]
    Own(E),
}

/// Why a stylization could not run; each names the file or field at fault.
#[derive(Debug, thiserror::Error)]
pub enum StylizeError {
    /// A configuration that does not parse or has an invalid value.
    #[error("configuration: {0}")]
    Config(String),
    /// An input that does not fit the others or cannot be loaded (the model file, the views,
    /// the patch size, the style image).
    #[error("{0}")]
    Input(String),
    /// A run that needs more memory than this machine has (see
    /// [`crate::memory_estimate::check_memory`]).
    #[error("{0}")]
    Memory(String),
    /// Model files (CLIP, its tokenizer, VGG-19) that cannot be found.
    #[error("{0}")]
    Weights(#[from] weights::MissingWeights),
    /// An output (folder or file) that cannot be written.
    #[error("{0}")]
    Output(#[from] writable::OutputError),
    /// Loading CLIP, VGG or the tokenizer, or computing the style direction.
    #[error("style loss: {0}")]
    Style(#[source] Box<style_loss::StyleLossError>),
    /// The optimizer or an image operation of gs-core.
    #[error("{0}")]
    Core(#[from] gs_core::GsError),
    /// The compute device asked for is missing or failed.
    #[error("{0}")]
    Device(#[from] gs_wgpu::backend::DeviceError),
    /// The style loss's GPU (candle's CUDA or Metal device) is missing or failed.
    #[error("{0}")]
    LossDevice(#[from] style_loss::compute_device::LossDeviceError),
    /// Rendering a model failed.
    #[error("render: {0}")]
    Render(#[from] gs_wgpu::backend::RenderError),
    /// Training stopped with an error.
    #[error("training: {0}")]
    Train(#[source] Box<gs_core::train::TrainError<style_loss::StyleLossError>>),
    /// A chart that could not be drawn.
    #[error("plot: {0}")]
    Plot(#[source] Box<dyn std::error::Error + Send + Sync>),
    /// More than one problem, each on a line of its own.
    #[error("{} problems:{}", .0.len(), .0.iter().map(|e| format!("\n  - {e}")).collect::<String>())]
    Several(Vec<StylizeError>),
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
    /// A model file (INRIA PLY) that cannot be read or written; the error names the file.
    #[error("{0}")]
    Ply(#[from] gs_core::ply::PlyError),
    /// A splat file of another format (compressed PLY, SPZ, .splat, .glb) that cannot be read or
    /// written; the error names the file.
    #[error("{0}")]
    Splats(#[from] gs_core::splats::SplatFileError),
    /// A dataset that cannot be loaded.
    #[error("dataset {}: {source}", path.display())]
    Dataset {
        /// The dataset folder.
        path: PathBuf,
        /// What is wrong with it.
        source: Box<gs_core::dataset::DatasetError>,
    },
    /// The style image, which does not decode.
    #[error("style image: {0}")]
    StyleImage(#[source] gs_core::GsError),
    /// Two models that cannot be blended (`interpolate`).
    #[error("{} and {}: {source}", a.display(), b.display())]
    Interpolate {
        /// The first model.
        a: PathBuf,
        /// The second model.
        b: PathBuf,
        /// Why they do not blend.
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// The fit of a base model was stopped (Ctrl-C); nothing of it was written.
    #[error("interrupted while fitting {what}; nothing was written")]
    InterruptedFit {
        /// What was being fitted (`the picture`, `the video`, `the scene`).
        what: String,
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

/// `e` and every error behind it, outermost first (its `source` chain).
pub fn causes<'a>(
    e: &'a (dyn std::error::Error + 'static),
) -> impl Iterator<Item = &'a (dyn std::error::Error + 'static)> {
    std::iter::successors(Some(e), |c| c.source())
}
