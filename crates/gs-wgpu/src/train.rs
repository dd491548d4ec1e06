//! One training step on the GPU ([`GpuTrainer::step`]): gs-core's `CpuTrainer::step` (the
//! same render, objective, backward and Adam, the same checks and report) over a model built on
//! the GPU ([`GpuModel::gpu_forward`]), with the parameters, gradients and Adam moments staying
//! there. A photometric objective ([`Objective::photometric`]) is evaluated on the device too,
//! its targets uploaded once and kept in the objective: per step only its partial sums are
//! read back, with two `u32`s (the tile-list size and the finiteness flag); any other objective
//! gets the image read back and its dL/dimage uploaded. A model on the provided host construction also moves its
//! parameters (when they changed), its Gaussians and their gradient. A GPU failure inside the
//! model is the device's failure.

use std::sync::Arc;
use std::time::Instant;

use super::adam::GpuAdam;
use super::backward::{backward_on_device, DeviceOutputGrads, GpuScreenStats};
use super::buffers::{read, storage, storage_from, zeroed_f32};
use super::device::{Binding, GpuContext, GpuError};
use super::forward::render;
use super::memory::{trained_values, training_bytes};
use super::model::{GpuForward, GpuModel, GpuParams, GpuScratch, GpuStep};
use super::photometric::{photometric, GpuTargets, PHOTOMETRIC_PIXEL_BYTES};
use super::shaders::KernelId;
use gs_core::adam::{AdamHyper, GroupConfig};
use gs_core::densify::ScreenStats;
use gs_core::model::{ModelError, View};
use gs_core::raster::GradMask;
use gs_core::sampler::Batch;
use gs_core::train::{check_batch, checked_value, Objective, StepReport, StepTimes, TrainError};
use gs_core::GsError;

/// A model whose parameters and Adam moments live on one GPU, trained a step at a time.
pub(crate) struct GpuTrainer<M> {
    pub(crate) ctx: Arc<GpuContext>,
    pub(crate) model: M,
    pub(crate) params: GpuParams,
    pub(crate) adam: GpuAdam,
    scratch: GpuScratch,
    trained: Vec<bool>,
    mask: GradMask,
    /// The summed gradient of a step of several views, every trained group's (`None` for
    /// frozen ones); made at the first such step, cleared at each one's start. A model's
    /// gradient buffers may be its own scratch, rewritten by the next view's backward, so
    /// they are added here rather than kept.
    sum: Option<Vec<Option<wgpu::Buffer>>>,
    /// The rendered Gaussians' densification statistics, gathered on the device when asked.
    pub(crate) screen_stats: Option<GpuScreenStats>,
}

impl<M: GpuModel> GpuTrainer<M> {
    /// The image of `view` over `background` from the parameters as they are now (between
    /// steps; the step's scratch buffers are rebuilt by the next step).
    pub(crate) fn render(
        &mut self,
        view: &gs_core::model::View,
        background: [f32; 3],
    ) -> Result<gs_core::Image, crate::backend::RenderError> {
        let gaussians = crate::model::gaussians_for_view(
            &mut self.model,
            &self.ctx,
            &self.params,
            &mut self.scratch,
            view,
        )
        .map_err(|e| match e.downcast::<GpuError>() {
            Ok(gpu) => crate::backend::RenderError::from(*gpu),
            Err(e) => crate::backend::RenderError::Model(e),
        })?;
        Ok(
            crate::forward::render(&self.ctx, &gaussians, &view.camera, background)?
                .image(&self.ctx),
        )
    }

    /// `model` uploaded to `ctx` with a fresh Adam over `groups`, one per parameter group in
    /// the model's order.
    pub(crate) fn new(
        ctx: Arc<GpuContext>,
        mut model: M,
        groups: Vec<GroupConfig>,
        hyper: AdamHyper,
    ) -> Result<Self, GpuError> {
        let lens = model.group_lens();
        let trained: Vec<bool> = groups.iter().map(|g| !g.frozen).collect();
        let needs = |e: GpuError| e.with_run_needs(training_bytes(&lens, &trained, 0, 0));
        let params = GpuParams::upload(&ctx, &mut model).map_err(needs)?;
        let adam = GpuAdam::new(&ctx, groups, &lens, hyper).map_err(needs)?;
        Ok(Self {
            mask: model.grad_mask(&trained),
            ctx,
            model,
            params,
            adam,
            scratch: GpuScratch::default(),
            trained,
            sum: None,
            screen_stats: None,
        })
    }

