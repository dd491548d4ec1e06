//! One training step, and the cpu backend's: for each view of a [`Batch`], build its
//! Gaussians and render them, ask the [`Objective`] for the loss and dL/dimage, back-propagate
//! through the rasterizer and the base model into the step's summed gradient; then one Adam
//! step. [`CpuTrainer::step`] is that step on the cpu; gs-wgpu's `Trainer::step` is the same
//! step on either device, and a run is a loop over it.

use std::time::{Duration, Instant};

use crate::adam::Adam;
use crate::densify::ScreenStats;
use crate::error::GsError;
use crate::image::Image;
use crate::image_loss::{PhotometricForm, PhotometricSums};
use crate::model::{BaseModel, Forward, ModelError, View};
use crate::raster::{self, GradMask, OutputGrads};
use crate::sampler::{Batch, ViewSampler};

/// What an objective returns for one rendered view.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectiveValue {
    /// The total loss.
    pub loss: f32,
    /// Named terms of the loss (already weighted), for logs.
    pub terms: Vec<(String, f32)>,
    /// dL/d(image), `[H, W, 3]`.
    pub grad: Vec<f32>,
}

/// The loss of one step: its objective's values summed over the step's views and divided by
/// the batch's divisor (their mean, except for a short last batch of
/// [`crate::sampler::BatchOrder::Consecutive`]).
#[derive(Clone, Debug, PartialEq)]
pub struct StepValue {
    /// The total loss.
    pub loss: f32,
    /// Named terms of the loss (already weighted), for logs.
    pub terms: Vec<(String, f32)>,
}

impl StepValue {
    /// The sums of the losses and of each named term of `values` divided by `divisor` (the
    /// terms of the first value, in its order; a term another value lacks counts as 0 there).
    fn divided(values: &[ObjectiveValue], divisor: usize) -> Self {
        let n = divisor.max(1) as f32;
        let Some(first) = values.first() else {
            return Self {
                loss: 0.0,
                terms: Vec::new(),
            };
        };
        let terms = first
            .terms
            .iter()
            .map(|(name, _)| {
                let sum: f32 = values
                    .iter()
                    .filter_map(|v| v.terms.iter().find(|(n, _)| n == name))
                    .map(|(_, x)| x)
                    .sum();
                (name.clone(), sum / n)
            })
            .collect();
        Self {
            loss: values.iter().map(|v| v.loss).sum::<f32>() / n,
            terms,
        }
    }
}

/// A loss on rendered images: given the view index and the render, the loss and its gradient.
pub trait Objective {
    /// Error type of the objective.
    type Error: std::error::Error + Send + Sync + 'static;
    /// Evaluates the loss of `image`, the render of view `view`.
    fn evaluate(&mut self, view: usize, image: &Image) -> Result<ObjectiveValue, Self::Error>;

    /// This objective as a photometric loss that a GPU evaluates where the render lives, reading
    /// back its sums alone ([`Objective::device_value`] is then called instead of
    /// [`Objective::evaluate`]); `None` (the default): every render is brought to `evaluate`.
    fn photometric(&self) -> Option<PhotometricForm<'_>> {
        None
    }

    /// The value of view `view` from the sums a device computed of [`Objective::photometric`]
    /// (dL/dimage stays on the device); the default is the photometric loss's.
    fn device_value(&mut self, view: usize, sums: &PhotometricSums) -> ObjectiveValue {
        let _ = view;
        sums.value(self.photometric().map_or(0.0, |form| form.lambda))
    }
}

/// Settings of a loop of steps (gs-wgpu's `Trainer::train`).
#[derive(Clone, Debug, PartialEq)]
pub struct TrainConfig {
    /// Total number of steps; the loop stops when the optimizer has taken this many. A step
    /// renders the views of one batch of the sampler ([`ViewSampler::next_batch`]).
    pub steps: u64,
    /// Background colour renders are composited over.
    pub background: [f32; 3],
}

/// What one step did.
#[derive(Clone, Debug)]
pub struct StepReport {
    /// Steps completed, 1-based: this step's number.
    pub step: u64,
    /// Index of the (first) view used.
    pub view: usize,
    /// Indices of the step's views, in the order they were rendered.
    pub batch: Vec<usize>,
    /// The objective's value over the step's views (summed, divided by the batch's divisor).
    pub value: StepValue,
    /// Time spent rendering (forward), over the step's views.
    pub render_time: Duration,
    /// Time spent in the objective, over the step's views.
    pub objective_time: Duration,
    /// Time spent in the backward passes and the optimizer step, over the step's views.
    pub backward_time: Duration,
}

