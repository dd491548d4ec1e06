//! gs-stylize: the CLIPGaussian stylization run (stage 2) that every modality shares. A base
//! crate's configuration implements [`drive::Modality`] (its inputs, its base model and fit,
//! its views, its outputs) and [`drive::run`] runs it in one order for every modality:
//! [`prepare`] checks everything first, the base model is given, resumed or fitted,
//! [`PreparedRun::stylize`] trains, and the modality writes its results.
//!
//! - [`background`]: background colours as users write them (`white`, `black`, `R,G,B`).
//! - [`cli`]: the `stylize` flags every binary shares, `interpolate`, the exit code.
//! - [`drive`]: the order of every stylization run, calling the modality through [`drive::Modality`].
//! - [`config`]: the shared settings, the flat configuration files and `field=value` overrides.
//! - [`rates`]: the learning rates of a modality's configuration, keyed by group name.
//! - [`run`](mod@run): the driver: the objective, the optimizer, resume, training, the loss log.
//! - [`summary`]: the summary a finished run prints and writes as `summary.json`.
//! - [`selftest`]: the `selftest` subcommand: each part on the chosen device against the cpu.
//! - [`evaluation`]: the paper's CLIP metrics of renders against ground truths (`eval`).
//! - [`checkpoint`]: saved parameter groups, optimizer and patch stream, to resume exactly.
//! - [`outputs`]: the files a run writes, each through a temporary name and a rename.
//! - [`memory_estimate`]: the memory a run will need, printed first; a run that cannot fit is refused.
//! - [`interrupt`]: Ctrl-C as a request to stop after the current step.
//! - [`model_kind`]: which binary opens a model file; the wrong binary refuses it by name.
//! - [`plot`]: line charts as pictures: the loss curves (`losses.png`), a fit's PSNR.
//! - [`picture`]: pictures as CLIP inputs (the style image).
//! - [`progress`]: the progress of a long loop on stderr: a bar, or plain lines in a log.
//! - [`weights`]: finding the CLIP, tokenizer and VGG-19 files, errors naming their flags.
//! - [`writable`]: checking before any work that every output can be written.

pub mod animation;
pub mod background;
pub mod checkpoint;
pub mod cli;
pub mod config;
pub mod drive;
pub mod evaluation;
pub mod interrupt;
pub mod memory_estimate;
pub mod model_kind;
pub mod outputs;
pub mod picture;
pub mod plot;
pub mod progress;
pub mod rates;
pub mod run;
pub mod selftest;
pub mod summary;
#[cfg(feature = "test-support")]
pub mod test_support;
pub mod weights;
pub mod writable;

use std::path::PathBuf;

pub use config::{resolve_config, Override, StyleSettings};
pub use gs_core::render_clamp::RenderClamp;
pub use run::{open_device, prepare, Batches, PreparedRun, RunOptions, StylizeJob, StylizeOutcome};

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
    /// Model files (CLIP, its tokenizer, VGG-19) that cannot be found.
    #[error("{0}")]
    Weights(#[from] weights::MissingWeights),
    /// An output (folder or file) that cannot be written.
    #[error("{0}")]
    Output(#[from] writable::OutputError),
    /// Loading CLIP, VGG or the tokenizer, or computing the style direction.
    #[error("style loss: {0}")]
    Style(Box<style_loss::StyleLossError>),
    /// The optimizer or an image operation of gs-core.
    #[error("{0}")]
    Core(#[from] gs_core::GsError),
    /// The compute device asked for is missing or failed.
    #[error("{0}")]
    Device(#[from] gs_wgpu::backend::DeviceError),
    /// The style loss's GPU (candle's CUDA or Metal device) is missing or failed.
    #[error("{0}")]
    LossDevice(String),
    /// Rendering a model failed.
    #[error("render: {0}")]
    Render(#[from] gs_wgpu::backend::RenderError),
    /// Training stopped with an error.
    #[error("training: {0}")]
    Train(Box<gs_core::train::TrainError<style_loss::StyleLossError>>),
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
