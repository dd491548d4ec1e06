//! The generic training loop: pick a view, build its Gaussians, render, ask the objective for
//! the loss and dL/dimage, back-propagate through the rasterizer and the base model, step Adam.

use std::ops::ControlFlow;
use std::time::{Duration, Instant};

use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::adam::Adam;
use crate::image::Image;
use crate::model::{BaseModel, Forward, ModelError, View};
use crate::raster::{self, GradMask, OutputGrads};

/// How a [`ViewSampler`] groups views into the batches of steps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BatchOrder {
    /// Each batch is the next views of a shuffle-without-replacement stream (every view once
    /// per epoch, a fresh random order each epoch).
    Shuffled,
    /// CLIPGaussian's 4D batches (and D-MiSo's): each batch is `B` consecutive entries of the
    /// views not yet drawn this epoch, kept in dataset order (neighbouring cameras and times),
    /// from a start drawn uniformly in `0..=max(0, left - B)`; so a batch may join views either
    /// side of an earlier batch, and the epoch's last one may be shorter than `B` (its loss is
    /// still divided by `B`, as the authors' `batch_loss / BATCH_SIZE`). The list refills when
    /// empty.
    Consecutive,
    /// D-MiSo's fit: the [`BatchOrder::Consecutive`] rule over the views in an order shuffled
    /// once, when the sampler is made (its `Scene(..., shuffle=True)` shuffles the camera list
    /// at load), the same order every epoch.
    ConsecutiveShuffledOnce,
}

/// Draws the views of each training step: batches of `batch` view indices in a
/// [`BatchOrder`]. Deterministic for a seed.
#[derive(Clone, Debug)]
pub struct ViewSampler {
    rng: ChaCha8Rng,
    count: usize,
    batch: usize,
    order: BatchOrder,
    /// The views of an epoch in the order runs are cut from (consecutive orders).
    epoch: Vec<usize>,
    pending: Vec<usize>,
}

impl ViewSampler {
    /// A sampler of one view per step, shuffled without replacement over `count` views.
    ///
    /// # Panics
    /// If `count` is 0.
    pub fn new(count: usize, seed: u64) -> Self {
        Self::batches(count, 1, BatchOrder::Shuffled, seed)
    }

    /// A sampler of `batch` views per step over `count` views, in `order`.
    ///
    /// # Panics
    /// If `count` or `batch` is 0.
    pub fn batches(count: usize, batch: usize, order: BatchOrder, seed: u64) -> Self {
        assert!(count > 0, "a view sampler needs at least one view");
        assert!(batch > 0, "a batch holds at least one view");
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut epoch: Vec<usize> = (0..count).collect();
        if order == BatchOrder::ConsecutiveShuffledOnce {
            epoch.shuffle(&mut rng);
        }
        Self {
            rng,
            count,
            batch,
            order,
            epoch,
            pending: Vec::new(),
        }
    }

    /// The same sampler after `steps` batches were drawn, so that a resumed run sees the view
    /// order of an uninterrupted one.
    pub fn advanced(mut self, steps: u64) -> Self {
        for _ in 0..steps {
            self.next_batch();
        }
        self
    }

    /// Number of views it draws from.
    pub fn count(&self) -> usize {
        self.count
    }

    /// Views per step.
    pub fn batch_size(&self) -> usize {
        self.batch
    }

    /// The next view of a shuffle-without-replacement stream ([`BatchOrder::Shuffled`]);
    /// refills and reshuffles when the epoch is used up.
    pub fn next_view(&mut self) -> usize {
        debug_assert_eq!(
            self.order,
            BatchOrder::Shuffled,
            "next_view draws single views"
        );
        if self.pending.is_empty() {
            self.pending = (0..self.count).collect();
            self.pending.shuffle(&mut self.rng);
        }
        self.pending.pop().expect("refilled above")
    }

    /// The views of the next step ([`BatchOrder`]).
    pub fn next_batch(&mut self) -> Vec<usize> {
        match self.order {
            BatchOrder::Shuffled => (0..self.batch).map(|_| self.next_view()).collect(),
            BatchOrder::Consecutive | BatchOrder::ConsecutiveShuffledOnce => {
                if self.pending.is_empty() {
                    self.pending = self.epoch.clone();
                }
                let left = self.pending.len();
                let start = self.rng.random_range(0..=left.saturating_sub(self.batch));
                let end = (start + self.batch).min(left);
                self.pending.drain(start..end).collect()
            }
        }
    }
}

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
/// the batch size (their mean, except for a short last batch of [`BatchOrder::Consecutive`]).
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
}