/// Time spent in the phases of one step, summed over its views.
#[derive(Clone, Copy, Debug, Default)]
pub struct StepTimes {
    /// Rendering (the model's forward and the rasterizer).
    pub render: Duration,
    /// The objective.
    pub objective: Duration,
    /// The backward passes and the optimizer step.
    pub backward: Duration,
}

impl StepTimes {
    /// Adds one view's phases, timed at `t0` (before the render), `t1` (render done), `t2`
    /// (objective done) and `t3` (backward done).
    pub fn add_view(&mut self, t0: Instant, t1: Instant, t2: Instant, t3: Instant) {
        self.render += t1 - t0;
        self.objective += t2 - t1;
        self.backward += t3 - t2;
    }
}

impl StepReport {
    /// The report of step `step` over `batch`, whose views' objective values are `values`.
    pub fn new(step: u64, batch: Batch, values: &[ObjectiveValue], times: StepTimes) -> Self {
        Self {
            step,
            view: batch.views[0],
            value: StepValue::divided(values, batch.divisor),
            batch: batch.views,
            render_time: times.render,
            objective_time: times.objective,
            backward_time: times.backward,
        }
    }
}

/// Why a step failed; the parameters are those of the step before.
#[derive(Debug, thiserror::Error)]
pub enum TrainError<E: std::error::Error + 'static> {
    /// The pieces given do not fit together; nothing was trained.
    #[error("cannot train: {0}")]
    Mismatch(String),
    /// The objective failed.
    #[error("objective failed at step {step}: {source}")]
    Objective {
        /// Step (1-based) at which it failed.
        step: u64,
        /// The objective's error.
        source: E,
    },
    /// A loss or gradient was NaN or infinite; the parameters were left as they were before it.
    #[error("non-finite {what} at step {step} (view {view}); parameters are unchanged from the step before")]
    NonFinite {
        /// Step (1-based).
        step: u64,
        /// The view.
        view: usize,
        /// What was not finite.
        what: &'static str,
    },
    /// The base model failed to build or differentiate a view's Gaussians.
    #[error("the model failed at step {step}: {source}")]
    Model {
        /// Step (1-based) at which it failed.
        step: u64,
        /// The model's error.
        source: ModelError,
    },
    /// The compute device failed (e.g. the GPU ran out of memory).
    #[error("device failed at step {step}: {source}")]
    Device {
        /// Step (1-based) at which it failed.
        step: u64,
        /// The device's error.
        source: Box<dyn std::error::Error + Send + Sync>,
    },
}

/// Checks that every view of `batch` is one of `views` views.
pub fn check_batch<E: std::error::Error>(batch: &Batch, views: usize) -> Result<(), TrainError<E>> {
    match batch.views.iter().find(|&&v| v >= views) {
        _ if batch.views.is_empty() => Err(TrainError::Mismatch("a step of no view".into())),
        Some(v) => Err(TrainError::Mismatch(format!(
            "the step draws view {v} but {views} views were given"
        ))),
        None => Ok(()),
    }
}

/// Checks that a sampler draws from the `views` views given to a loop of steps.
pub fn check_sampler<E: std::error::Error>(
    sampler: &ViewSampler,
    views: usize,
) -> Result<(), TrainError<E>> {
    if sampler.count() != views {
        return Err(TrainError::Mismatch(format!(
            "the view sampler draws from {} views but {views} were given",
            sampler.count(),
        )));
    }
    Ok(())
}

/// The objective's `result` for view `view` of step `step`, checked (an error, a non-finite
/// loss or dL/dimage stop the step) and with dL/dimage divided by `divisor`, the batch's: the
/// step's losses are summed and divided by it, so the summed parameter gradient is the loss's
/// (exactly as it is for one view).
pub fn checked_value<E: std::error::Error>(
    step: u64,
    view: usize,
    result: Result<ObjectiveValue, E>,
    divisor: usize,
) -> Result<ObjectiveValue, TrainError<E>> {
    let non_finite = |what| TrainError::NonFinite { step, view, what };
    let mut value = result.map_err(|source| TrainError::Objective { step, source })?;
    if !value.loss.is_finite() {
        return Err(non_finite("loss"));
    }
    if !value.grad.iter().all(|g| g.is_finite()) {
        return Err(non_finite("dL/dimage"));
    }
    if divisor > 1 {
        let scale = 1.0 / divisor as f32;
        value.grad.iter_mut().for_each(|g| *g *= scale);
    }
    Ok(value)
}

