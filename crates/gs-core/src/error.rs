//! gs-core's error: each variant names what was wrong and where.

use std::path::PathBuf;

/// Errors of gs-core: each names what was wrong and where.
#[derive(Debug, thiserror::Error)]
pub enum GsError {
    /// A camera with an impossible size, intrinsics or pose.
    #[error("invalid camera: {0}")]
    InvalidCamera(String),
    /// An image file that could not be read or written.
    #[error("image {path}: {source}")]
    Image {
        /// The file.
        path: PathBuf,
        /// What went wrong (the decoder's, the encoder's or the file system's error).
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// A render and its target differ in size.
    #[error(
        "view {view}: render is {render_w}x{render_h} but its target is {target_w}x{target_h}"
    )]
    SizeMismatch {
        /// The view index.
        view: usize,
        /// Render width, pixels.
        render_w: u32,
        /// Render height, pixels.
        render_h: u32,
        /// Target width, pixels.
        target_w: u32,
        /// Target height, pixels.
        target_h: u32,
    },
    /// Saved optimizer state that does not fit the parameters it is restored into.
    #[error("optimizer state: {0}")]
    OptimizerState(String),
    /// An input/output error on a named file.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
}