/// Settings of a training run.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainConfig {
    /// Total number of steps; the run stops when the optimizer has taken this many. A step
    /// renders the views of one batch of the sampler ([`ViewSampler::next_batch`]) and
    /// averages their losses.
    pub steps: u64,
    /// Background colour renders are composited over.
    pub background: [f32; 3],
}

/// Progress of one step, passed to the callback.
#[derive(Clone, Debug)]
pub struct StepReport {
    /// Steps completed, 1-based.
    pub step: u64,
    /// Total steps of the run.
    pub steps: u64,
    /// Index of the (first) view used.
    pub view: usize,
    /// Indices of the step's views, in the order they were rendered.
    pub batch: Vec<usize>,
    /// The objective's value over the step's views (summed, divided by the batch size).
    pub value: StepValue,
    /// Time spent rendering (forward), over the step's views.
    pub render_time: Duration,
    /// Time spent in the objective, over the step's views.
    pub objective_time: Duration,
    /// Time spent in the backward passes and the optimizer step, over the step's views.
    pub backward_time: Duration,
}

/// Why a run stopped early.
#[derive(Debug, thiserror::Error)]
pub enum TrainError<E: std::error::Error + 'static> {
    /// The pieces given to [`train`] do not fit together; nothing was trained.
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

/// How a step ended on a [`StepBackend`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StepEnd {
    /// The optimizer stepped.
    Taken,
    /// A parameter gradient was not finite; nothing changed.
    NonFiniteGradient,
}

/// Why a step on a [`StepBackend`] failed.
#[derive(Debug)]
pub enum StepFailure<E> {
    /// The device failed.
    Device(E),
    /// The model failed.
    Model(ModelError),
}

impl<E> From<ModelError> for StepFailure<E> {
    fn from(e: ModelError) -> Self {
        Self::Model(e)
    }
}

/// Where the parameters and the optimizer live, and how one step is computed there: the cpu
/// backend below, the wgpu one in the gs-wgpu crate. [`run_steps`] is the loop both share. A step
/// is one [`StepBackend::accumulate`] per view of its batch, then [`StepBackend::apply`].
pub trait StepBackend {
    /// A failure of the device.
    type Error: std::error::Error + Send + Sync + 'static;

    /// Steps the optimizer has taken.
    fn step_count(&self) -> u64;

    /// Starts a step of `views` views (the cpu keeps a zeroed sum; nothing to do).
    fn begin(&mut self, _views: usize) -> Result<(), StepFailure<Self::Error>> {
        Ok(())
    }

    /// Renders `view` over `background` and hands the image to `evaluate`; when that returns
    /// dL/dimage, back-propagates it and adds the parameters' gradient to the step's sum.
    /// Returns false (and adds nothing) when `evaluate` returned no gradient.
    fn accumulate<'g>(
        &mut self,
        view: &View,
        background: [f32; 3],
        evaluate: impl FnOnce(&Image) -> Option<&'g [f32]>,
    ) -> Result<bool, StepFailure<Self::Error>>;

    /// Steps the optimizer with the summed gradient unless a value of it is not finite, and
    /// clears the sum.
    fn apply(&mut self) -> Result<StepEnd, StepFailure<Self::Error>>;
}