/// Checks that an optimizer of `optimizer_groups` groups fits a model with `names`.
fn check_groups(optimizer_groups: usize, names: &[String]) -> Result<(), GsError> {
    if optimizer_groups != names.len() {
        return Err(GsError::OptimizerState(format!(
            "the optimizer has {} parameter groups, the model {} ({})",
            optimizer_groups,
            names.len(),
            names.join(", ")
        )));
    }
    Ok(())
}

/// A model and its [`Adam`] on the cpu, trained a step at a time ([`CpuTrainer::step`]) with
/// the rayon rasterizer.
#[derive(Debug)]
pub struct CpuTrainer<M> {
    model: M,
    adam: Adam,
    /// Whether each group is trained (not frozen).
    trained: Vec<bool>,
    /// Which Gaussian gradients the rasterizer's backward computes.
    mask: GradMask,
    /// The step's summed gradient of every group (empty for frozen groups), zero between steps.
    sum: Vec<Vec<f32>>,
    /// The rendered Gaussians' densification statistics, when gathered.
    screen_stats: Option<ScreenStats>,
}

impl<M: BaseModel> CpuTrainer<M> {
    /// `model` trained by `adam`, whose groups are the model's in
    /// [`BaseModel::group_names`] order ([`crate::adam::groups_in_model_order`]); a restored
    /// `adam` continues its run.
    pub fn new(model: M, adam: Adam) -> Result<Self, GsError> {
        check_groups(adam.groups().len(), &model.group_names())?;
        let trained: Vec<bool> = adam.groups().iter().map(|g| !g.frozen).collect();
        let sum = model
            .group_lens()
            .iter()
            .zip(&trained)
            .map(|(&n, &t)| if t { vec![0.0; n] } else { Vec::new() })
            .collect();
        Ok(Self {
            mask: model.grad_mask(&trained),
            model,
            adam,
            trained,
            sum,
            screen_stats: None,
        })
    }

    /// From the next step on, adds every view's view-space gradients of the rendered Gaussians
    /// to `stats` ([`ScreenStats::add_view`]; one entry per rendered Gaussian).
    pub fn gather_screen_stats(&mut self, stats: ScreenStats) {
        self.screen_stats = Some(stats);
    }

    /// The statistics gathered since [`CpuTrainer::gather_screen_stats`], which stops.
    pub fn take_screen_stats(&mut self) -> Option<ScreenStats> {
        self.screen_stats.take()
    }

    /// One step over the views `batch` names of `views`, composited over `background`: for
    /// each view, render, the objective's value and dL/dimage, backward into the step's sum;
    /// then Adam on the sum. A non-finite loss, dL/dimage or parameter gradient stops it with
    /// the parameters as they were.
    pub fn step<O: Objective>(
        &mut self,
        views: &[View],
        batch: Batch,
        background: [f32; 3],
        objective: &mut O,
    ) -> Result<StepReport, TrainError<O::Error>> {
        check_batch(&batch, views.len())?;
        let step = self.adam.step_count() + 1;
        let model_failed = |source| TrainError::Model { step, source };
        let mut times = StepTimes::default();
        let mut values = Vec::with_capacity(batch.views.len());
        for &index in &batch.views {
            let view = &views[index];
            // Render.
            let t0 = Instant::now();
            let Forward { gaussians, tape } = self.model.forward(view).map_err(model_failed)?;
            if let Some(stats) = &self.screen_stats {
                ScreenStats::check_rendered(stats.len(), gaussians.len())
                    .map_err(|e| model_failed(ModelError::from(e)))?;
            }
            let rendered = raster::render(gaussians.as_ref(), &view.camera, background);
            // The loss and its image gradient.
            let t1 = Instant::now();
            let result = objective.evaluate(index, &rendered.image);
            let value = checked_value(step, index, result, batch.divisor)?;
            // Backward, through the rasterizer and the model, into the step's sum.
            let t2 = Instant::now();
            let out = OutputGrads {
                rgb: &value.grad,
                alpha: None,
                depth: None,
            };
            let (grads, screen) = raster::backward_with_screen_grads(
                gaussians.as_ref(),
                &view.camera,
                &rendered,
                &out,
                self.mask,
            );
            if let Some(stats) = &mut self.screen_stats {
                let size = (view.camera.width, view.camera.height);
                stats.add_view(&rendered, &screen, size);
            }
            drop(gaussians);
            self.model
                .backward(view, tape, &grads.gaussians, &self.trained, &mut self.sum)
                .map_err(model_failed)?;
            times.add_view(t0, t1, t2, Instant::now());
            values.push(value);
        }
        // The optimizer, unless a gradient is not finite.
        let t3 = Instant::now();
        let finite = self.sum.iter().flatten().all(|g| g.is_finite());
        if finite {
            let grads: Vec<&[f32]> = self.sum.iter().map(|g| g.as_slice()).collect();
            self.adam.step(&mut self.model.groups_mut(), &grads);
        }
        self.sum.iter_mut().for_each(|g| g.fill(0.0));
        if !finite {
            return Err(TrainError::NonFinite {
                step,
                view: batch.views[0],
                what: "parameter gradient",
            });
        }
        times.backward += t3.elapsed();
        Ok(StepReport::new(step, batch, &values, times))
    }

