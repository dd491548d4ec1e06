//! The compute device of a run, chosen at run time (`--device cpu|gpu|auto`), and what runs on
//! it: training ([`Trainer`]) and rendering a model view by view ([`ModelRenderer`]) or a
//! fixed Gaussian set ([`Renderer`]).
//!
//! `auto` takes a real GPU adapter when there is one, else the cpu; a software Vulkan device
//! (Mesa's lavapipe) is for tests, never a default: `gpu` refuses it unless the environment
//! variable [`ALLOW_SOFTWARE_GPU`] is `1`.

use std::ops::ControlFlow;
use std::sync::Arc;

use crate::backward::GpuScreenStats;
use crate::train::GpuTrainer;
use crate::{AdapterChoice, GpuContext, GpuError, GpuGaussians, GpuModel, GpuParams};
use gs_core::adam::{Adam, AdamHyper, GroupConfig};
use gs_core::camera::Camera;
use gs_core::densify::ScreenStats;
pub use gs_core::device::DeviceChoice;
use gs_core::gaussians::GaussianSet;
use gs_core::image::Image;
use gs_core::model::{ModelError, View};
use gs_core::raster::{GradMask, Gradients, OutputGrads};
use gs_core::sampler::{Batch, ViewSampler};
use gs_core::train::{check_sampler, CpuTrainer, Objective, StepReport, TrainConfig, TrainError};
use gs_core::GsError;

/// The environment variable that lets `gpu` take a software adapter (for tests on lavapipe).
pub const ALLOW_SOFTWARE_GPU: &str = "CLIPGAUSSIAN_ALLOW_SOFTWARE_GPU";

/// Why the device asked for cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum DeviceError {
    /// `gpu` was asked for and there is no GPU this run may use.
    #[error("--device gpu: {0}")]
    NoGpu(String),
    /// The GPU failed.
    #[error("GPU: {0}")]
    Gpu(#[from] GpuError),
    /// The optimizer's groups do not name the model's ([`gs_core::adam::groups_in_model_order`]).
    #[error("optimizer: {0}")]
    Groups(String),
}

/// Opening the device a [`DeviceChoice`] names.
pub trait OpenDevice {
    /// Opens the device: the cpu, or a GPU adapter as described in the module documentation;
    /// `gpu` takes a software adapter only when `allow_software` (an embedder's switch; the
    /// binaries and tests set it with [`ALLOW_SOFTWARE_GPU`], see [`OpenDevice::open`]).
    fn open_with(self, allow_software: bool) -> Result<Backend, DeviceError>;

    /// [`OpenDevice::open_with`], allowing a software adapter when the environment variable
    /// [`ALLOW_SOFTWARE_GPU`] is `1`.
    fn open(self) -> Result<Backend, DeviceError>;
}

impl OpenDevice for DeviceChoice {
    fn open_with(self, allow_software: bool) -> Result<Backend, DeviceError> {
        match self {
            Self::Cpu => Ok(Backend::Cpu),
            Self::Gpu => open_gpu(allow_software),
            Self::Auto => Ok(open_hardware_gpu().unwrap_or(Backend::Cpu)),
        }
    }

    fn open(self) -> Result<Backend, DeviceError> {
        self.open_with(std::env::var(ALLOW_SOFTWARE_GPU).is_ok_and(|v| v == "1"))
    }
}

/// A real GPU, when there is one.
fn open_hardware_gpu() -> Option<Backend> {
    GpuContext::new(AdapterChoice::Hardware)
        .ok()
        .map(|ctx| Backend::Gpu(Arc::new(ctx)))
}

/// A real GPU, or a software one when `software` is allowed.
fn open_gpu(software: bool) -> Result<Backend, DeviceError> {
    let choice = if software {
        AdapterChoice::AllowSoftware
    } else {
        AdapterChoice::Hardware
    };
    match GpuContext::new(choice) {
        Ok(ctx) => Ok(Backend::Gpu(Arc::new(ctx))),
        Err(GpuError::NoAdapter { seen, .. }) => Err(DeviceError::NoGpu(no_adapter_message(&seen))),
        Err(e) => Err(e.into()),
    }
}

