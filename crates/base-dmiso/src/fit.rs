//! Fitting a dynamic scene (CLIPGaussian stage 1 for 4D), in D-MiSo's three stages, each a
//! run of gs-core's trainer with `(1 - 0.2) L1 + 0.2 D-SSIM` over batches of views drawn as
//! D-MiSo's `train.py` draws them (runs of the views left this epoch from a uniform start, in an
//! order shuffled once: [`BatchOrder::ConsecutiveShuffledOnce`]):
//!
//! 1. warm-up (`warm_up` steps): the cores, static (the network is not called);
//! 2. deformation: the cores and the network;
//! 3. from `subs_from`: `sub_cores` cores drawn, `subs_per_core` sub-Gaussians each
//!    ([`with_sub_gaussians`]), which train with the network and the time-rotation layer; the
//!    triangles stay (D-MiSo stops training them there).
//!
//! D-MiSo's learning rates: triangles `1.6e-4 extent -> 1.6e-5 extent` over 30,000 steps, core
//! colour 0.0025 (higher degrees a twentieth), opacity 0.05, network `8e-4 -> 1.6e-5` over
//! 40,000 steps (from step 0, as D-MiSo decays it through the warm-up); then offsets 1e-3,
//! sub-Gaussian colour 0.0025 (all degrees), opacity 0.05, log-scales 0.005, quaternions 0.001,
//! time-rotation layer 0.1. Before `subs_from` the cores are densified as D-MiSo does
//! ([`crate::densify`]: clone, split, prune every 100 steps from step 500, opacity reset every
//! 3000 and, over white, at step 500), the optimizer's moments following the rows.
//!
//! Where this differs from D-MiSo: the SH degree is 3 from the start (D-MiSo raises it by one
//! every 1000 steps); Adam's moments restart when the warm-up ends; the cores given
//! sub-Gaussians are drawn without repetition; the time-rotation layer starts as the identity
//! `[I | 0]` rather than at random, so the sub-Gaussians start exactly where their cores were;
//! the densification's statistics differ as [`crate::densify`] says.

use std::ops::ControlFlow;

use candle_core::Device;
use gs_core::adam::{rearrange_state, AdamHyper, GroupConfig, LrSchedule, RateAt};
pub use gs_core::image_loss::mean_psnr;
use gs_core::image_loss::{check_fit_settings, PhotometricObjective};
use gs_core::model::{BaseModel, View};
use gs_core::sampler::{BatchOrder, ViewSampler};
use gs_core::train::{StepReport, TrainConfig};
use gs_core::Image;
use gs_wgpu::backend::{Backend, Trainer};
pub use gs_wgpu::FitError;
use gs_wgpu::GpuModel;

use crate::deform_net::NetShape;
use crate::densify::{densify, reset_opacity, DensifySettings, GradStats, Recording};
use crate::init::{initial_model, with_sub_gaussians};
use crate::model::{group, Dmiso, GROUP_NAMES, TORCH_ADAM_EPS};

/// How to fit a dynamic scene. The defaults are D-MiSo's (`train.py`'s arguments).
#[derive(Clone, Debug, PartialEq)]
pub struct DynamicSceneFitSettings {
    /// Random starting points (cores).
    pub points: usize,
    /// Optimizer steps of the whole fit.
    pub steps: u64,
    /// Steps of the static warm-up.
    pub warm_up: u64,
    /// The step at which the sub-Gaussians are created (D-MiSo's `densify_until_iter`).
    pub subs_from: u64,
    /// Cores kept with sub-Gaussians (D-MiSo's `num_gauss`).
    pub sub_cores: usize,
    /// Sub-Gaussians per core (D-MiSo's `num_splat`).
    pub subs_per_core: usize,
    /// Views per step, their losses summed and divided by this size (also for the epoch's
    /// shorter last batch, as D-MiSo's `batch_loss / BATCH_SIZE`).
    pub batch: usize,
    /// Width of the deformation network.
    pub deform_width: usize,
    /// Length of the network's learning-rate decay, steps (D-MiSo's `deform_lr_max_steps`,
    /// 40,000 whatever the fit's length).
    pub deform_lr_steps: u64,
    /// Seed of the starting model, of the cores drawn and of the view order.
    pub seed: u64,
    /// Weight of the D-SSIM term.
    pub lambda_dssim: f32,
    /// Background colour, linear RGB in `[0, 1]`.
    pub background: [f32; 3],
    /// D-MiSo's densification of the cores before `subs_from` (none: the cores stay the
    /// `points` drawn).
    pub densify: Option<DensifySettings>,
}