    /// Steps the optimizer has taken.
    pub fn step_count(&self) -> u64 {
        self.adam.step_count()
    }

    /// The model, with the parameters of the last step.
    pub fn model(&self) -> &M {
        &self.model
    }

    /// The optimizer.
    pub fn adam(&self) -> &Adam {
        &self.adam
    }

    /// The optimizer, to restore saved state into.
    pub fn adam_mut(&mut self) -> &mut Adam {
        &mut self.adam
    }

    /// The current values of every parameter group, in [`BaseModel::group_names`] order.
    pub fn param_groups(&mut self) -> Vec<Vec<f32>> {
        self.model
            .groups_mut()
            .into_iter()
            .map(|g| g.to_vec())
            .collect()
    }

    /// The trained model.
    pub fn into_model(self) -> M {
        self.model
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::adam::{AdamHyper, GroupConfig, LrSchedule};
    use crate::camera::Camera;
    use crate::gaussians::{GaussianSet, PARAM_NAMES};
    use crate::sampler::BatchOrder;

    /// An objective whose gradient turns NaN at a chosen call.
    struct PoisonAt(usize, usize);

    impl Objective for PoisonAt {
        type Error = std::io::Error;
        fn evaluate(&mut self, _view: usize, image: &Image) -> Result<ObjectiveValue, Self::Error> {
            self.0 += 1;
            let bad = self.0 == self.1;
            Ok(ObjectiveValue {
                loss: 1.0,
                terms: Vec::new(),
                grad: vec![if bad { f32::NAN } else { 0.01 }; image.data.len()],
            })
        }
    }

    /// Steps of `trainer` over `views` drawn by `sampler` until it has taken `steps`, or the
    /// first error.
    fn run<M: BaseModel, O: Objective>(
        trainer: &mut CpuTrainer<M>,
        views: &[View],
        sampler: &mut ViewSampler,
        objective: &mut O,
        steps: u64,
    ) -> Result<Vec<StepReport>, TrainError<O::Error>> {
        let mut reports = Vec::new();
        while trainer.step_count() < steps {
            reports.push(trainer.step(views, sampler.next_batch(), [0.0; 3], objective)?);
        }
        Ok(reports)
    }

    #[test]
    fn a_nan_gradient_stops_the_run_with_the_parameters_of_the_step_before() {
        let cam =
            Camera::look_at([0.0, 0.0, -3.0], [0.0; 3], [0.0, -1.0, 0.0], 1.0, 16, 16).unwrap();
        let views = vec![View::still(cam)];
        let mut model = GaussianSet::zeros(4, 0);
        for (i, m) in model.means.chunks_mut(3).enumerate() {
            m[0] = 0.1 * i as f32;
        }
        let groups: Vec<GroupConfig> = PARAM_NAMES
            .iter()
            .map(|n| GroupConfig::new(*n, LrSchedule::Constant(0.01)))
            .collect();
        let train = |steps: u64, poison: usize| {
            let adam = Adam::new(groups.clone(), &model.group_lens(), AdamHyper::default());
            let mut trainer = CpuTrainer::new(model.clone(), adam).unwrap();
            let mut sampler = ViewSampler::new(1, 0);
            let result = run(
                &mut trainer,
                &views,
                &mut sampler,
                &mut PoisonAt(0, poison),
                steps,
            );
            (trainer.step_count(), trainer.into_model(), result)
        };
        let (steps_taken, poisoned, result) = train(10, 3);
        let err = result.unwrap_err();
        assert!(
            matches!(
                err,
                TrainError::NonFinite {
                    step: 3,
                    what: "dL/dimage",
                    ..
                }
            ),
            "{err}"
        );
        assert_eq!(steps_taken, 2);
        let (_, clean, result) = train(2, usize::MAX);
        assert_eq!(result.unwrap().len(), 2);
        assert_eq!(poisoned, clean);
        assert_ne!(clean, model, "two steps must have moved the parameters");

        let adam = Adam::new(
            groups[..5].to_vec(),
            &model.group_lens()[..5],
            AdamHyper::default(),
        );
        let e = CpuTrainer::new(model.clone(), adam)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("5 parameter groups") && e.contains("sh_rest"),
            "{e}"
        );

        // A batch naming a view that is not there is refused before anything runs.
        let adam = Adam::new(groups.clone(), &model.group_lens(), AdamHyper::default());
        let mut trainer = CpuTrainer::new(model.clone(), adam).unwrap();
        let batch = Batch {
            views: vec![1],
            divisor: 1,
        };
        let e = trainer
            .step(&views, batch, [0.0; 3], &mut PoisonAt(0, 0))
            .unwrap_err();
        assert!(e.to_string().contains("view 1 but 1 views"), "{e}");
        assert_eq!((trainer.step_count(), trainer.model()), (0, &model));
    }