/// The training loop of every backend: see [`train`].
pub fn run_steps<B, O, F>(
    backend: &mut B,
    views: &[View],
    objective: &mut O,
    sampler: &mut ViewSampler,
    config: &TrainConfig,
    mut on_step: F,
) -> Result<(), TrainError<O::Error>>
where
    B: StepBackend,
    O: Objective,
    F: FnMut(&StepReport) -> ControlFlow<()>,
{
    if sampler.count() != views.len() {
        return Err(TrainError::Mismatch(format!(
            "the view sampler draws from {} views but {} were given",
            sampler.count(),
            views.len()
        )));
    }
    let device_failure = |step, e| match e {
        StepFailure::Device(e) => TrainError::Device {
            step,
            source: Box::new(e),
        },
        StepFailure::Model(source) => TrainError::Model { step, source },
    };
    while backend.step_count() < config.steps {
        let step = backend.step_count() + 1;
        let batch = sampler.next_batch();
        // The batch's losses are summed and divided by B, also for a shorter last batch of an
        // epoch (the authors' `batch_loss / BATCH_SIZE`): each view's dL/dimage is scaled by 1/B
        // (exactly 1 for one view), so the summed parameter gradient is the loss's.
        let divisor = sampler.batch_size();
        let scale = 1.0 / divisor as f32;
        let (mut render_time, mut objective_time, mut backward_time) = Default::default();
        let mut values = Vec::with_capacity(batch.len());
        backend
            .begin(batch.len())
            .map_err(|e| device_failure(step, e))?;
        for &view_index in &batch {
            let non_finite = |what| TrainError::NonFinite {
                step,
                view: view_index,
                what,
            };
            let mut value = None;
            let mut failure = None;
            let t0 = Instant::now();
            let (mut t1, mut t2) = (t0, t0);
            let (value_slot, failure_slot) = (&mut value, &mut failure);
            let (t1_slot, t2_slot) = (&mut t1, &mut t2);
            let objective = &mut *objective;
            let evaluated = backend
                .accumulate(&views[view_index], config.background, move |image| {
                    *t1_slot = Instant::now();
                    let result = objective.evaluate(view_index, image);
                    *t2_slot = Instant::now();
                    let checked = match result {
                        Err(source) => Err(TrainError::Objective { step, source }),
                        Ok(v) if !v.loss.is_finite() => Err(non_finite("loss")),
                        Ok(v) if !v.grad.iter().all(|g| g.is_finite()) => {
                            Err(non_finite("dL/dimage"))
                        }
                        Ok(mut v) => {
                            if scale != 1.0 {
                                v.grad.iter_mut().for_each(|g| *g *= scale);
                            }
                            Ok(v)
                        }
                    };
                    match checked {
                        Ok(v) => {
                            let value: &ObjectiveValue = value_slot.insert(v);
                            Some(value.grad.as_slice())
                        }
                        Err(e) => {
                            *failure_slot = Some(e);
                            None
                        }
                    }
                })
                .map_err(|e| device_failure(step, e))?;
            let t3 = Instant::now();
            if let Some(e) = failure {
                return Err(e);
            }
            let value = value.filter(|_| evaluated).unwrap_or_else(|| {
                unreachable!("a view was evaluated without a value or a failure")
            });
            values.push(value);
            render_time += t1 - t0;
            objective_time += t2 - t1;
            backward_time += t3 - t2;
        }
        let t3 = Instant::now();
        let end = backend.apply().map_err(|e| device_failure(step, e))?;
        backward_time += t3.elapsed();
        if end == StepEnd::NonFiniteGradient {
            return Err(TrainError::NonFinite {
                step,
                view: batch[0],
                what: "parameter gradient",
            });
        }
        let report = StepReport {
            step,
            steps: config.steps,
            view: batch[0],
            batch,
            value: StepValue::divided(&values, divisor),
            render_time,
            objective_time,
            backward_time,
        };
        if on_step(&report).is_break() {
            break;
        }
    }
    Ok(())
}

/// The cpu backend: the model's own parameters, the rayon rasterizer and [`Adam`].
struct CpuBackend<'a, M> {
    model: &'a mut M,
    adam: &'a mut Adam,
    trained: Vec<bool>,
    mask: GradMask,
    /// The step's summed gradient of every group (empty for frozen groups).
    sum: Vec<Vec<f32>>,
}

