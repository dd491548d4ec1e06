//! The second phase of a stylization, once the modality has loaded or fitted its model and
//! views: [`PreparedRun::stylize`] checks the job, builds the style objective and the
//! optimizer, resumes or refuses an earlier run's checkpoint, then (and only then) creates the
//! output folder and runs the steps, a plain loop: one step (render, the style loss and its
//! image gradient, backward, Adam: `Trainer::step`), its losses shown and logged, a checkpoint
//! when due, the live preview when due, a stop after Ctrl-C; then it writes the loss log and
//! plot.

use std::path::Path;
use std::sync::atomic::Ordering;

use gs_core::adam::{AdamHyper, GroupConfig};
use gs_core::model::{BaseModel, View};
use gs_core::render_clamp::{ClampedObjective, RenderClamp};
use gs_core::sampler::{BatchOrder, ViewSampler};
use gs_core::Image;
use gs_wgpu::backend::Trainer;
use gs_wgpu::GpuModel;
use serde::Serialize;
use style_loss::{CacheBudget, LossWeights, PatchSettings, StyleLoss, StyleObjective};

use crate::checkpoint::{self, changed_fields, restore_params, Checkpoint, ParamGroup};
use crate::memory_estimate::{check_memory, machine_memory, MemoryEstimate};
use crate::outputs::{
    create_folder, write_json, StepLosses, CONFIG_JSON, LOSSES_JSON, LOSSES_PNG, PREVIEW_PNG,
    VIEW_CACHE_DIR,
};
use crate::plot::write_loss_plot;
use crate::prepare::{PreparedRun, StyleModels};
use crate::progress::Progress;
use crate::{StyleSettings, StylizeError};

/// The patch stream is seeded with `seed + PATCH_SEED_OFFSET`, so that it is not the same
/// ChaCha8 stream as the view order (seeded with `seed`). Public so that a replay of a run
/// (e.g. in another framework) can draw the same patches.
pub const PATCH_SEED_OFFSET: u64 = 1;

/// What a modality hands to [`PreparedRun::stylize`]: its loaded model and views. `views`,
/// `images`, `labels` and `masks` (when given) have one entry per view, in the same order.
#[derive(Clone, Debug)]
pub struct StylizeJob<M> {
    /// The model as loaded (training starts from it, or from the checkpoint when resuming).
    pub model: M,
    /// One Adam group per parameter group of the model, in [`BaseModel::group_names`] order.
    pub groups: Vec<GroupConfig>,
    /// The training views.
    pub views: Vec<View>,
    /// The ground truth of each view, the size of its camera.
    pub images: Vec<Image>,
    /// How each view is named in errors (e.g. its picture file).
    pub labels: Vec<String>,
    /// A background mask per view (`[h * w]`, 1 = background) when every view has one; the
    /// background loss is on only with masks and a positive `lambda_background`.
    pub masks: Option<Vec<Vec<f32>>>,
    /// The colour renders are composited over.
    pub background: [f32; 3],
    /// Views per step (their losses summed and divided by the size) and how they are grouped;
    /// one shuffled view per
    /// step is [`Batches::ONE`].
    pub batches: Batches,
    /// What the loss sees of each render: clamped to `[0, 1]` where the modality's authors'
    /// renderer clamps (3DGS), else the render as it is.
    pub render_clamp: RenderClamp,
}

/// The views of each step of a stylization.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Batches {
    /// Views per step, at least 1.
    pub size: usize,
    /// How they are grouped.
    pub order: BatchOrder,
}

impl Batches {
    /// One view per step, shuffled without replacement (3D, 2D, video).
    pub const ONE: Self = Self {
        size: 1,
        order: BatchOrder::Shuffled,
    };
}

/// What a finished run produced.
#[derive(Clone, Debug)]
pub struct StylizeOutcome<M> {
    /// The stylized model.
    pub model: M,
    /// The losses of every step, including those before a resume.
    pub losses: Vec<StepLosses>,
}