impl Default for DynamicSceneFitSettings {
    fn default() -> Self {
        Self {
            points: 100_000,
            steps: 40_000,
            warm_up: 3_000,
            subs_from: 35_000,
            sub_cores: 2_000,
            subs_per_core: 500,
            batch: 2,
            deform_width: 256,
            deform_lr_steps: 40_000,
            seed: 0,
            lambda_dssim: 0.2,
            background: [1.0; 3],
            densify: Some(DensifySettings::default()),
        }
    }
}

impl DynamicSceneFitSettings {
    /// The step counts after which the fit's later stages begin: the deformation network
    /// after the warm-up, the sub-Gaussians at `subs_from` (each slower a step than the one
    /// before).
    pub fn stages(&self) -> [u64; 2] {
        [self.warm_up, self.subs_from]
    }

    /// Checks the settings; the error starts with the flag of `clipgaussian-4d fit` that sets
    /// the field.
    pub fn check(&self) -> Result<(), FitError> {
        check_fit_settings(self.points, self.steps, self.lambda_dssim, self.background)
            .map_err(|e| FitError::Settings(format!("--{e}")))?;
        let bad = |m: String| Err(FitError::Settings(m));
        if self.warm_up > self.subs_from || self.subs_from > self.steps {
            return bad(format!(
                "--warm-up {} <= --subs-from {} <= --steps {} is required",
                self.warm_up, self.subs_from, self.steps
            ));
        }
        if self.sub_cores == 0 || self.subs_per_core == 0 {
            return bad(format!(
                "--sub-cores ({}) and --subs-per-core ({}) must be at least 1",
                self.sub_cores, self.subs_per_core
            ));
        }
        if self.batch == 0 {
            return bad("--batch-size: must be at least 1".into());
        }
        if self.deform_width == 0 {
            return bad("--deform-width: must be at least 1".into());
        }
        Ok(())
    }
}

/// The stages of a fit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Stage {
    WarmUp,
    Deformation,
    SubGaussians,
}

/// An exponential decay from `start` to `end` over `length` steps, seen from step `from`.
fn decay_from(start: f64, end: f64, length: u64, from: u64) -> LrSchedule {
    let full = LrSchedule::Exponential {
        start,
        end,
        steps: length,
    };
    LrSchedule::Exponential {
        start: full.at(from),
        end,
        steps: length.saturating_sub(from).max(1),
    }
}

/// D-MiSo's Adam groups (in [`GROUP_NAMES`] order) for `stage`, starting at step `from` of a
/// fit whose network decays over `net_steps`, in a scene of extent `extent`.
fn stage_groups(stage: Stage, extent: f64, net_steps: u64, from: u64) -> Vec<GroupConfig> {
    let constant = LrSchedule::Constant;
    let mesh = decay_from(1.6e-4 * extent, 1.6e-5 * extent, 30_000, from);
    let net = decay_from(8e-4, 1.6e-5, net_steps, from);
    let rates: [Option<LrSchedule>; 9] = match stage {
        Stage::WarmUp | Stage::Deformation => [
            Some(mesh),
            None,
            None,
            None,
            Some(constant(0.05)),
            Some(constant(0.0025)),
            Some(constant(0.0025 / 20.0)),
            (stage == Stage::Deformation).then_some(net),
            None,
        ],
        Stage::SubGaussians => [
            None,
            Some(constant(1e-3)),
            Some(constant(0.005)),
            Some(constant(0.001)),
            Some(constant(0.05)),
            Some(constant(0.0025)),
            Some(constant(0.0025)),
            Some(net),
            Some(constant(0.1)),
        ],
    };
    // D-MiSo's train.py updates every rate after the step (update k at lr(k - 1), from the
    // stage's start) and gives the time-rotation layer its own Adam with torch's epsilon.
    let mut groups: Vec<GroupConfig> = GROUP_NAMES
        .iter()
        .zip(rates)
        .map(|(name, rate)| match rate {
            Some(rate) => GroupConfig::new(*name, rate).with_rate_at(RateAt::PreviousIteration),
            None => GroupConfig::frozen(*name),
        })
        .collect();
    groups[group::TIME_NET].eps = Some(TORCH_ADAM_EPS);
    groups
}

