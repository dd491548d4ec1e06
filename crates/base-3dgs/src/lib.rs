//! base-3dgs: the 3D Gaussian splatting base model of CLIPGaussian.
//!
//! - [`dataset`]: NeRF-synthetic and COLMAP scenes as views, ground-truth images, background
//!   masks and the scene extent.
//! - [`fit`]: a 3DGS scene fitted to a dataset as INRIA's `train.py` does it
//!   (`clipgaussian-3d fit`).
//! - [`stylize`]: the 3D stylization run (`clipgaussian-3d stylize`).
//! - [`render_views`]: renders from a dataset's cameras or a camera file (`clipgaussian-3d render`).
//! - [`evaluation`]: the CLIP metrics of a folder of renders (`clipgaussian-3d eval`).

/// The datasets live in gs-core (D-MiSo reads the same NeRF-synthetic layout, with times).
pub use gs_core::dataset;
pub mod evaluation;
pub mod fit;
pub mod render_views;
pub mod stylize;
