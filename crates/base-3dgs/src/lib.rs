//! base-3dgs: the 3D Gaussian splatting base model of CLIPGaussian.
//!
//! - [`ply`]: INRIA 3DGS PLY files (read and write, every SH degree, extra properties kept).
//! - [`dataset`]: NeRF-synthetic and COLMAP scenes as views, ground-truth images, background
//!   masks and the scene extent.
//! - [`stylize`]: the 3D stylization run behind the `stylize-3d` binary.

pub mod dataset;
pub mod interpolate;
pub mod ply;
pub mod stylize;

pub use ply::{read_ply, read_ply_with_format, write_ply, PlyFormat, PlyGaussians};