/// Why `--device gpu` found no adapter, from the adapters wgpu saw (`"none"` when it saw none):
/// with none, what is missing (a Vulkan loader and driver; in a container, the driver's graphics
/// capability), else that only software devices were there.
fn no_adapter_message(seen: &str) -> String {
    let missing = if seen == "none" {
        "wgpu sees no Vulkan, Metal or DX12 device at all: on Linux the Vulkan loader (libvulkan1) \
         and the GPU's Vulkan driver are needed (NVIDIA: its driver's Vulkan ICD; in a container, \
         NVIDIA_DRIVER_CAPABILITIES must include graphics; AMD and Intel: mesa-vulkan-drivers)"
            .to_string()
    } else {
        format!(
            "adapters seen: {seen}; software devices such as lavapipe are for tests and need \
             {ALLOW_SOFTWARE_GPU}=1"
        )
    };
    format!("no GPU adapter ({missing}); use --device cpu or auto to run on the cpu")
}

/// An opened device.
#[derive(Clone, Debug)]
pub enum Backend {
    /// The cpu backend: the rayon rasterizer and [`Adam`].
    Cpu,
    /// The wgpu backend on one adapter.
    Gpu(Arc<GpuContext>),
}

impl Backend {
    /// One line naming the device: `cpu (rayon, 8 threads)` or the GPU adapter.
    pub fn describe(&self) -> String {
        match self {
            Self::Cpu => format!("cpu (rayon, {} threads)", rayon::current_num_threads()),
            Self::Gpu(ctx) => format!("gpu: {}", ctx.describe()),
        }
    }

    /// A renderer of `gaussians` on this device (on a GPU they are uploaded once).
    pub fn renderer<'a>(&self, gaussians: &'a GaussianSet) -> Result<Renderer<'a>, DeviceError> {
        match self {
            Self::Cpu => Ok(Renderer::Cpu(gaussians)),
            Self::Gpu(ctx) => Ok(Renderer::Gpu {
                gaussians: Box::new(GpuGaussians::upload(ctx, gaussians)?),
                ctx: Arc::clone(ctx),
            }),
        }
    }
}

/// Why rendering a model failed.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// The device failed.
    #[error(transparent)]
    Device(#[from] DeviceError),
    /// The model failed to build the view's Gaussians.
    #[error("the model failed: {0}")]
    Model(ModelError),
}

impl From<GpuError> for RenderError {
    fn from(e: GpuError) -> Self {
        Self::Device(e.into())
    }
}

impl Backend {
    /// A renderer of `model` on this device, view by view through the model's own forward
    /// (on a GPU its parameters are uploaded once and each view's Gaussians built there).
    pub fn model_renderer<'m, M: GpuModel>(
        &self,
        model: &'m mut M,
    ) -> Result<ModelRenderer<'m, M>, RenderError> {
        let device = match self {
            Self::Cpu => ModelDevice::Cpu,
            Self::Gpu(ctx) => ModelDevice::Gpu {
                params: Box::new(GpuParams::upload(ctx, model)?),
                scratch: Box::default(),
                ctx: Arc::clone(ctx),
            },
        };
        Ok(ModelRenderer { model, device })
    }
}

/// Where a [`ModelRenderer`] builds and renders.
enum ModelDevice {
    Cpu,
    Gpu {
        ctx: Arc<GpuContext>,
        params: Box<GpuParams>,
        scratch: Box<crate::GpuScratch>,
    },
}

/// A model ready to render any view on one device (frames of a video, times of a dynamic
/// scene), with the same forward as training.
pub struct ModelRenderer<'m, M> {
    model: &'m mut M,
    device: ModelDevice,
}

