//! The generic training loop: pick a view, build its Gaussians, render, ask the objective for
//! the loss and dL/dimage, back-propagate through the rasterizer and the base model, step Adam.

use std::ops::ControlFlow;
use std::time::{Duration, Instant};

use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::adam::Adam;
use crate::image::Image;
use crate::model::{BaseModel, Forward, ModelError, View};
use crate::raster::{self, GradMask, OutputGrads};

/// Shuffle-without-replacement over view indices: every view once per epoch, in a fresh
/// random order each epoch. Deterministic for a seed.
#[derive(Clone, Debug)]
pub struct ViewSampler {
    rng: ChaCha8Rng,
    count: usize,
    pending: Vec<usize>,
}

impl ViewSampler {
    /// A sampler over `count` views (at least one).
    ///
    /// # Panics
    /// If `count` is 0.
    pub fn new(count: usize, seed: u64) -> Self {
        assert!(count > 0, "a view sampler needs at least one view");
        Self {
            rng: ChaCha8Rng::seed_from_u64(seed),
            count,
            pending: Vec::new(),
        }
    }

    /// Number of views it draws from.
    pub fn count(&self) -> usize {
        self.count
    }

    /// The next view index; refills and reshuffles when the epoch is used up.
    pub fn next_view(&mut self) -> usize {
        if self.pending.is_empty() {
            self.pending = (0..self.count).collect();
            self.pending.shuffle(&mut self.rng);
        }
        self.pending.pop().expect("refilled above")
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
    /// Total number of steps; the run stops when the optimizer has taken this many.
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
    /// Index of the view used.
    pub view: usize,
    /// The objective's value.
    pub value: ObjectiveValue,
    /// Time spent rendering (forward).
    pub render_time: Duration,
    /// Time spent in the objective.
    pub objective_time: Duration,
    /// Time spent in the backward passes and the optimizer step.
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
pub(crate) enum StepEnd {
    /// The optimizer stepped.
    Taken,
    /// The objective gave no gradient; nothing changed.
    Abandoned,
    /// A parameter gradient was not finite; nothing changed.
    NonFiniteGradient,
}

/// Why a step on a [`StepBackend`] failed.
#[derive(Debug)]
pub(crate) enum StepFailure<E> {
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
/// backend below, the wgpu one in `crate::wgpu`. [`run_steps`] is the loop both share.
pub(crate) trait StepBackend {
    /// A failure of the device.
    type Error: std::error::Error + Send + Sync + 'static;

    /// Steps the optimizer has taken.
    fn step_count(&self) -> u64;

    /// Renders `view` over `background`, hands the image to `evaluate` and, when that returns
    /// dL/dimage, back-propagates it and steps the optimizer unless a parameter gradient is
    /// not finite.
    fn step<'g>(
        &mut self,
        view: &View,
        background: [f32; 3],
        evaluate: impl FnOnce(&Image) -> Option<&'g [f32]>,
    ) -> Result<StepEnd, StepFailure<Self::Error>>;
}

/// The training loop of every backend: see [`train`].
pub(crate) fn run_steps<B, O, F>(
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
    while backend.step_count() < config.steps {
        let step = backend.step_count() + 1;
        let view_index = sampler.next_view();
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
        let end = backend
            .step(&views[view_index], config.background, move |image| {
                *t1_slot = Instant::now();
                let result = objective.evaluate(view_index, image);
                *t2_slot = Instant::now();
                let checked = match result {
                    Err(source) => Err(TrainError::Objective { step, source }),
                    Ok(v) if !v.loss.is_finite() => Err(non_finite("loss")),
                    Ok(v) if !v.grad.iter().all(|g| g.is_finite()) => Err(non_finite("dL/dimage")),
                    Ok(v) => Ok(v),
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
            .map_err(|e| match e {
                StepFailure::Device(e) => TrainError::Device {
                    step,
                    source: Box::new(e),
                },
                StepFailure::Model(source) => TrainError::Model { step, source },
            })?;
        let t3 = Instant::now();
        match (end, value, failure) {
            (_, _, Some(e)) => return Err(e),
            (StepEnd::NonFiniteGradient, ..) => return Err(non_finite("parameter gradient")),
            (StepEnd::Taken, Some(value), None) => {
                let report = StepReport {
                    step,
                    steps: config.steps,
                    view: view_index,
                    value,
                    render_time: t1 - t0,
                    objective_time: t2 - t1,
                    backward_time: t3 - t2,
                };
                if on_step(&report).is_break() {
                    break;
                }
            }
            (end, ..) => unreachable!("a step ended {end:?} without a value or a failure"),
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
    lens: Vec<usize>,
}

impl<M: BaseModel> StepBackend for CpuBackend<'_, M> {
    type Error = std::convert::Infallible;

    fn step_count(&self) -> u64 {
        self.adam.step_count()
    }

    fn step<'g>(
        &mut self,
        view: &View,
        background: [f32; 3],
        evaluate: impl FnOnce(&Image) -> Option<&'g [f32]>,
    ) -> Result<StepEnd, StepFailure<Self::Error>> {
        let Forward { gaussians, tape } = self.model.forward(view)?;
        let rendered = raster::render(gaussians.as_ref(), &view.camera, background);
        let Some(grad) = evaluate(&rendered.image) else {
            return Ok(StepEnd::Abandoned);
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
        let mut group_grads: Vec<Vec<f32>> = self
            .lens
            .iter()
            .zip(&self.trained)
            .map(|(&n, &t)| if t { vec![0.0; n] } else { Vec::new() })
            .collect();
        drop(gaussians);
        self.model.backward(
            view,
            tape,
            &grads.gaussians,
            &self.trained,
            &mut group_grads,
        )?;
        if !group_grads.iter().flatten().all(|g| g.is_finite()) {
            return Ok(StepEnd::NonFiniteGradient);
        }
        let grad_refs: Vec<&[f32]> = group_grads.iter().map(|g| g.as_slice()).collect();
        self.adam.step(&mut self.model.groups_mut(), &grad_refs);
        Ok(StepEnd::Taken)
    }
}

/// Checks that an optimizer of `optimizer_groups` groups fits a model with `names`.
pub(crate) fn check_groups<E: std::error::Error>(
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
/// sampler advanced by the steps already taken ([`resumed_sampler`]). `crate::wgpu::train` is
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
    let mut backend = CpuBackend {
        mask: model.grad_mask(&trained),
        lens: model.group_lens(),
        trained,
        model,
        adam,
    };
    run_steps(&mut backend, views, objective, sampler, config, on_step)
}

/// A sampler in the state it has after `steps_done` draws, so a resumed run sees the same view
/// order as an uninterrupted one.
pub fn resumed_sampler(count: usize, seed: u64, steps_done: u64) -> ViewSampler {
    let mut s = ViewSampler::new(count, seed);
    for _ in 0..steps_done {
        s.next_view();
    }
    s
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