impl<M: BaseModel> StepBackend for CpuBackend<'_, M> {
    type Error = std::convert::Infallible;

    fn step_count(&self) -> u64 {
        self.adam.step_count()
    }

    fn accumulate<'g>(
        &mut self,
        view: &View,
        background: [f32; 3],
        evaluate: impl FnOnce(&Image) -> Option<&'g [f32]>,
    ) -> Result<bool, StepFailure<Self::Error>> {
        let Forward { gaussians, tape } = self.model.forward(view)?;
        let rendered = raster::render(gaussians.as_ref(), &view.camera, background);
        let Some(grad) = evaluate(&rendered.image) else {
            return Ok(false);
        };
        let grads = raster::backward(
            gaussians.as_ref(),
            &view.camera,
            &rendered,
            &OutputGrads {
                rgb: grad,
                alpha: None,
                depth: None,
            },
            self.mask,
        );
        drop(gaussians);
        self.model
            .backward(view, tape, &grads.gaussians, &self.trained, &mut self.sum)?;
        Ok(true)
    }

    fn apply(&mut self) -> Result<StepEnd, StepFailure<Self::Error>> {
        let finite = self.sum.iter().flatten().all(|g| g.is_finite());
        if finite {
            let grad_refs: Vec<&[f32]> = self.sum.iter().map(|g| g.as_slice()).collect();
            self.adam.step(&mut self.model.groups_mut(), &grad_refs);
        }
        self.sum.iter_mut().for_each(|g| g.fill(0.0));
        Ok(if finite {
            StepEnd::Taken
        } else {
            StepEnd::NonFiniteGradient
        })
    }
}

/// Checks that an optimizer of `optimizer_groups` groups fits a model with `names`.
pub fn check_groups<E: std::error::Error>(
    optimizer_groups: usize,
    names: &[String],
) -> Result<(), TrainError<E>> {
    if optimizer_groups != names.len() {
        return Err(TrainError::Mismatch(format!(
            "the optimizer has {} parameter groups, the model {} ({})",
            optimizer_groups,
            names.len(),
            names.join(", ")
        )));
    }
    Ok(())
}

/// Trains `model` on `views` with `objective` and `adam` on the cpu until `adam` has taken
/// `config.steps` steps, calling `on_step` after each (return `ControlFlow::Break` to stop
/// early, e.g. on Ctrl-C). A run resumed from a checkpoint passes the restored optimizer and a
/// sampler advanced by the steps already taken ([`resumed_sampler`]). gs-wgpu's `train` is
/// the same loop with everything on the GPU.
pub fn train<M, O, F>(
    model: &mut M,
    views: &[View],
    objective: &mut O,
    adam: &mut Adam,
    sampler: &mut ViewSampler,
    config: &TrainConfig,
    on_step: F,
) -> Result<(), TrainError<O::Error>>
where
    M: BaseModel,
    O: Objective,
    F: FnMut(&StepReport) -> ControlFlow<()>,
{
    check_groups(adam.groups().len(), &model.group_names())?;
    let trained: Vec<bool> = adam.groups().iter().map(|g| !g.frozen).collect();
    let sum = model
        .group_lens()
        .iter()
        .zip(&trained)
        .map(|(&n, &t)| if t { vec![0.0; n] } else { Vec::new() })
        .collect();
    let mut backend = CpuBackend {
        mask: model.grad_mask(&trained),
        sum,
        trained,
        model,
        adam,
    };
    run_steps(&mut backend, views, objective, sampler, config, on_step)
}