impl PreparedRun {
    /// Stylizes `job.model` on this run's device with its settings (see the module
    /// documentation), writing to its output folder:
    /// `config.json` (`config`, the modality's whole resolved configuration, whose `settings` these
    /// are), checkpoints, `losses.json` and `losses.png`. Bad inputs are reported before anything
    /// is written; a fresh run refuses an output folder that holds the checkpoint of an unfinished
    /// run ([`check_out_folder`]), a resumed one a checkpoint of another configuration
    /// ([`checkpoint::changed_fields`]) or model. When [`RunOptions::stop`] is set, the run ends
    /// after the current step with a checkpoint of it and [`StylizeError::Interrupted`]. A run that
    /// takes all its steps saves a checkpoint of the last one (unless `checkpoint_every` is 0 and
    /// there is no checkpoint of an earlier stop); the modality marks it finished
    /// ([`checkpoint::mark_finished`]) once its own outputs are written.
    pub fn stylize<M, C>(
        &self,
        config: &C,
        job: StylizeJob<M>,
    ) -> Result<StylizeOutcome<M>, StylizeError>
    where
        M: GpuModel,
        C: Serialize,
    {
        let PreparedRun {
            settings,
            out,
            options,
            backend,
            loss_device: device,
            models,
        } = self;
        let out = out.as_path();
        check_job(settings, &job)?;
        let view_pixels: Vec<u64> = job
            .images
            .iter()
            .map(|i| u64::from(i.width) * u64::from(i.height))
            .collect();
        let parameters: usize = job.model.group_lens().iter().sum();
        let estimate = MemoryEstimate::of(settings, &view_pixels, parameters);
        println!("{}", estimate.line());
        if let Some(note) = check_memory(&estimate, machine_memory())? {
            println!("{note}");
        }
        let StylizeJob {
            mut model,
            groups,
            views,
            images,
            masks,
            background,
            batches,
            render_clamp,
            ..
        } = job;
        let (loss, masks) = build_loss(settings, models, masks)?;
        let caching = Progress::new(options.progress, "caching views", images.len() as u64, 0);
        let objective = StyleObjective::with_progress(
            loss,
            &images,
            masks.as_deref(),
            settings.seed.wrapping_add(PATCH_SEED_OFFSET),
            device,
            &CacheBudget {
                resident_bytes: settings.view_cache_mb.saturating_mul(1 << 20),
                spill: Some(out.join(VIEW_CACHE_DIR)),
            },
            &mut |done, total| caching.update(done as u64, &format!("view {done} of {total}")),
        );
        caching.finish();
        let mut objective = objective?;
        let config_json = serde_json::to_value(config).expect("the config serializes");
        let bad_checkpoint = |message: String| StylizeError::Checkpoint {
            path: checkpoint::checkpoint_dir(out),
            message,
        };
        let saved = if options.resume {
            let saved = checkpoint::load(out)?;
            let changed = changed_fields(&saved.config, &config_json);
            if !changed.is_empty() {
                return Err(bad_checkpoint(format!(
                    "saved by a run with different values of {}; resume with the same settings",
                    changed.join(", ")
                )));
            }
            restore_params(&mut model, &saved.params).map_err(bad_checkpoint)?;
            Some(saved)
        } else {
            None
        };
        let names = model.group_names();
        let mut trainer = Trainer::new(backend, model, groups, AdamHyper::default())?;
        let mut losses = Vec::new();
        if let Some(saved) = saved {
            trainer.restore_optimizer(&saved.adam_state)?;
            if trainer.step_count() != saved.step {
                return Err(bad_checkpoint(format!(
                    "the optimizer took {} steps, the state says {}",
                    trainer.step_count(),
                    saved.step
                )));
            }
            if saved.step > settings.steps {
                return Err(bad_checkpoint(format!(
                    "saved at step {}, past the {} steps asked for",
                    saved.step, settings.steps
                )));
            }
            objective.set_rng(saved.rng);
            losses = saved.losses;
            println!(
                "resuming from step {} of {} ({})",
                saved.step,
                settings.steps,
                checkpoint::checkpoint_dir(out).display()
            );
        }

        if !options.resume {
            checkpoint::discard_finished(out)?;
        }
        create_folder(out)?;
        write_json(&out.join(CONFIG_JSON), config)?;
        let mut sampler =
            ViewSampler::batches(views.len(), batches.size, batches.order, settings.seed)
                .advanced(trainer.step_count());
        let progress = Progress::new(
            options.progress,
            "stylize",
            settings.steps,
            trainer.step_count(),
        );
        let every = settings.checkpoint_every;
        let mut saved_at = trainer.step_count();
        let mut live =
            LivePreview::new(settings.preview_every, settings.steps, trainer.step_count());
        let save = |trainer: &mut Trainer<M>, objective: &StyleObjective, losses: &[StepLosses]| {
            let params = names
                .iter()
                .cloned()
                .zip(trainer.param_groups())
                .map(|(name, values)| ParamGroup { name, values })
                .collect();
            checkpoint::save(
                out,
                &Checkpoint {
                    step: trainer.step_count(),
                    params,
                    adam_state: trainer.save_optimizer(),
                    rng: objective.rng().clone(),
                    config: config_json.clone(),
                    losses: losses.to_vec(),
                },
            )
        };
        while trainer.step_count() < settings.steps {
            // One step: render, the style loss and its image gradient, backward, Adam.
            let batch = sampler.next_batch();
            let mut seen = ClampedObjective::new(&mut objective, render_clamp);
            let report = trainer.step(&views, batch, background, &mut seen)?;
            let step = StepLosses::from_report(&report);
            progress.update(report.step, &describe(&step));
            losses.push(step);
            // The live preview: the first view's picture | its render now, and the losses.
            if report.step < settings.steps && live.due(report.step) {
                let now = trainer.render(&views[0], background)?;
                write_live_preview(out, &images[0], &now, &losses)?;
            }
            // Checkpoints, and Ctrl-C: a checkpoint of this step, then stop.
            let stopped = options.stop.load(Ordering::SeqCst) && report.step < settings.steps;
            if stopped || report.step.checked_rem(every) == Some(0) {
                save(&mut trainer, &objective, &losses)?;
                saved_at = report.step;
            }
            if stopped {
                progress.finish();
                return Err(StylizeError::Interrupted {
                    step: report.step,
                    out: out.to_path_buf(),
                });
            }
        }
        progress.finish();
        // The last step's checkpoint, which the modality marks finished; also when checkpoints are
        // off but this run resumed from one (a Ctrl-C), so that one does not stay behind.
        let has_checkpoint = every > 0 || checkpoint::checkpoint_dir(out).exists();
        if has_checkpoint && saved_at != trainer.step_count() {
            save(&mut trainer, &objective, &losses)?;
        }

        write_json(&out.join(LOSSES_JSON), &losses)?;
        write_loss_plot(&out.join(LOSSES_PNG), &losses)?;
        Ok(StylizeOutcome {
            model: trainer.into_model(),
            losses,
        })
    }
}