impl<M: GpuModel> ModelRenderer<'_, M> {
    /// The image of `view` over `background`.
    pub fn render(&mut self, view: &View, background: [f32; 3]) -> Result<Image, RenderError> {
        match &mut self.device {
            ModelDevice::Cpu => {
                let forward = self.model.forward(view).map_err(RenderError::Model)?;
                Ok(gs_core::raster::render(&forward.gaussians, &view.camera, background).image)
            }
            ModelDevice::Gpu {
                ctx,
                params,
                scratch,
            } => {
                let gaussians = crate::gaussians_for_view(self.model, ctx, params, scratch, view)
                    .map_err(|e| match e.downcast::<GpuError>() {
                    Ok(gpu) => RenderError::from(*gpu),
                    Err(e) => RenderError::Model(e),
                })?;
                Ok(crate::render(ctx, &gaussians, &view.camera, background)?.image(ctx))
            }
        }
    }
}

/// A Gaussian set ready to render from any camera on one device.
pub enum Renderer<'a> {
    /// The cpu rasterizer.
    Cpu(&'a GaussianSet),
    /// The set on a GPU.
    Gpu {
        /// The device.
        ctx: Arc<GpuContext>,
        /// The set, uploaded.
        gaussians: Box<GpuGaussians>,
    },
}

impl Renderer<'_> {
    /// The image through `camera` over `background`.
    pub fn render(&self, camera: &Camera, background: [f32; 3]) -> Result<Image, DeviceError> {
        match self {
            Self::Cpu(g) => Ok(gs_core::raster::render(g, camera, background).image),
            Self::Gpu { ctx, gaussians } => {
                Ok(crate::render(ctx, gaussians, camera, background)?.image(ctx))
            }
        }
    }

    /// The image through `camera` over `background`, kept with what its backward needs
    /// ([`DifferentiableRender::backward`]).
    pub fn render_differentiable(
        &self,
        camera: &Camera,
        background: [f32; 3],
    ) -> Result<DifferentiableRender<'_>, DeviceError> {
        let state = match self {
            Self::Cpu(g) => RenderState::Cpu {
                gaussians: g,
                camera: camera.clone(),
                rendered: Box::new(gs_core::raster::render(g, camera, background)),
            },
            Self::Gpu { ctx, gaussians } => RenderState::Gpu {
                rendered: Box::new(crate::render(ctx, gaussians, camera, background)?),
                ctx,
                gaussians,
            },
        };
        Ok(DifferentiableRender { state })
    }
}

/// A render kept for its backward pass, on the device that made it.
pub struct DifferentiableRender<'r> {
    state: RenderState<'r>,
}

enum RenderState<'r> {
    Cpu {
        gaussians: &'r GaussianSet,
        camera: Camera,
        rendered: Box<gs_core::raster::Rendered>,
    },
    Gpu {
        ctx: &'r GpuContext,
        gaussians: &'r GpuGaussians,
        rendered: Box<crate::GpuRendered>,
    },
}

impl DifferentiableRender<'_> {
    /// The rendered image (read back from a GPU).
    pub fn image(&self) -> Image {
        match &self.state {
            RenderState::Cpu { rendered, .. } => rendered.image.clone(),
            RenderState::Gpu { ctx, rendered, .. } => rendered.image(ctx),
        }
    }

    /// The gradients of the arrays `mask` asks for and of the background, given
    /// `dl_dimage`, the gradient of a loss with respect to the image (`[H, W, 3]`).
    ///
    /// # Panics
    /// If `dl_dimage` does not have the image's size.
    pub fn backward(&self, dl_dimage: &[f32], mask: GradMask) -> Result<Gradients, DeviceError> {
        let out = OutputGrads {
            rgb: dl_dimage,
            alpha: None,
            depth: None,
        };
        match &self.state {
            RenderState::Cpu {
                gaussians,
                camera,
                rendered,
            } => Ok(gs_core::raster::backward(
                gaussians, camera, rendered, &out, mask,
            )),
            RenderState::Gpu {
                ctx,
                gaussians,
                rendered,
            } => Ok(crate::backward(ctx, gaussians, rendered, &out, mask)?.download(ctx)),
        }
    }
}

