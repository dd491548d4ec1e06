//! The GPU side of a base model: its parameter groups resident on the GPU ([`GpuParams`]),
//! what a model's GPU construction works with in one step ([`GpuStep`]: the device, the
//! parameters, buffers kept from step to step in a [`GpuScratch`]), what it returns
//! ([`GpuForward`]), the GPU twins of a model's forward and backward ([`GpuModel`]), and the
//! provided construction of every model without kernels of its own ([`host_forward`],
//! [`host_backward`]): build on the host, upload, bring the gradient back.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};

use super::backward::GpuGradients;
use super::buffers::{per_item_from, read, GpuGaussians};
use super::device::{GpuContext, GpuError};
use gs_core::gaussians::GaussianSet;
use gs_core::model::{BaseModel, Forward, ModelError, View};

/// The GPU twins of a [`BaseModel`]'s forward and backward. Both are provided: the Gaussians
/// are built on the host and uploaded, and their gradient is brought back ([`host_forward`],
/// [`host_backward`]), so a model trains and renders on a GPU with `impl GpuModel for M {}`;
/// a model overrides them with its own kernels where measurement says they pay.
pub trait GpuModel: BaseModel + Sized {
    /// The GPU twin of [`BaseModel::forward`], from the parameters on the GPU (`gpu.params`;
    /// the host values of `self` may be stale). Provided: brings the parameters back when they
    /// changed, builds on the host and uploads (buffers kept in `gpu.scratch` for the next
    /// step).
    fn gpu_forward(
        &mut self,
        gpu: &mut GpuStep<'_>,
        view: &View,
    ) -> Result<GpuForward<Self::Tape>, ModelError> {
        host_forward(self, gpu, view)
    }

    /// The GPU twin of [`BaseModel::backward`]: the gradient of every group (`None` where
    /// `trained[i]` is false), given `grads` with respect to the Gaussians of
    /// [`GpuModel::gpu_forward`] (which may be handed on without a copy). Provided: brings
    /// the gradient back, runs [`BaseModel::backward`] and uploads the result.
    fn gpu_backward(
        &mut self,
        gpu: &mut GpuStep<'_>,
        view: &View,
        tape: Self::Tape,
        grads: GpuGradients,
        trained: &[bool],
    ) -> Result<Vec<Option<wgpu::Buffer>>, ModelError> {
        host_backward(self, gpu, view, tape, grads, trained)
    }
}

/// Plain 3D Gaussians render their parameters as they are: the GPU forward hands the
/// parameter buffers on, the backward the gradient of the trained arrays.
impl GpuModel for GaussianSet {
    fn gpu_forward(
        &mut self,
        gpu: &mut GpuStep<'_>,
        _view: &View,
    ) -> Result<GpuForward<()>, ModelError> {
        Ok(GpuForward::untaped(
            gpu.params.as_gaussians(self.sh_degree()),
        ))
    }

    fn gpu_backward(
        &mut self,
        _gpu: &mut GpuStep<'_>,
        _view: &View,
        _tape: (),
        grads: GpuGradients,
        trained: &[bool],
    ) -> Result<Vec<Option<wgpu::Buffer>>, ModelError> {
        Ok(grads.into_trained(trained))
    }
}

/// A model's parameter groups on the GPU, one buffer per group in
/// [`BaseModel::group_names`] order: uploaded once, read back on request (checkpoints,
/// outputs, and the host construction of a model without kernels when they changed).
pub struct GpuParams {
    buffers: Vec<wgpu::Buffer>,
    lens: Vec<usize>,
    /// True while the host model holds the values on the GPU (after an upload or a download,
    /// until the optimizer steps).
    host_current: AtomicBool,
}

impl GpuParams {
    /// Uploads the parameter groups of `model` (mutable access is how [`BaseModel`] lends
    /// them; nothing is changed).
    pub fn upload<M: BaseModel>(ctx: &GpuContext, model: &mut M) -> Result<Self, GpuError> {
        let names = model.group_names();
        let mut buffers = Vec::with_capacity(names.len());
        let mut lens = Vec::with_capacity(names.len());
        for (name, values) in names.iter().zip(model.groups_mut()) {
            buffers.push(per_item_from(ctx, &format!("parameters {name}"), values)?);
            lens.push(values.len());
        }
        Ok(Self {
            buffers,
            lens,
            host_current: AtomicBool::new(true),
        })
    }

    /// Reads every group back, in group order.
    pub fn download(&self, ctx: &GpuContext) -> Vec<Vec<f32>> {
        self.buffers
            .iter()
            .zip(&self.lens)
            .map(|(b, &n)| read(ctx, b, n))
            .collect()
    }

    /// Copies the values on the GPU into `model`'s groups.
    ///
    /// # Panics
    /// If `model` is not the model uploaded (its group sizes differ).
    pub fn download_into<M: BaseModel>(&self, ctx: &GpuContext, model: &mut M) {
        for (dst, values) in model.groups_mut().into_iter().zip(self.download(ctx)) {
            dst.copy_from_slice(&values);
        }
        self.host_current.store(true, Ordering::Release);
    }

    /// Brings the values into `model` only when they changed since the last upload or
    /// download ([`GpuParams::mark_changed`]).
    pub fn sync_host<M: BaseModel>(&self, ctx: &GpuContext, model: &mut M) {
        if !self.host_current.load(Ordering::Acquire) {
            self.download_into(ctx, model);
        }
    }

    /// Records that the values on the GPU changed (the optimizer stepped).
    pub fn mark_changed(&self) {
        self.host_current.store(false, Ordering::Release);
    }

