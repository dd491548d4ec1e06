//! The training loop on the GPU: [`gs_core::train::train`]'s loop (the same sampler, objective,
//! reports, callback and checks) over a model built on the GPU ([`GpuModel::gpu_forward`]),
//! with the parameters, gradients and Adam moments staying there. Per step the image is read
//! back, dL/dimage uploaded, and two `u32`s read (the tile-list size and the finiteness flag);
//! a model on the provided host construction also moves its parameters (when they changed),
//! its Gaussians and their gradient. A GPU failure inside the model is the device's failure.

use std::ops::ControlFlow;

use super::adam::GpuAdam;
use super::backward::backward;
use super::buffers::{read, storage, zeroed_f32};
use super::device::{Binding, GpuContext, GpuError};
use super::forward::render;
use super::memory::{trained_values, training_bytes};
use super::model::{GpuForward, GpuModel, GpuParams, GpuScratch, GpuStep};
use super::shaders::KernelId;
use gs_core::image::Image;
use gs_core::model::{ModelError, View};
use gs_core::raster::{GradMask, OutputGrads};
use gs_core::train::{
    check_groups, run_steps, Objective, StepBackend, StepEnd, StepFailure, StepReport, TrainConfig,
    TrainError, ViewSampler,
};

/// The wgpu backend of the training loop.
struct GpuBackend<'a, M> {
    ctx: &'a GpuContext,
    model: &'a mut M,
    params: &'a GpuParams,
    scratch: GpuScratch,
    adam: &'a mut GpuAdam,
    trained: Vec<bool>,
    mask: GradMask,
    /// The gradient of a one-view step: that view's buffers, as the model handed them.
    single: Option<Vec<Option<wgpu::Buffer>>>,
    /// The summed gradient of a step of several views, every trained group's (`None` for
    /// frozen ones); kept from step to step and cleared at each step's start. A model's
    /// gradient buffers may be its own scratch, rewritten by the next view's backward, so
    /// they are added here rather than kept.
    sum: Option<Vec<Option<wgpu::Buffer>>>,
    /// Views in the current step.
    views: usize,
}

impl<M: GpuModel> StepBackend for GpuBackend<'_, M> {
    type Error = GpuError;

    fn step_count(&self) -> u64 {
        self.adam.step_count()
    }

    fn begin(&mut self, views: usize) -> Result<(), StepFailure<GpuError>> {
        self.views = views;
        self.single = None;
        if views > 1 {
            match &self.sum {
                Some(sum) => {
                    let mut encoder = self.ctx.encoder();
                    for buffer in sum.iter().flatten() {
                        encoder.clear_buffer(buffer, 0, None);
                    }
                    self.ctx.submit(encoder);
                }
                None => {
                    let sum = self
                        .params
                        .lens()
                        .iter()
                        .zip(&self.trained)
                        .map(|(&n, &t)| {
                            t.then(|| zeroed_f32(self.ctx, "summed gradient", n))
                                .transpose()
                        })
                        .collect::<Result<_, _>>()
                        .map_err(StepFailure::Device)?;
                    self.sum = Some(sum);
                }
            }
        }
        Ok(())
    }

    fn accumulate<'g>(
        &mut self,
        view: &View,
        background: [f32; 3],
        evaluate: impl FnOnce(&Image) -> Option<&'g [f32]>,
    ) -> Result<bool, StepFailure<GpuError>> {
        let ctx = self.ctx;
        let mut gpu = GpuStep {
            ctx,
            params: self.params,
            scratch: &mut self.scratch,
        };
        let pixels = view.camera.pixel_count() as u64;
        let lens = self.params.lens();
        let GpuForward { gaussians, tape } = self
            .model
            .gpu_forward(&mut gpu, view)
            .map_err(|e| device_or_model(e, training_bytes(lens, &self.trained, 0, pixels)))?;
        let run_needs = training_bytes(self.params.lens(), &self.trained, gaussians.len(), pixels)
            + self.sum_bytes();
        let needs = |e: GpuError| StepFailure::Device(e.with_run_needs(run_needs));
        let rendered = render(ctx, &gaussians, &view.camera, background).map_err(needs)?;
        let Some(grad) = evaluate(&rendered.image(ctx)) else {
            return Ok(false);
        };
        let out = OutputGrads {
            rgb: grad,
            alpha: None,
            depth: None,
        };
        let grads = backward(ctx, &gaussians, &rendered, &out, self.mask).map_err(needs)?;
        drop(gaussians);
        let mut gpu = GpuStep {
            ctx,
            params: self.params,
            scratch: &mut self.scratch,
        };
        let group_grads = self
            .model
            .gpu_backward(&mut gpu, view, tape, grads, &self.trained)
            .map_err(|e| device_or_model(e, run_needs))?;
        match (&self.sum, self.views) {
            (Some(sum), 2..) => {
                add_into(ctx, &group_grads, sum, self.params.lens()).map_err(needs)?
            }
            _ => self.single = Some(group_grads),
        }
        Ok(true)
    }

    fn apply(&mut self) -> Result<StepEnd, StepFailure<GpuError>> {
        let ctx = self.ctx;
        let single = self.single.take();
        let sum = match (&single, &self.sum) {
            (Some(single), _) => single,
            (None, Some(sum)) => sum,
            (None, None) => unreachable!("a step is applied after at least one view"),
        };
        if !all_finite(ctx, sum, self.params.lens()).map_err(StepFailure::Device)? {
            return Ok(StepEnd::NonFiniteGradient);
        }
        let grad_refs: Vec<Option<&wgpu::Buffer>> = sum.iter().map(Option::as_ref).collect();
        let params: Vec<&wgpu::Buffer> = self.params.buffers().iter().collect();
        self.adam
            .step(ctx, &params, &grad_refs)
            .map_err(StepFailure::Device)?;
        self.params.mark_changed();
        Ok(StepEnd::Taken)
    }
}

