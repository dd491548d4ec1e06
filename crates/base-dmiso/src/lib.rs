//! base-dmiso: the D-MiSo base model of CLIPGaussian for dynamic scenes (D-NeRF datasets).
//!
//! - [`encoding`]: the positional encodings of vertices and time.
//! - [`deform_net`]: the deformation network in candle, with its backward.
//! - [`core_frame`]: a core triangle deformed at a time and its frame, with the backward.
//! - [`sub_gaussian`]: one sub-Gaussian in its core's frame, with the backward.
//! - [`densify`]: D-MiSo's densification of the cores during the fit.
//! - [`init`]: the starting model and the switch to sub-Gaussians.
//! - [`fit`]: fitting a D-NeRF scene in D-MiSo's stages.
//! - [`model_file`]: our model file and the folder the authors' code saves.
//! - [`stylize`]: the 4D stylization run and its outputs.
//! - [`evaluation`]: the paper's CLIP metrics of the stylized test views (`clipgaussian-4d eval`).
//! - [`model`]: [`Dmiso`] behind gs-core's `BaseModel`: sub-Gaussians of every core.

pub mod core_frame;
pub mod deform_net;
pub mod densify;
pub mod encoding;
pub mod evaluation;
pub mod fit;
pub mod init;
pub mod model;
pub mod model_file;
pub mod stylize;
pub mod sub_gaussian;

pub use model::{interpolate, Dmiso, DmisoParams, GROUP_NAMES};