/// Fits `views` (each at its time) to `images` with `settings` on `backend`, the network on
/// `device`; `extent` is the scene's camera extent. `on_step` is called after every step with
/// the step counted over the whole fit (return `ControlFlow::Break` to stop early; the model
/// of the stage reached is returned).
pub fn fit<F>(
    views: &[View],
    images: &[Image],
    extent: f64,
    settings: &DynamicSceneFitSettings,
    backend: &Backend,
    device: &Device,
    mut on_step: F,
) -> Result<Dmiso, FitError>
where
    F: FnMut(&StepReport) -> ControlFlow<()>,
{
    settings.check()?;
    if views.len() != images.len() || views.is_empty() {
        return Err(FitError::Settings(format!(
            "{} views and {} images: one image per view, at least one",
            views.len(),
            images.len()
        )));
    }
    let net = NetShape {
        width: settings.deform_width,
    };
    let mut model =
        initial_model(settings.points, net, settings.seed, device).map_err(FitError::Settings)?;
    let mut objective = PhotometricObjective::new(images.to_vec(), settings.lambda_dssim);
    let batch = settings.batch.min(views.len());
    let mut sampler = ViewSampler::batches(
        views.len(),
        batch,
        BatchOrder::ConsecutiveShuffledOnce,
        settings.seed,
    );
    let stages = [
        (Stage::WarmUp, 0, settings.warm_up),
        (Stage::Deformation, settings.warm_up, settings.subs_from),
        (Stage::SubGaussians, settings.subs_from, settings.steps),
    ];
    let mut stopped = false;
    let mut run = Run {
        views,
        objective: &mut objective,
        sampler: &mut sampler,
        settings,
        backend,
        extent,
        on_step: &mut on_step,
        stopped: &mut stopped,
    };
    let mut stats = None;
    for (stage, from, to) in stages {
        if *run.stopped {
            break;
        }
        if stage == Stage::SubGaussians {
            model = with_sub_gaussians(
                &model,
                settings.sub_cores,
                settings.subs_per_core,
                settings.seed,
            )
            .map_err(FitError::Settings)?;
        } else {
            model.deformation = stage == Stage::Deformation;
        }
        if from < to {
            (model, stats) = run.stage(stage, model, (from, to), stats)?;
        }
    }
    Ok(model)
}

/// What the stages of one fit share.
struct Run<'a, F> {
    views: &'a [View],
    objective: &'a mut PhotometricObjective,
    sampler: &'a mut ViewSampler,
    settings: &'a DynamicSceneFitSettings,
    backend: &'a Backend,
    extent: f64,
    on_step: &'a mut F,
    stopped: &'a mut bool,
}