/// A sampler in the state it has after `steps_done` draws, so a resumed run sees the same view
/// order as an uninterrupted one.
pub fn resumed_sampler(count: usize, seed: u64, steps_done: u64) -> ViewSampler {
    ViewSampler::new(count, seed).advanced(steps_done)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::adam::{AdamHyper, GroupConfig, LrSchedule};
    use crate::camera::Camera;
    use crate::gaussians::{GaussianSet, PARAM_NAMES};

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
        let run = |steps: u64, poison: usize| {
            let mut model = model.clone();
            let mut adam = Adam::new(groups.clone(), &model.group_lens(), AdamHyper::default());
            let config = TrainConfig {
                steps,
                background: [0.0; 3],
            };
            let result = train(
                &mut model,
                &views,
                &mut PoisonAt(0, poison),
                &mut adam,
                &mut ViewSampler::new(1, 0),
                &config,
                |_| ControlFlow::Continue(()),
            );
            (model, adam.step_count(), result)
        };
        let (poisoned, steps_taken, result) = run(10, 3);
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
        let (clean, _, result) = run(2, usize::MAX);
        result.unwrap();
        assert_eq!(poisoned, clean);
        assert_ne!(clean, model, "two steps must have moved the parameters");

        let mut adam = Adam::new(
            groups[..5].to_vec(),
            &model.group_lens()[..5],
            AdamHyper::default(),
        );
        let config = TrainConfig {
            steps: 1,
            background: [0.0; 3],
        };
        let e = train(
            &mut model.clone(),
            &views,
            &mut PoisonAt(0, 0),
            &mut adam,
            &mut ViewSampler::new(1, 0),
            &config,
            |_| ControlFlow::Continue(()),
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("5 parameter groups") && e.contains("sh_rest"),
            "{e}"
        );
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
        let config = TrainConfig {
            steps: 3,
            background: [0.0; 3],
        };
        let mut trained = model.clone();
        let mut adam = Adam::new(groups.clone(), &model.group_lens(), AdamHyper::default());
        let mut reports = Vec::new();
        train(
            &mut trained,
            &views,
            &mut PerViewGradient,
            &mut adam,
            &mut sampler.clone(),
            &config,
            |r| {
                reports.push(r.clone());
                ControlFlow::Continue(())
            },
        )
        .unwrap();

        let mut by_hand = model.clone();
        let mut adam = Adam::new(groups, &model.group_lens(), AdamHyper::default());
        let mut sampler = sampler;
        for report in &reports {
            let batch = sampler.next_batch();
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
        assert_eq!(trained, by_hand);
        assert_ne!(trained, model);
    }

    #[test]
    fn consecutive_batches_are_runs_of_the_views_left_from_a_uniform_start() {
        let mut s = ViewSampler::batches(7, 3, BatchOrder::Consecutive, 1);
        for _ in 0..5 {
            // One epoch: runs of increasing views, every view once, the last run maybe short.
            let mut left: Vec<usize> = (0..7).collect();
            while !left.is_empty() {
                let batch = s.next_batch();
                assert_eq!(batch.len(), 3.min(left.len()), "{batch:?} of {left:?}");
                let start = left.iter().position(|&v| v == batch[0]).unwrap();
                assert_eq!(
                    batch,
                    left[start..start + batch.len()],
                    "consecutive in {left:?}"
                );
                left.drain(start..start + batch.len());
            }
        }
        // The start is uniform over 0..=left-B: every start of a 7-view epoch occurs.
        let starts: std::collections::BTreeSet<usize> = (0..200)
            .map(|seed| ViewSampler::batches(7, 3, BatchOrder::Consecutive, seed).next_batch()[0])
            .collect();
        assert_eq!(starts.into_iter().collect::<Vec<_>>(), vec![0, 1, 2, 3, 4]);
        // Shuffled once: the same runs rule over one fixed permutation, every epoch.
        let mut once = ViewSampler::batches(7, 3, BatchOrder::ConsecutiveShuffledOnce, 1);
        let order = once.epoch.clone();
        assert_ne!(order, (0..7).collect::<Vec<_>>());
        for _ in 0..5 {
            let mut left = order.clone();
            while !left.is_empty() {
                let batch = once.next_batch();
                let start = left.iter().position(|&v| v == batch[0]).unwrap();
                assert_eq!(batch, left[start..start + batch.len()], "runs of {left:?}");
                left.drain(start..start + batch.len());
            }
        }
        let mut shuffled = ViewSampler::batches(4, 2, BatchOrder::Shuffled, 2);
        let mut epoch: Vec<usize> = (0..2).flat_map(|_| shuffled.next_batch()).collect();
        epoch.sort_unstable();
        assert_eq!(epoch, vec![0, 1, 2, 3]);
    }

    #[test]
    fn sampler_visits_every_view_once_per_epoch() {
        let mut s = ViewSampler::new(5, 3);
        for _ in 0..4 {
            let mut seen: Vec<usize> = (0..5).map(|_| s.next_view()).collect();
            seen.sort_unstable();
            assert_eq!(seen, vec![0, 1, 2, 3, 4]);
        }
    }

    #[test]
    fn resumed_sampler_continues_the_same_sequence() {
        let mut full = ViewSampler::new(7, 11);
        let all: Vec<usize> = (0..30).map(|_| full.next_view()).collect();
        let mut resumed = resumed_sampler(7, 11, 12);
        let rest: Vec<usize> = (0..18).map(|_| resumed.next_view()).collect();
        assert_eq!(rest, all[12..]);
        let mut other = ViewSampler::new(7, 12);
        let other_seq: Vec<usize> = (0..30).map(|_| other.next_view()).collect();
        assert_ne!(other_seq, all);
    }
}
