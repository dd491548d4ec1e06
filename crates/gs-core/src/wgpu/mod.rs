//! The wgpu backend (feature `wgpu`): the rasterizer, its backward pass and Adam as WGSL compute
//! kernels (the repository's `shaders/`, one kernel a file, each named after its cpu twin),
//! with exactly the semantics of the cpu backend ([`crate::raster`], [`crate::adam`]).
//!
//! - [`GpuContext`]: adapter choice (a real GPU first; a software device such as Mesa's
//!   lavapipe only when asked for), the adapter's own limits, the compiled kernels.
//! - [`GpuGaussians`]: Gaussian parameters resident on the GPU.
//! - [`render`] and [`backward`]: projection, SH colour, tile binning, a GPU radix sort by
//!   depth and then by tile, front-to-back compositing, and the exact backward pass.
//! - [`GpuAdam`]: Adam whose moments stay on the GPU.
//!
//! Per step, the only traffic between host and GPU is the rendered image read back, dL/dimage
//! uploaded, and one `u32` (the number of tile-Gaussian pairs, which sizes the pair lists).

mod adam;
mod backward;
mod buffers;
mod device;
mod forward;
mod scan;
mod shaders;
mod sort;

pub use adam::GpuAdam;
pub use backward::{backward, GpuGradients};
pub use buffers::{read_f32, upload_f32, GpuGaussians};
pub use device::{AdapterChoice, GpuContext, GpuError, GpuOptions};
pub use forward::{render, GpuRendered};