    /// The six groups of a plain Gaussian set of SH degree `sh_degree`, as its rendered
    /// Gaussians (the buffers are shared, not copied).
    ///
    /// # Panics
    /// If there are not six groups.
    pub fn as_gaussians(&self, sh_degree: usize) -> GpuGaussians {
        let arrays: [wgpu::Buffer; 6] = self
            .buffers
            .clone()
            .try_into()
            .expect("six parameter groups");
        GpuGaussians::from_buffers(self.lens[3], sh_degree, arrays)
    }

    /// The group buffers, in group order.
    pub fn buffers(&self) -> &[wgpu::Buffer] {
        &self.buffers
    }

    /// The number of values of each group.
    pub fn lens(&self) -> &[usize] {
        &self.lens
    }
}

/// GPU buffers a model keeps from one step to the next (its per-view outputs, uniforms),
/// by name: a buffer is made again only when its size changes.
#[derive(Default)]
pub struct GpuScratch {
    buffers: HashMap<&'static str, (u64, wgpu::Buffer)>,
    /// The host-built Gaussians of the provided construction.
    uploaded: Option<GpuGaussians>,
}

impl GpuScratch {
    /// The buffer `name` of `bytes` bytes: the one kept from an earlier step when its size is
    /// the same, else a new one from `make` (kept for the next step). Its contents are
    /// whatever was last written.
    pub fn buffer(
        &mut self,
        name: &'static str,
        bytes: u64,
        make: impl FnOnce() -> Result<wgpu::Buffer, GpuError>,
    ) -> Result<wgpu::Buffer, GpuError> {
        match self.buffers.get(name) {
            Some((size, buffer)) if *size == bytes => Ok(buffer.clone()),
            _ => {
                let buffer = make()?;
                self.buffers.insert(name, (bytes, buffer.clone()));
                Ok(buffer)
            }
        }
    }
}

/// What a model's GPU construction works with in one step.
pub struct GpuStep<'a> {
    /// The device.
    pub ctx: &'a GpuContext,
    /// The model's parameters on the device.
    pub params: &'a GpuParams,
    /// Buffers kept from step to step.
    pub scratch: &'a mut GpuScratch,
}

/// What [`GpuModel::gpu_forward`] returns: the Gaussians of a view on the GPU and the tape
/// its backward consumes.
pub struct GpuForward<T> {
    /// The Gaussians to render.
    pub gaussians: GpuGaussians,
    /// What the backward of the same step needs.
    pub tape: T,
}

impl GpuForward<()> {
    /// Gaussians that need no tape.
    pub fn untaped(gaussians: GpuGaussians) -> Self {
        Self {
            gaussians,
            tape: (),
        }
    }
}

/// The provided [`GpuModel::gpu_forward`]: the parameters brought back when they changed,
/// [`BaseModel::forward`] on the host, the Gaussians uploaded (into the buffers of the last
/// step when the count and degree are the same).
pub fn host_forward<M: BaseModel>(
    model: &mut M,
    gpu: &mut GpuStep<'_>,
    view: &View,
) -> Result<GpuForward<M::Tape>, ModelError> {
    gpu.params.sync_host(gpu.ctx, model);
    let Forward { gaussians, tape } = model.forward(view)?;
    let reusable = gpu
        .scratch
        .uploaded
        .as_ref()
        .is_some_and(|g| (g.len(), g.sh_degree()) == (gaussians.len(), gaussians.sh_degree()));
    if reusable {
        let kept = gpu.scratch.uploaded.as_ref().expect("checked above");
        kept.write(gpu.ctx, &gaussians);
    } else {
        gpu.scratch.uploaded = Some(GpuGaussians::upload(gpu.ctx, &gaussians)?);
    }
    let uploaded = gpu.scratch.uploaded.as_ref().expect("set above");
    Ok(GpuForward {
        gaussians: uploaded.clone(),
        tape,
    })
}

/// The provided [`GpuModel::gpu_backward`]: the gradient with respect to the Gaussians
/// brought back, [`BaseModel::backward`] on the host, the trained groups' gradients uploaded.
pub fn host_backward<M: BaseModel>(
    model: &mut M,
    gpu: &mut GpuStep<'_>,
    view: &View,
    tape: M::Tape,
    grads: GpuGradients,
    trained: &[bool],
) -> Result<Vec<Option<wgpu::Buffer>>, ModelError> {
    let gaussian_grads = grads.download(gpu.ctx).gaussians;
    let mut out: Vec<Vec<f32>> = gpu
        .params
        .lens()
        .iter()
        .zip(trained)
        .map(|(&n, &t)| if t { vec![0.0; n] } else { Vec::new() })
        .collect();
    model.backward(view, tape, &gaussian_grads, trained, &mut out)?;
    out.iter()
        .zip(trained)
        .map(|(g, &t)| {
            t.then(|| per_item_from(gpu.ctx, "model gradient", g))
                .transpose()
                .map_err(Into::into)
        })
        .collect()
}

/// The Gaussians of `model` for `view` on the GPU, for a caller that renders without
/// training (nothing steps the parameters, so the host values stay current).
pub(crate) fn gaussians_for_view<M: GpuModel>(
    model: &mut M,
    ctx: &GpuContext,
    params: &GpuParams,
    scratch: &mut GpuScratch,
    view: &View,
) -> Result<GpuGaussians, ModelError> {
    let mut gpu = GpuStep {
        ctx,
        params,
        scratch,
    };
    Ok(model.gpu_forward(&mut gpu, view)?.gaussians)
}