/// When a run refreshes its live preview: every `every` steps, or (unset) every 5 % of the
/// steps or [`LIVE_PREVIEW_SECONDS`], whichever comes first.
struct LivePreview {
    every: Option<u64>,
    steps: u64,
    last_step: u64,
    last_time: std::time::Instant,
}

/// The longest a run goes without refreshing its live preview (unless `preview_every` is set).
const LIVE_PREVIEW_SECONDS: u64 = 60;

impl LivePreview {
    fn new(every: Option<u64>, steps: u64, start: u64) -> Self {
        Self {
            every,
            steps,
            last_step: start,
            last_time: std::time::Instant::now(),
        }
    }

    /// Whether the preview is due after `step`; if so, the schedule restarts from it.
    fn due(&mut self, step: u64) -> bool {
        let due = match self.every {
            Some(0) => false,
            Some(k) => step.is_multiple_of(k),
            None => {
                step - self.last_step >= (self.steps / 20).max(1)
                    || self.last_time.elapsed().as_secs() >= LIVE_PREVIEW_SECONDS
            }
        };
        if due {
            self.last_step = step;
            self.last_time = std::time::Instant::now();
        }
        due
    }
}

/// Writes the live preview into `out`: `preview.png` (`picture` | `now`), and the losses so far
/// (`losses.json`, `losses.png`); the run's own outputs replace them at its end.
fn write_live_preview(
    out: &Path,
    picture: &Image,
    now: &Image,
    losses: &[StepLosses],
) -> Result<(), StylizeError> {
    Image::side_by_side(&[picture, now]).save_png(&out.join(PREVIEW_PNG))?;
    write_json(&out.join(LOSSES_JSON), &losses)?;
    write_loss_plot(&out.join(LOSSES_PNG), losses)
}