    /// One step over the views `batch` names of `views`, composited over `background`, as
    /// gs-core's `CpuTrainer::step`: for each view, render, the objective's value and
    /// dL/dimage, backward (into the step's sum when there are several views); then Adam on
    /// the gradient unless a value of it is not finite.
    pub(crate) fn step<O: Objective>(
        &mut self,
        views: &[View],
        batch: Batch,
        background: [f32; 3],
        objective: &mut O,
    ) -> Result<StepReport, TrainError<O::Error>> {
        check_batch(&batch, views.len())?;
        let step = self.adam.step_count() + 1;
        let ctx = Arc::clone(&self.ctx);
        let ctx = ctx.as_ref();
        let lens = self.params.lens().to_vec();
        let several = batch.views.len() > 1;
        if several {
            self.clear_sum().map_err(|e| device_failed(step, e))?;
        }
        let sum_bytes = if several {
            4 * trained_values(&lens, &self.trained)
        } else {
            0
        };
        // A photometric objective runs on the device, its targets uploaded once (kept in the
        // objective) and checked against the step's cameras before any work.
        let device_loss = match objective.photometric() {
            Some(form) => {
                let targets = GpuTargets::of(&self.ctx, &form);
                let targets = targets.map_err(|e| device_failed(step, e))?;
                for &index in &batch.views {
                    device_target(&targets, index, &views[index].camera)?;
                }
                Some((form.lambda, form.clamp, targets))
            }
            None => None,
        };
        let loss_bytes = device_loss.as_ref().map_or(0, |(_, _, t)| t.bytes());
        let mut single = None;
        let mut times = StepTimes::default();
        let mut values = Vec::with_capacity(batch.views.len());
        for &index in &batch.views {
            let view = &views[index];
            let pixels = view.camera.pixel_count() as u64;
            // Render.
            let t0 = Instant::now();
            let mut gpu = GpuStep {
                ctx,
                params: &self.params,
                scratch: &mut self.scratch,
            };
            let GpuForward { gaussians, tape } =
                self.model.gpu_forward(&mut gpu, view).map_err(|e| {
                    model_failed(step, e, training_bytes(&lens, &self.trained, 0, pixels))
                })?;
            let mut run_needs =
                training_bytes(&lens, &self.trained, gaussians.len(), pixels) + sum_bytes;
            if loss_bytes > 0 {
                run_needs += loss_bytes + PHOTOMETRIC_PIXEL_BYTES * pixels;
            }
            let needs = |e: GpuError| device_failed(step, e.with_run_needs(run_needs));
            if let Some(stats) = &self.screen_stats {
                ScreenStats::check_rendered(stats.len(), gaussians.len()).map_err(|e| {
                    TrainError::Model {
                        step,
                        source: e.into(),
                    }
                })?;
            }
            let rendered = render(ctx, &gaussians, &view.camera, background).map_err(needs)?;
            // The loss and its image gradient.
            let t1 = Instant::now();
            let (value, grad_rgb) = match &device_loss {
                Some((lambda, clamp, targets)) => {
                    let (lambda, clamp) = (*lambda, *clamp);
                    let target = device_target(targets, index, &view.camera)?;
                    let factor = 1.0 / batch.divisor.max(1) as f32;
                    let evaluated = photometric(ctx, &rendered, target, lambda, clamp, factor)
                        .map_err(needs)?;
                    let value = objective.device_value(index, &evaluated.sums);
                    // dL/dimage is on the device, already divided by the batch's divisor; its
                    // values were checked there.
                    let value = checked_value(step, index, Ok(value), 1)?;
                    if evaluated.non_finite_grads > 0 {
                        return Err(TrainError::NonFinite {
                            step,
                            view: index,
                            what: "dL/dimage",
                        });
                    }
                    (value, evaluated.grad)
                }
                None => {
                    let image = rendered.image(ctx);
                    let result = objective.evaluate(index, &image);
                    let value = checked_value(step, index, result, batch.divisor)?;
                    let grad = storage_from(ctx, "dL/dRGB", &value.grad).map_err(needs)?;
                    (value, grad)
                }
            };
            // Backward, through the rasterizer and the model.
            let t2 = Instant::now();
            let out = DeviceOutputGrads {
                rgb: &grad_rgb,
                alpha: None,
                depth: None,
            };
            let stats = self.screen_stats.as_ref();
            let grads = backward_on_device(ctx, &gaussians, &rendered, &out, self.mask, stats)
                .map_err(needs)?;
            drop(gaussians);
            let mut gpu = GpuStep {
                ctx,
                params: &self.params,
                scratch: &mut self.scratch,
            };
            let group_grads = self
                .model
                .gpu_backward(&mut gpu, view, tape, grads, &self.trained)
                .map_err(|e| model_failed(step, e, run_needs))?;
            match &self.sum {
                Some(sum) if several => add_into(ctx, &group_grads, sum, &lens).map_err(needs)?,
                _ => single = Some(group_grads),
            }
            times.add_view(t0, t1, t2, Instant::now());
            values.push(value);
        }
        // The optimizer, unless a gradient is not finite.
        let t3 = Instant::now();
        let grads = match (&single, &self.sum) {
            (Some(single), _) => single,
            (None, Some(sum)) => sum,
            (None, None) => unreachable!("a step has at least one view (check_batch)"),
        };
        if !all_finite(ctx, grads, &lens).map_err(|e| device_failed(step, e))? {
            return Err(TrainError::NonFinite {
                step,
                view: batch.views[0],
                what: "parameter gradient",
            });
        }
        let grad_refs: Vec<Option<&wgpu::Buffer>> = grads.iter().map(Option::as_ref).collect();
        let params: Vec<&wgpu::Buffer> = self.params.buffers().iter().collect();
        self.adam
            .step(ctx, &params, &grad_refs)
            .map_err(|e| device_failed(step, e))?;
        self.params.mark_changed();
        times.backward += t3.elapsed();
        Ok(StepReport::new(step, batch, &values, times))
    }