impl<M> GpuBackend<'_, M> {
    /// Bytes of the batch's summed gradient (none for a step of one view).
    fn sum_bytes(&self) -> u64 {
        if self.views < 2 {
            return 0;
        }
        4 * trained_values(self.params.lens(), &self.trained)
    }
}

/// Adds every gradient of `grads` (`lens[i]` values of group `i`) to the same group of `sum`.
fn add_into(
    ctx: &GpuContext,
    grads: &[Option<wgpu::Buffer>],
    sum: &[Option<wgpu::Buffer>],
    lens: &[usize],
) -> Result<(), GpuError> {
    let mut encoder = ctx.encoder();
    for ((g, s), &n) in grads.iter().zip(sum).zip(lens) {
        let (Some(g), Some(s)) = (g.as_ref(), s.as_ref()) else {
            continue;
        };
        let n = u32::try_from(n).expect("at most u32::MAX values a group");
        ctx.dispatch_items(
            &mut encoder,
            KernelId::AddInto,
            &[Binding::PerItem(g, 4), Binding::PerItem(s, 4)],
            n,
        )?;
    }
    ctx.submit(encoder);
    Ok(())
}

/// A model's failure as the device's when it is a [`GpuError`] (an allocation that failed, with
/// what the run needs), else as the model's own.
fn device_or_model(e: ModelError, run_needs: u64) -> StepFailure<GpuError> {
    match e.downcast::<GpuError>() {
        Ok(gpu) => StepFailure::Device((*gpu).with_run_needs(run_needs)),
        Err(e) => StepFailure::Model(e),
    }
}

/// True when every value of every gradient (`lens[i]` values of `grads[i]`) is finite.
fn all_finite(
    ctx: &GpuContext,
    grads: &[Option<wgpu::Buffer>],
    lens: &[usize],
) -> Result<bool, GpuError> {
    let flag = storage(ctx, "finiteness flag", 4)?;
    let mut encoder = ctx.encoder();
    for (g, &n) in grads.iter().zip(lens) {
        let Some(g) = g.as_ref() else {
            continue;
        };
        let n = u32::try_from(n).expect("at most u32::MAX values a group");
        ctx.dispatch_items(
            &mut encoder,
            KernelId::CheckFinite,
            &[Binding::PerItem(g, 4), Binding::Whole(&flag)],
            n,
        )?;
    }
    ctx.submit(encoder);
    Ok(read::<u32>(ctx, &flag, 1)[0] == 0)
}

/// Trains `model`, whose parameters are `params` on the GPU of `ctx`, on `views` with
/// `objective` and `adam` until `adam` has taken `config.steps` steps, exactly as
/// [`gs_core::train::train`] does on the cpu (same view order, reports, callback and errors).
/// The parameters stay on the GPU: read them with [`GpuParams::download_into`].
#[allow(clippy::too_many_arguments)]
pub fn train<M, O, F>(
    ctx: &GpuContext,
    model: &mut M,
    params: &GpuParams,
    views: &[View],
    objective: &mut O,
    adam: &mut GpuAdam,
    sampler: &mut ViewSampler,
    config: &TrainConfig,
    on_step: F,
) -> Result<(), TrainError<O::Error>>
where
    M: GpuModel,
    O: Objective,
    F: FnMut(&StepReport) -> ControlFlow<()>,
{
    check_groups(adam.groups().len(), &model.group_names())?;
    if params.lens() != model.group_lens() {
        return Err(TrainError::Mismatch(format!(
            "the parameters on the GPU have groups of {:?} values, the model {:?}",
            params.lens(),
            model.group_lens()
        )));
    }
    let trained: Vec<bool> = adam.groups().iter().map(|g| !g.frozen).collect();
    let mut backend = GpuBackend {
        ctx,
        mask: model.grad_mask(&trained),
        model,
        params,
        scratch: GpuScratch::default(),
        trained,
        adam,
        single: None,
        sum: None,
        views: 0,
    };
    run_steps(&mut backend, views, objective, sampler, config, on_step)
}
