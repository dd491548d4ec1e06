//! gs-stylize: the CLIPGaussian stylization run (stage 2) that every modality shares. A base
//! crate's configuration implements [`drive::Modality`] (its inputs, its base model and fit,
//! its views, its outputs) and [`drive::run`] runs it in one order for every modality:
//! [`prepare`] checks everything first, the base model is given, resumed or fitted,
//! [`PreparedRun::stylize`] trains, and the modality writes its results.
//!
//! - [`drive`]: the order of every stylization run, calling the modality through
//!   [`drive::Modality`].
//! - [`prepare`](mod@prepare): every check before any long work, the devices opened, the
//!   loss's models loaded.
//! - [`stylize`]: the stylization itself: the job's checks, the objective, the optimizer,
//!   resume, the loop of steps with its checkpoints, the loss log.
//! - [`config`]: the shared settings, the flat configuration files and `field=value` overrides.
//! - [`rates`]: the learning rates of a modality's configuration, keyed by group name.
//! - [`background`]: background colours as users write them (`white`, `black`, `R,G,B`).
//! - [`binary`]: the one skeleton of the four binaries: their subcommands, parsing and
//!   dispatch, over a modality's [`binary::ModalityBinary`].
//! - [`cli`]: the `stylize` flags every binary shares, `interpolate`, the exit code.
//! - [`animation`]: frames, GIF previews and mp4 videos of a sequence of renders.
//! - [`summary`]: the summary a finished run prints and writes as `summary.json`.
//! - [`selftest`]: the `selftest` subcommand: each part on the chosen device against the cpu.
//! - [`evaluation`]: the paper's CLIP metrics of renders against ground truths (`eval`).
//! - [`export`]: the `export` subcommand: a model's Gaussians in the splat formats viewers
//!   open.
//! - [`checkpoint`]: saved parameter groups, optimizer and patch stream, to resume exactly.
//! - [`outputs`]: the files a run writes, each through a temporary name and a rename.
//! - [`memory_estimate`]: the memory a run will need, printed first; a run that cannot fit is
//!   refused.
//! - [`error`]: [`StylizeError`], why a stylization could not run.
//! - [`interrupt`]: Ctrl-C as a request to stop after the current step.
//! - [`model_kind`]: which binary opens a model file; the wrong binary refuses it by name.
//! - [`plot`]: line charts as pictures: the loss curves (`losses.png`), a fit's PSNR.
//! - [`picture`]: pictures as CLIP inputs (the style image).
//! - [`progress`]: the progress of a long loop on stderr: a bar, or plain lines in a log.
//! - [`weights`]: finding the CLIP, tokenizer and VGG-19 files, errors naming their flags.
//! - [`writable`]: checking before any work that every output can be written.

pub mod animation;
pub mod background;
pub mod binary;
pub mod checkpoint;
pub mod cli;
pub mod config;
pub mod drive;
pub mod error;
pub mod evaluation;
pub mod export;
pub mod interrupt;
pub mod memory_estimate;
pub mod model_kind;
pub mod model_views;
pub mod outputs;
pub mod picture;
pub mod plot;
pub mod prepare;
pub mod progress;
pub mod rates;
pub mod selftest;
pub mod stylize;
pub mod summary;
#[cfg(feature = "test-support")]
pub mod test_support;
pub mod viewer;
pub mod weights;
pub mod writable;

pub use config::{resolve_config, Override, StyleSettings};
pub use error::{RunError, StylizeError};
pub use gs_core::render_clamp::RenderClamp;
pub use prepare::{open_device, prepare, PreparedRun, RunOptions};
pub use stylize::{Batches, StylizeJob, StylizeOutcome};