/// Checks that the job's lists agree, that its optimizer groups match the model's, and that
/// the patches fit every view.
fn check_job<M: BaseModel>(
    settings: &StyleSettings,
    job: &StylizeJob<M>,
) -> Result<(), StylizeError> {
    let count = job.views.len();
    if count == 0 {
        return Err(StylizeError::Input("there is no view to train on".into()));
    }
    if job.batches.size == 0 || job.batches.size > count {
        return Err(StylizeError::Input(format!(
            "a batch of {} views for {count} views; it must be 1 to {count} (--batch-size)",
            job.batches.size
        )));
    }
    let mut lists = vec![("images", job.images.len()), ("labels", job.labels.len())];
    if let Some(masks) = &job.masks {
        lists.push(("masks", masks.len()));
    }
    if let Some((name, n)) = lists.into_iter().find(|&(_, n)| n != count) {
        return Err(StylizeError::Input(format!("{n} {name} for {count} views")));
    }
    let names = job.model.group_names();
    if job.groups.len() != names.len() {
        return Err(StylizeError::Input(format!(
            "{} optimizer groups for the model's {} parameter groups ({})",
            job.groups.len(),
            names.len(),
            names.join(", ")
        )));
    }
    check_patches_fit(settings, &job.images, &job.labels)
}

/// Checks that the patches of the patch loss (when it is on) fit every view; `labels` name
/// the views in the error. Views are never resized to make them fit.
pub fn check_patches_fit(
    settings: &StyleSettings,
    images: &[Image],
    labels: &[String],
) -> Result<(), StylizeError> {
    if settings.lambda_patch > 0.0 {
        let size = settings.patch_size;
        for (i, (img, label)) in images.iter().zip(labels).enumerate() {
            if (img.width as usize) < size || (img.height as usize) < size {
                return Err(StylizeError::Input(format!(
                    "patch_size {size} is larger than view {i} ({label}, {}x{}); lower it \
                     with --set patch_size={} (or use larger views)",
                    img.width,
                    img.height,
                    img.width.min(img.height)
                )));
            }
        }
    }
    Ok(())
}

/// `loss 1.234 (directional 0.5, patch 0.7)`, for the progress display.
fn describe(step: &StepLosses) -> String {
    let terms: Vec<String> = step
        .terms
        .iter()
        .map(|(name, v)| format!("{name} {v:.4}"))
        .collect();
    format!("loss {:.4} ({})", step.total, terms.join(", "))
}

/// One background mask per view, `[h * w]` each, 1 = background.
type ViewMasks = Vec<Vec<f32>>;

/// The style loss of `settings` on `models`, and the background masks it uses (none when the
/// background term is off; the term is off when the views have no masks).
fn build_loss(
    settings: &StyleSettings,
    models: &StyleModels,
    masks: Option<ViewMasks>,
) -> Result<(StyleLoss, Option<ViewMasks>), StylizeError> {
    let masks = masks.filter(|_| settings.lambda_background > 0.0);
    let weights = LossWeights {
        directional: settings.lambda_directional,
        patch: settings.lambda_patch,
        content: settings.lambda_content,
        background: if masks.is_some() {
            settings.lambda_background
        } else {
            0.0
        },
    };
    let patches = PatchSettings {
        patch_size: settings.patch_size,
        num_patches: settings.num_patches,
        distortion_scale: settings.distortion_scale,
    };
    let StyleModels {
        clip,
        vgg,
        direction,
        ..
    } = models.clone();
    Ok((
        StyleLoss::new(clip, vgg, direction, weights, patches)?,
        masks,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_live_preview_is_due_on_its_schedule() {
        let due = |every: Option<u64>, steps: u64| -> Vec<u64> {
            let mut live = LivePreview::new(every, steps, 0);
            (1..=steps).filter(|&s| live.due(s)).collect()
        };
        assert_eq!(due(Some(0), 10), Vec::<u64>::new());
        assert_eq!(due(Some(3), 10), [3, 6, 9]);
        // Unset: every 5 % of the steps (at least every step), the minute not yet reached.
        assert_eq!(due(None, 100), (1..=20).map(|k| 5 * k).collect::<Vec<_>>());
        assert_eq!(due(None, 7), (1..=7).collect::<Vec<_>>());
        // A resumed run counts from where it starts.
        let mut live = LivePreview::new(None, 100, 42);
        assert!(!live.due(43) && live.due(47));
    }
}