/// Where a trainer's parameters and optimizer live.
enum State<M> {
    Cpu(CpuTrainer<M>),
    Gpu(Box<GpuTrainer<M>>),
}

/// A model and its optimizer on one device, trained a step at a time ([`Trainer::step`]). On a
/// GPU the parameters and moments are uploaded once and read back on request (and, for a model
/// on the provided host construction, after each step that changed them)
/// ([`Trainer::param_groups`], [`Trainer::save_optimizer`], [`Trainer::into_model`]); optimizer
/// state is in one format on both devices, so a run saved on one resumes on the other.
pub struct Trainer<M> {
    state: State<M>,
}

impl<M: GpuModel> Trainer<M> {
    /// `model` with a fresh Adam over `groups` (one per parameter group, matched to the model's
    /// groups by name in any order) on `backend`.
    pub fn new(
        backend: &Backend,
        model: M,
        groups: Vec<GroupConfig>,
        hyper: AdamHyper,
    ) -> Result<Self, DeviceError> {
        let groups = gs_core::adam::groups_in_model_order(groups, &model.group_names())
            .map_err(DeviceError::Groups)?;
        let state = match backend {
            Backend::Cpu => {
                let adam = Adam::new(groups, &model.group_lens(), hyper);
                let trainer =
                    CpuTrainer::new(model, adam).map_err(|e| DeviceError::Groups(e.to_string()))?;
                State::Cpu(trainer)
            }
            Backend::Gpu(ctx) => State::Gpu(Box::new(GpuTrainer::new(
                Arc::clone(ctx),
                model,
                groups,
                hyper,
            )?)),
        };
        Ok(Self { state })
    }

    /// Steps the optimizer has taken.
    pub fn step_count(&self) -> u64 {
        match &self.state {
            State::Cpu(cpu) => cpu.step_count(),
            State::Gpu(gpu) => gpu.adam.step_count(),
        }
    }

    /// One training step over the views `batch` names of `views` (a batch of
    /// [`gs_core::sampler::ViewSampler::next_batch`]), composited over `background`: for each
    /// view, render, `objective`'s loss and dL/dimage, backward through the rasterizer and the
    /// model; then one Adam step on the summed gradient (divided by the batch's divisor). A
    /// non-finite loss, dL/dimage or parameter gradient, or a failure, stops it with the
    /// parameters as they were. The same step on either device
    /// ([`gs_core::train::CpuTrainer::step`]).
    pub fn step<O: Objective>(
        &mut self,
        views: &[View],
        batch: Batch,
        background: [f32; 3],
        objective: &mut O,
    ) -> Result<StepReport, TrainError<O::Error>> {
        match &mut self.state {
            State::Cpu(cpu) => cpu.step(views, batch, background, objective),
            State::Gpu(gpu) => gpu.step(views, batch, background, objective),
        }
    }

    /// Steps over the batches of `sampler` until the optimizer has taken `config.steps`
    /// steps, calling `on_step` after each; it stops early when that returns
    /// `ControlFlow::Break` (e.g. on Ctrl-C). For a fit, whose loop has nothing else to do; a
    /// resumed run passes the restored optimizer and a sampler advanced by the steps taken.
    pub fn train<O, F>(
        &mut self,
        views: &[View],
        objective: &mut O,
        sampler: &mut ViewSampler,
        config: &TrainConfig,
        mut on_step: F,
    ) -> Result<(), TrainError<O::Error>>
    where
        O: Objective,
        F: FnMut(&StepReport) -> ControlFlow<()>,
    {
        check_sampler(sampler, views.len())?;
        while self.step_count() < config.steps {
            let report = self.step(views, sampler.next_batch(), config.background, objective)?;
            if on_step(&report).is_break() {
                break;
            }
        }
        Ok(())
    }