impl<F> Run<'_, F>
where
    F: FnMut(&StepReport) -> ControlFlow<()>,
{
    /// The steps after which the cores are densified or their opacity reset, in `(from, to]`
    /// (none with sub-Gaussians or without densification).
    fn events(&self, stage: Stage, from: u64, to: u64) -> Vec<u64> {
        let Some(d) = &self.settings.densify else {
            return Vec::new();
        };
        if stage == Stage::SubGaussians {
            return Vec::new();
        }
        (from + 1..=to)
            .filter(|&s| s < self.settings.subs_from)
            .filter(|&s| (s > d.from && s.is_multiple_of(d.every.max(1))) || self.resets_opacity(s))
            .collect()
    }

    /// Trains `model` from step `from` to `to` of the fit in `stage`, densifying the cores at
    /// the steps [`Run::events`] names (each a new optimizer whose moments follow the rows;
    /// an event at `to` changes the model the next stage starts from). The cores' gradient
    /// statistics continue from `stats` (those of the stage before) and are returned for the
    /// next stage.
    fn stage(
        &mut self,
        stage: Stage,
        model: Dmiso,
        (from, to): (u64, u64),
        stats: Option<GradStats>,
    ) -> Result<(Dmiso, Option<GradStats>), FitError> {
        let groups = stage_groups(stage, self.extent, self.settings.deform_lr_steps, from);
        let densifying = self.settings.densify.clone();
        let (Some(settings), false) = (densifying, stage == Stage::SubGaussians) else {
            return Ok((self.segment(model, &groups, None, from, to)?.0, None));
        };
        let events = self.events(stage, from, to);
        let mut model = match stats {
            Some(stats) => Recording::with_stats(model, stats),
            None => Recording::new(model),
        };
        let mut state: Option<Vec<u8>> = None;
        let mut ends = events.clone();
        if ends.last() != Some(&to) {
            ends.push(to);
        }
        for end in ends {
            let (recorded, bytes) = self.segment(model, &groups, state.take(), from, end)?;
            if *self.stopped || !events.contains(&end) {
                let stats = recorded.stats();
                return Ok((recorded.model, Some(stats)));
            }
            let lens = trained_lens(&recorded.model, &groups);
            let mut stats = Some(recorded.stats());
            let mut next = recorded.model;
            let mut bytes = bytes;
            if end > settings.from && end.is_multiple_of(settings.every.max(1)) {
                let (dense, rows) = densify(
                    &next,
                    stats.as_ref().expect("kept until densified"),
                    self.extent,
                    &settings,
                    self.settings.seed ^ end,
                )
                .map_err(FitError::Settings)?;
                bytes = rearrange_state(&bytes, &groups, &lens, &rows)?;
                next = dense;
                // The statistics restart after a densification only.
                stats = None;
            }
            if self.resets_opacity(end) {
                let lens = trained_lens(&next, &groups);
                let rows = reset_opacity(&mut next);
                bytes = rearrange_state(&bytes, &groups, &lens, &rows)?;
            }
            if end == to {
                return Ok((next, stats));
            }
            state = Some(bytes);
            model = match stats {
                Some(stats) => Recording::with_stats(next, stats),
                None => Recording::new(next),
            };
        }
        unreachable!("the last segment ends at the stage's end")
    }

    /// Whether the opacities are reset after step `step` (every `opacity_reset_every` steps,
    /// and at the densification's first step over a white background).
    fn resets_opacity(&self, step: u64) -> bool {
        let Some(d) = &self.settings.densify else {
            return false;
        };
        let white = self.settings.background == [1.0; 3];
        step.is_multiple_of(d.opacity_reset_every.max(1)) || (white && step == d.from)
    }

    /// Trains `model` with a new optimizer of `groups` (restored from `state` when given) until
    /// it has taken `end - from` steps of the stage starting at step `from`; returns the model
    /// and the optimizer's state.
    fn segment<M: GpuModel>(
        &mut self,
        model: M,
        groups: &[GroupConfig],
        state: Option<Vec<u8>>,
        from: u64,
        end: u64,
    ) -> Result<(M, Vec<u8>), FitError> {
        let mut trainer = Trainer::new(self.backend, model, groups.to_vec(), AdamHyper::default())?;
        if let Some(bytes) = &state {
            trainer.restore_optimizer(bytes)?;
        }
        let config = TrainConfig {
            steps: end - from,
            background: self.settings.background,
        };
        let (on_step, stopped) = (&mut *self.on_step, &mut *self.stopped);
        trainer.train(
            self.views,
            self.objective,
            self.sampler,
            &config,
            |report| {
                let mut overall = report.clone();
                overall.step += from;
                let flow = on_step(&overall);
                *stopped |= flow.is_break();
                flow
            },
        )?;
        let bytes = trainer.save_optimizer();
        Ok((trainer.into_model(), bytes))
    }
}

/// The lengths of `model`'s groups that `groups` trains (`None` for frozen ones), as its
/// optimizer's state holds them.
fn trained_lens(model: &Dmiso, groups: &[GroupConfig]) -> Vec<Option<usize>> {
    model
        .group_lens()
        .into_iter()
        .zip(groups)
        .map(|(n, g)| (!g.frozen).then_some(n))
        .collect()
}

/// The images of `model` at `views`, over `background`.
pub fn render_views(
    model: &mut Dmiso,
    views: &[View],
    background: [f32; 3],
    backend: &Backend,
) -> Result<Vec<Image>, FitError> {
    let mut renderer = backend.model_renderer(model)?;
    views
        .iter()
        .map(|v| Ok(renderer.render(v, background)?))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_rate_is_updated_after_the_step_and_the_time_layer_has_torchs_epsilon() {
        let deformation = stage_groups(Stage::Deformation, 2.0, 40_000, 3000);
        // The first update of a stage uses the rate at the stage's start, as D-MiSo's
        // train.py sets it after the step before.
        let full_mesh = LrSchedule::Exponential {
            start: 1.6e-4 * 2.0,
            end: 1.6e-5 * 2.0,
            steps: 30_000,
        };
        let first = deformation[group::PSEUDOMESH].lr_for_update(1);
        assert!((first - full_mesh.at(3000)).abs() < 1e-18, "{first}");
        let subs = stage_groups(Stage::SubGaussians, 2.0, 40_000, 0);
        for g in subs.iter().filter(|g| !g.frozen) {
            assert_eq!(g.rate_at, RateAt::PreviousIteration, "{}", g.name);
        }
        assert_eq!(subs[group::TIME_NET].eps, Some(TORCH_ADAM_EPS));
        assert_eq!(subs[group::DEFORM].eps, None);
    }
}
