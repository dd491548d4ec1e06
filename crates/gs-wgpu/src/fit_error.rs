//! Why a photometric fit of a base model on a [`crate::backend::Backend`] could not run.

use gs_core::train::TrainError;
use gs_core::GsError;

use crate::backend::{DeviceError, RenderError};

/// Why a photometric fit (MiraGe's, VeGaS's) could not run.
#[derive(Debug, thiserror::Error)]
pub enum FitError {
    /// A setting out of its range.
    #[error("{0}")]
    Settings(String),
    /// gs-core's error: a camera that could not be built, optimizer state that does not fit.
    #[error("{0}")]
    Core(#[from] GsError),
    /// Training stopped with an error.
    #[error("fitting: {0}")]
    Train(#[from] TrainError<GsError>),
    /// The device could not hold the model.
    #[error("fitting: {0}")]
    Device(#[from] DeviceError),
    /// The model could not be rendered.
    #[error("rendering: {0}")]
    Render(#[from] RenderError),
}