    /// From the next step on, adds every view's view-space gradients of the rendered Gaussians
    /// to `stats` (3DGS's densification statistics, [`gs_core::densify::ScreenStats`]): on a
    /// GPU they are uploaded once and gathered on the device, nothing read back per step.
    pub fn gather_screen_stats(&mut self, stats: ScreenStats) -> Result<(), DeviceError> {
        match &mut self.state {
            State::Cpu(cpu) => cpu.gather_screen_stats(stats),
            State::Gpu(gpu) => gpu.screen_stats = Some(GpuScreenStats::upload(&gpu.ctx, &stats)?),
        }
        Ok(())
    }

    /// The statistics gathered since [`Trainer::gather_screen_stats`] (read back from a GPU),
    /// which stops.
    pub fn take_screen_stats(&mut self) -> Option<ScreenStats> {
        match &mut self.state {
            State::Cpu(cpu) => cpu.take_screen_stats(),
            State::Gpu(gpu) => gpu
                .screen_stats
                .take()
                .map(|stats| stats.download(&gpu.ctx)),
        }
    }

    /// The current values of every parameter group, in
    /// [`gs_core::model::BaseModel::group_names`] order (read back from a GPU).
    pub fn param_groups(&mut self) -> Vec<Vec<f32>> {
        match &mut self.state {
            State::Cpu(cpu) => cpu.param_groups(),
            State::Gpu(gpu) => gpu.params.download(&gpu.ctx),
        }
    }

    /// The optimizer state as bytes ([`Adam::save_state`]'s format on every device).
    pub fn save_optimizer(&self) -> Vec<u8> {
        match &self.state {
            State::Cpu(cpu) => cpu.adam().save_state(),
            State::Gpu(gpu) => gpu.adam.save_state(&gpu.ctx),
        }
    }

    /// Restores optimizer state saved on any device ([`Trainer::save_optimizer`]).
    pub fn restore_optimizer(&mut self, bytes: &[u8]) -> Result<(), GsError> {
        match &mut self.state {
            State::Cpu(cpu) => cpu.adam_mut().restore_state(bytes),
            State::Gpu(gpu) => gpu.adam.restore_state(&gpu.ctx, bytes),
        }
    }

    /// The image of `view` over `background` from the model as trained so far (for a run's
    /// live preview, between steps), as [`ModelRenderer::render`] renders it.
    pub fn render(&mut self, view: &View, background: [f32; 3]) -> Result<Image, RenderError> {
        match &mut self.state {
            State::Cpu(cpu) => {
                let forward = cpu.model().forward(view).map_err(RenderError::Model)?;
                Ok(gs_core::raster::render(&forward.gaussians, &view.camera, background).image)
            }
            State::Gpu(gpu) => gpu.render(view, background),
        }
    }

    /// The trained model (its parameters read back from a GPU).
    pub fn into_model(self) -> M {
        match self.state {
            State::Cpu(cpu) => cpu.into_model(),
            State::Gpu(gpu) => {
                let GpuTrainer {
                    ctx,
                    mut model,
                    params,
                    ..
                } = *gpu;
                params.download_into(&ctx, &mut model);
                model
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_adapter_says_what_is_missing() {
        let none = no_adapter_message("none");
        assert!(
            none.contains("libvulkan1") && none.contains("NVIDIA_DRIVER_CAPABILITIES"),
            "{none}"
        );
        let software = no_adapter_message("llvmpipe (Cpu, Vulkan)");
        assert!(
            software.contains("llvmpipe") && software.contains(ALLOW_SOFTWARE_GPU),
            "{software}"
        );
        assert!(none.ends_with("use --device cpu or auto to run on the cpu"));
    }

    #[test]
    fn device_names_parse_and_print_back() {
        for d in [DeviceChoice::Cpu, DeviceChoice::Gpu, DeviceChoice::Auto] {
            assert_eq!(d.to_string().parse::<DeviceChoice>(), Ok(d));
        }
        let e = "cuda".parse::<DeviceChoice>().unwrap_err();
        assert!(e.contains("cuda") && e.contains("cpu, gpu, auto"), "{e}");
        assert_eq!(DeviceChoice::default(), DeviceChoice::Auto);
    }
}