    /// Zeroes the summed gradient of a step of several views, making it at the first.
    fn clear_sum(&mut self) -> Result<(), GpuError> {
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
                        t.then(|| zeroed_f32(&self.ctx, "summed gradient", n))
                            .transpose()
                    })
                    .collect::<Result<_, _>>()?;
                self.sum = Some(sum);
            }
        }
        Ok(())
    }
}

/// The target of view `view` on the device, or, when there is none or its size is not the
/// camera's, a mismatch naming what gs-core's objective names (which fails at its evaluation
/// on the cpu, as `TrainError::Objective`: here before any work of the step).
fn device_target<'a, E: std::error::Error>(
    targets: &'a GpuTargets,
    view: usize,
    camera: &gs_core::Camera,
) -> Result<&'a wgpu::Buffer, TrainError<E>> {
    let Some((width, height, buffer)) = targets.get(view) else {
        return Err(TrainError::Mismatch(format!(
            "the objective has no target for view {view}"
        )));
    };
    if (*width, *height) != (camera.width, camera.height) {
        let e = GsError::SizeMismatch {
            view,
            render_w: camera.width,
            render_h: camera.height,
            target_w: *width,
            target_h: *height,
        };
        return Err(TrainError::Mismatch(e.to_string()));
    }
    Ok(buffer)
}

/// The GPU's failure at step `step`.
fn device_failed<E: std::error::Error>(step: u64, e: GpuError) -> TrainError<E> {
    TrainError::Device {
        step,
        source: Box::new(e),
    }
}

/// A model's failure at step `step`: the device's when it is a [`GpuError`] (an allocation
/// that failed, with `run_needs`, what the run needs), else the model's own.
fn model_failed<E: std::error::Error>(step: u64, e: ModelError, run_needs: u64) -> TrainError<E> {
    match e.downcast::<GpuError>() {
        Ok(gpu) => device_failed(step, (*gpu).with_run_needs(run_needs)),
        Err(source) => TrainError::Model { step, source },
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