    /// An objective with a fixed gradient per view (`0.01 (1 + view)`), the loss its view.
    struct PerViewGradient;

    impl Objective for PerViewGradient {
        type Error = std::io::Error;
        fn evaluate(&mut self, view: usize, image: &Image) -> Result<ObjectiveValue, Self::Error> {
            Ok(ObjectiveValue {
                loss: view as f32,
                terms: vec![("view".into(), 2.0 * view as f32)],
                grad: image
                    .data
                    .iter()
                    .enumerate()
                    .map(|(i, _)| 0.01 * (1.0 + view as f32) * if i % 3 == 0 { 1.0 } else { -0.5 })
                    .collect(),
            })
        }
    }

    #[test]
    fn a_batch_step_is_one_adam_step_on_the_mean_gradient_of_its_views() {
        let views: Vec<View> = (0..5)
            .map(|i| {
                let a = i as f64;
                let eye = [3.0 * a.cos(), -0.5, 3.0 * a.sin()];
                View::still(Camera::look_at(eye, [0.0; 3], [0.0, -1.0, 0.0], 0.9, 16, 16).unwrap())
            })
            .collect();
        let mut model = GaussianSet::zeros(6, 1);
        for (i, m) in model.means.chunks_mut(3).enumerate() {
            m.copy_from_slice(&[0.2 * i as f32 - 0.5, 0.1 * (i % 2) as f32, 0.05 * i as f32]);
        }
        model.log_scales.fill(-1.5);
        model.opacity_logits.fill(1.0);
        let groups: Vec<GroupConfig> = PARAM_NAMES
            .iter()
            .map(|n| GroupConfig::new(*n, LrSchedule::Constant(0.01)))
            .collect();
        let sampler = ViewSampler::batches(5, 3, BatchOrder::Consecutive, 4);
        let adam = Adam::new(groups.clone(), &model.group_lens(), AdamHyper::default());
        let mut trainer = CpuTrainer::new(model.clone(), adam).unwrap();
        let reports = run(
            &mut trainer,
            &views,
            &mut sampler.clone(),
            &mut PerViewGradient,
            3,
        )
        .unwrap();

        let mut by_hand = model.clone();
        let mut adam = Adam::new(groups, &model.group_lens(), AdamHyper::default());
        let mut sampler = sampler;
        for report in &reports {
            let batch = sampler.next_batch().views;
            assert_eq!(report.batch, batch);
            assert!(batch.windows(2).all(|w| w[1] > w[0]), "{batch:?}");
            let mean = batch.iter().sum::<usize>() as f32 / 3.0;
            assert_eq!(report.value.loss, mean);
            assert_eq!(report.value.terms, vec![("view".to_string(), 2.0 * mean)]);
            let mut sum: Vec<Vec<f32>> =
                by_hand.group_lens().iter().map(|&n| vec![0.0; n]).collect();
            for &v in &batch {
                let rendered = raster::render(&by_hand, &views[v].camera, [0.0; 3]);
                let mut grad = PerViewGradient.evaluate(v, &rendered.image).unwrap().grad;
                grad.iter_mut().for_each(|g| *g *= 1.0 / 3.0);
                let out = OutputGrads {
                    rgb: &grad,
                    alpha: None,
                    depth: None,
                };
                let grads =
                    raster::backward(&by_hand, &views[v].camera, &rendered, &out, GradMask::ALL);
                crate::model::add_identity_grads(&grads.gaussians, &[true; 6], &mut sum, None);
            }
            let refs: Vec<&[f32]> = sum.iter().map(|g| g.as_slice()).collect();
            adam.step(&mut by_hand.groups_mut(), &refs);
        }
        let lens: Vec<usize> = reports.iter().map(|r| r.batch.len()).collect();
        assert_eq!(
            lens,
            vec![3, 2, 3],
            "the epoch's last batch is short, still divided by 3"
        );
        assert_eq!(trainer.into_model(), by_hand);
        assert_ne!(by_hand, model);
    }
}
