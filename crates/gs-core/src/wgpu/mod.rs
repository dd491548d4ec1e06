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
//! - [`GpuParams`], [`GpuStep`], [`GpuScratch`], [`GpuForward`]: a model's parameters on the
//!   GPU and what its per-view construction there works with ([`crate::model::BaseModel`]'s
//!   GPU twins; [`host_forward`] and [`host_backward`] are the provided ones).
//! - [`train`](fn@train): the training loop of [`crate::train`] with all of the above.
//! - [`training_bytes`]: the GPU memory a training run needs, reported when an allocation fails.
//! - [`test_context`]: a context for tests, skipped (or failed, with [`REQUIRE_GPU_TESTS`]) on
//!   a machine without an adapter.
//! - [`KernelSource`]: WGSL kernels of other crates (a base model's own construction), with
//!   the same `//#import` of gs-core's shader files.
//!
//! Per training step of a model with its own GPU construction (plain Gaussians, MiraGe), the
//! only traffic between host and GPU is the rendered image read back, dL/dimage uploaded, and
//! two `u32`s (the number of tile-Gaussian pairs, which sizes the pair lists, and whether every
//! gradient is finite). A model on the provided [`host_forward`] / [`host_backward`] also moves
//! its parameters (when they changed), its Gaussians and their gradient.

mod adam;
mod backward;
mod buffers;
mod device;
mod forward;
mod memory;
mod model;
mod scan;
mod shaders;
mod sort;
mod test_gpu;
mod train;

pub use adam::GpuAdam;
pub use backward::{backward, GpuGradients};
pub use buffers::{read_f32, upload_f32, zeroed_f32, GpuGaussians};
pub use device::{AdapterChoice, Binding, GpuContext, GpuError, GpuOptions};
pub use forward::{render, GpuRendered};
pub use memory::training_bytes;
pub(crate) use model::gaussians_for_view;
pub use model::{host_backward, host_forward, GpuForward, GpuParams, GpuScratch, GpuStep};
pub use shaders::{Access, KernelSource};
pub use test_gpu::{test_adapter_exists, test_context, REQUIRE_GPU_TESTS};
pub use train::train;
pub use wgpu::Buffer;
