//! gs-wgpu: gs-core's GPU backend. The rasterizer, its backward pass and Adam as WGSL compute
//! kernels (the repository's `shaders/`, one kernel a file, each named after its cpu twin),
//! with exactly the semantics of the cpu backend ([`gs_core::raster`], [`gs_core::adam`]), and
//! the device a run chooses at run time.
//!
//! - [`backend`]: the device a run opens ([`backend::OpenDevice`] of gs-core's
//!   `DeviceChoice`: the cpu, or a GPU), training on it ([`backend::Trainer`]) and rendering
//!   on it, one step at a time; what an embedder calls.
//! - [`GpuModel`]: the GPU twins of a [`gs_core::model::BaseModel`]'s forward and backward
//!   (provided: built on the host and uploaded; a model overrides them with its own kernels).
//! - [`FitError`]: why a photometric fit (MiraGe's, VeGaS's) on a backend could not run.
//! - [`GpuContext`]: adapter choice (a real GPU first; a software device such as Mesa's
//!   lavapipe only when asked for), the adapter's own limits, the compiled kernels.
//! - [`GpuGaussians`]: Gaussian parameters resident on the GPU.
//! - [`render`] and [`backward`]: projection, SH colour, tile binning, a GPU radix sort by
//!   depth and then by tile, front-to-back compositing, and the exact backward pass.
//! - [`GpuAdam`]: Adam whose moments stay on the GPU.
//! - [`photometric`]: a fit's photometric loss (L1 and D-SSIM) and dL/dimage where the render
//!   lives; [`backward_on_device`] takes that gradient without a copy to the host.
//! - [`GpuParams`], [`GpuStep`], [`GpuScratch`], [`GpuForward`]: a model's parameters on the
//!   GPU and what its per-view construction there works with ([`GpuModel`]; [`host_forward`]
//!   and [`host_backward`] are the provided twins).
//! - [`training_bytes`]: the GPU memory a training run needs, reported when an allocation fails.
//! - [`test_context`]: a context for tests, skipped (or failed, with [`REQUIRE_GPU_TESTS`]) on
//!   a machine without an adapter.
//! - [`KernelSource`]: WGSL kernels of other crates (a base model's own construction), with
//!   the same `//#import` of gs-core's shader files.
//!
//! Per training step of a model with its own GPU construction (plain Gaussians, MiraGe), the
//! only traffic between host and GPU is two `u32`s (the number of tile-Gaussian pairs, which
//! sizes the pair lists, and whether every gradient is finite) and the objective's: a fit's
//! photometric loss runs on the device ([`photometric`]) and reads back its partial sums (four
//! floats per 256 values); any other objective gets the rendered image read back and its
//! dL/dimage uploaded. A model on the provided [`host_forward`] / [`host_backward`] also moves
//! its parameters (when they changed), its Gaussians and their gradient.
//!
//! Rendering a pipeline's own arrays and differentiating the render, on the cpu or (with
//! `DeviceChoice::Gpu` or `Auto`) on a GPU through the same calls:
//!
//! ```
//! use gs_wgpu::backend::{Backend, DeviceChoice, OpenDevice};
//! use gs_core::raster::GradMask;
//! use gs_core::{Camera, GaussianSet};
//!
//! // One Gaussian at the origin, SH degree 0 ([N, K, 3] = [1, 1, 3]).
//! let set = GaussianSet::from_arrays(
//!     vec![0.0, 0.0, 0.0],
//!     vec![-1.5; 3],
//!     vec![1.0, 0.0, 0.0, 0.0],
//!     vec![2.0],
//!     &[0.5, 0.2, -0.3],
//! )?;
//! let camera = Camera::look_at([0.0, 0.0, -3.0], [0.0; 3], [0.0, -1.0, 0.0], 0.8, 32, 24)?;
//! let backend: Backend = DeviceChoice::Cpu.open()?;
//! let renderer = backend.renderer(&set)?;
//! let render = renderer.render_differentiable(&camera, [1.0; 3])?;
//! let image = render.image();
//! // dL/dimage of L = sum of the image: all ones.
//! let grads = render.backward(&vec![1.0; image.data.len()], GradMask::ALL)?;
//! assert_eq!(grads.gaussians.means.len(), 3);
//! assert!(grads.gaussians.sh_dc[0] > 0.0);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

mod adam;
pub mod backend;
mod backward;
mod buffers;
mod device;
mod fit_error;
mod forward;
mod memory;
mod model;
mod photometric;
mod scan;
mod shaders;
mod sort;
mod test_context;
mod train;

pub use adam::GpuAdam;
pub use backward::{
    backward, backward_on_device, backward_with_stats, DeviceOutputGrads, GpuGradients,
    GpuScreenStats,
};
pub use buffers::{read_f32, upload_f32, zeroed_f32, GpuGaussians};
pub use device::{AdapterChoice, Binding, GpuContext, GpuError, GpuOptions, ADAPTER_VARIABLE};
pub use fit_error::FitError;
pub use forward::{render, GpuRendered};
pub use memory::training_bytes;
pub(crate) use model::gaussians_for_view;
pub use model::{
    host_backward, host_forward, GpuForward, GpuModel, GpuParams, GpuScratch, GpuStep,
};
pub use photometric::{photometric, upload_target, GpuPhotometric};
pub use shaders::{Access, KernelSource, ParameterBinding};
pub use test_context::{test_adapter_exists, test_context, REQUIRE_GPU_TESTS};
pub use wgpu::Buffer;
