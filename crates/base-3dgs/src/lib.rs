//! base-3dgs: the 3D Gaussian splatting base model of CLIPGaussian.
//!
//! - [`ply`]: INRIA 3DGS PLY files (read and write, every SH degree, extra properties kept).
//! - [`dataset`]: NeRF-synthetic and COLMAP scenes as views, ground-truth images, background
//!   masks and the scene extent.
//! - [`interpolate`]: parameter-by-parameter interpolation of two Gaussian sets.
//! - [`stylize`]: the 3D stylization run (`clipgaussian-3d stylize`).
//! - [`render_views`]: renders from a dataset's cameras or a camera file (`clipgaussian-3d render`).
//! - [`evaluation`]: the CLIP metrics of a folder of renders (`clipgaussian-3d eval`).

pub mod dataset;
pub mod evaluation;
pub mod interpolate;
pub mod ply;
pub mod render_views;
pub mod stylize;

pub use ply::{read_ply, read_ply_with_format, write_ply, PlyFormat, PlyGaussians};
