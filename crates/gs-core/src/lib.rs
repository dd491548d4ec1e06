//! gs-core: the shared machinery of every CLIPGaussian base model.
//!
//! - [`GaussianSet`] ([`gaussians`]): structure-of-arrays Gaussian parameters (count fixed after
//!   construction); [`sh`]: their spherical-harmonics colour.
//! - [`Camera`] ([`camera`]): pinhole cameras in OpenCV axes, from NeRF/Blender or COLMAP poses.
//! - [`Image`] ([`image`]): linear RGB pictures, read and written as 8-bit files, and a
//!   picture's size from its header.
//! - [`mat`] and [`real`]: the small 3x3 algebra and the `f32`/`f64` trait the rasterizer is
//!   written over.
//! - [`dataset`]: posed ground-truth images: NeRF-synthetic (and D-NeRF, with a time per frame)
//!   and COLMAP scenes, with background masks and the scene extent.
//! - [`orbit`]: cameras made from a Gaussian set alone (where it is, and views around or from
//!   within it), for models that come without their cameras.
//! - [`mirror_pair`]: the two cameras of Gaussians on a plane (MiraGe pictures, VeGaS frames).
//! - [`plane_neighbours`]: nearest-neighbour distances of points on a plane (initial scales).
//! - [`raster`]: the differentiable tile rasterizer (cpu backend) with its exact backward.
//! - [`adam`]: Adam with parameter groups, learning-rate schedules and saved state.
//! - [`fs`]: files written through a temporary name, fsynced and renamed, never half written.
//! - [`image_loss`]: L1 and SSIM with their gradients.
//! - [`ply`]: INRIA 3DGS PLY files (read and write, every SH degree, extra properties kept),
//!   the format of 3DGS and MiraGe models alike.
//! - [`splats`]: the splat formats viewers open: SuperSplat's compressed PLY, SPZ, `.splat`
//!   (read and written) and glTF with `KHR_gaussian_splatting` (written).
//! - [`interpolate`]: parameter-by-parameter blends of two models with the same Gaussians.
//! - [`model`]: the `BaseModel` trait; [`sampler`]: the views of each training step;
//!   [`train`]: one training step (render, loss, backward, Adam) and the cpu's.
//! - [`render_clamp`]: the render as the loss sees it (as rasterized, or clamped to `[0, 1]`).
//! - [`pil_resize`] and [`wide_pictures`]: Pillow's bicubic resize of 8-bit pictures, bit for
//!   bit, and the authors' loaders' shrinking of pictures wider than 1600 pixels.
//! - [`device`]: the device a run asks for (`cpu|gpu|auto`).
//! - [`vector_exp`] and [`widest_simd!`]: `exp` in arithmetic the compiler vectorizes, and
//!   kernels compiled per instruction set, for the CPU loops here and in the style loss.
//! - [`GsError`]: this crate's error.
//!
//! The GPU backend, and the opening of the device a run asks for, are the gs-wgpu crate
//! beside this one.
//!
//! Conventions follow gsplat's layouts and INRIA's rasterizer rules (near plane, radius, tiles,
//! gradient at the alpha cap); see `docs/conventions.md` in the repository.

pub mod adam;
pub mod camera;
pub mod dataset;
pub mod densify;
pub mod device;
mod error;
pub mod fallible;
pub mod fs;
pub mod gaussians;
pub mod image;
pub mod image_loss;
pub mod interpolate;
pub mod levels;
pub mod mat;
pub mod mirror_pair;
pub mod model;
pub mod orbit;
pub mod pil_resize;
pub mod plane_neighbours;
pub mod ply;
pub mod raster;
pub mod real;
pub mod render_clamp;
pub mod sampler;
pub mod sh;
mod simd;
pub mod splats;
pub mod train;
pub mod vector_exp;
pub mod wide_pictures;

pub use camera::Camera;
pub use gaussians::{GaussianGrads, GaussianSet};
pub use image::Image;
pub use real::Real;

pub use error::GsError;
