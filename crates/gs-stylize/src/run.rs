//! The stylization of every modality, in two phases, which [`crate::drive::run`] calls in its
//! order. [`prepare`] checks everything a run needs before any long work (settings, output
//! folder, weights, style image, CLIP configuration, device) and reports every problem at once;
//! once the modality has loaded or fitted its model and views, [`PreparedRun::stylize`] checks
//! the job, builds the style objective and the optimizer, resumes or refuses an earlier run's
//! checkpoint, then (and only then) creates the output folder, trains with checkpoints and
//! progress, and writes the loss log and plot.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use candle_core::Device;
use gs_core::adam::{AdamHyper, GroupConfig};
use gs_core::model::{BaseModel, View};
use gs_core::render_clamp::{ClampedObjective, RenderClamp};
use gs_core::train::{BatchOrder, TrainConfig, ViewSampler};
use gs_core::Image;
use gs_wgpu::backend::OpenDevice;
use gs_wgpu::backend::{Backend, DeviceChoice, Trainer};
use gs_wgpu::GpuModel;
use serde::Serialize;
use style_loss::clip::CPU_BF16_ENV;
use style_loss::compute_device;
use style_loss::{
    CacheBudget, ClipConfig, ClipModel, ClipPrecision, ClipTokenizer, LossWeights, PatchSettings,
    StyleDirection, StyleLoss, StyleObjective, Vgg19Features, Vgg19Widths, VggPrecision,
};

use crate::checkpoint::{self, changed_fields, restore_params, Checkpoint, ParamGroup};
use crate::memory_estimate::{check_memory, machine_memory, MemoryEstimate};
use crate::outputs::{
    create_folder, write_json, StepLosses, CONFIG_JSON, LOSSES_JSON, LOSSES_PNG, VIEW_CACHE_DIR,
};
use crate::picture::load_style_picture;
use crate::plot::write_loss_plot;
use crate::progress::Progress;
use crate::weights::{resolve_weights, WeightFiles};
use crate::writable::check_output_folder;
use crate::{StyleSettings, StylizeError};

/// The patch stream is seeded with `seed + PATCH_SEED_OFFSET`, so that it is not the same
/// ChaCha8 stream as the view order (seeded with `seed`). Public so that a replay of a run
/// (e.g. in another framework) can draw the same patches.
pub const PATCH_SEED_OFFSET: u64 = 1;

/// How to run, beyond the configuration.
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    /// Continue from the checkpoint in `<out>/checkpoint/` (the configuration must be the
    /// saved one except for [`checkpoint::RESUMABLE_CHANGES`]).
    pub resume: bool,
    /// Show the progress on stderr ([`Progress`]: a bar on a terminal, else plain lines).
    pub progress: bool,
    /// Set (e.g. by a Ctrl-C handler) to stop after the current step: the run then writes a
    /// checkpoint and returns [`StylizeError::Interrupted`].
    pub stop: Arc<AtomicBool>,
}

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

/// Opens the device `choice` names and prints it in one line (`device: ...`).
pub fn open_device(choice: DeviceChoice) -> Result<Backend, StylizeError> {
    let backend = choice.open()?;
    println!("device: {}", backend.describe());
    Ok(backend)
}

/// A stylization run whose inputs are all checked ([`prepare`]), on an opened device.
#[derive(Debug)]
pub struct PreparedRun {
    settings: StyleSettings,
    out: PathBuf,
    options: RunOptions,
    backend: Backend,
    loss_device: Device,
    models: StyleModels,
}

/// Checks everything a stylization with `settings` into `out` needs before any long work: the
/// settings, the output folder ([`check_out_folder`]), the model files ([`resolve_weights`]),
/// the style image, the CLIP configuration, and the devices, which it opens and names in one
/// line; then loads the loss's models (CLIP, VGG-19) and the style's direction, so a bad model
/// file is refused before a fit writes anything (`device: <rasterizer's>; style loss: <candle's>`, see [`compute_device::open_for`]). Every
/// problem found is reported at once
/// ([`StylizeError::Several`] when there are more than one).
pub fn prepare(
    settings: &StyleSettings,
    out: &Path,
    options: RunOptions,
) -> Result<PreparedRun, StylizeError> {
    let mut problems = Vec::new();
    let mut check = |result: Result<(), StylizeError>| {
        if let Err(e) = result {
            problems.push(e);
        }
    };
    check(settings.validate());
    check(check_out_folder(out, options.resume, settings.steps));
    check(check_style_image_and_clip_config(settings));
    // No download (hundreds of MB) for a run that will not start anyway.
    let download = problems.is_empty();
    let weights = resolve_weights(settings, download)
        .map_err(|e| problems.push(e.into()))
        .ok();
    let backend = settings
        .device
        .open()
        .map_err(|e| problems.push(e.into()))
        .ok();
    let loss_device = compute_device::open_for(settings.device)
        .map_err(|e| problems.push(StylizeError::LossDevice(e)))
        .ok();
    match (weights, backend, loss_device) {
        (Some(weights), Some(backend), Some((loss_device, note))) if problems.is_empty() => {
            println!(
                "device: {}; style loss: {}{note}",
                backend.describe(),
                compute_device::describe(&loss_device)
            );
            println!("{}", loading_line(&weights));
            let models = load_style_models(settings, &weights, &loss_device)?;
            for line in precision_lines(settings, &models) {
                println!("{line}");
            }
            Ok(PreparedRun {
                settings: settings.clone(),
                out: out.to_path_buf(),
                options,
                backend,
                loss_device,
                models,
            })
        }
        _ if problems.len() == 1 => Err(problems.remove(0)),
        _ => Err(StylizeError::Several(problems)),
    }
}

impl PreparedRun {
    /// The device the run trains on (a modality fits and renders there too).
    pub fn backend(&self) -> &Backend {
        &self.backend
    }

    /// The candle device the style loss runs on.
    pub fn loss_device(&self) -> &Device {
        &self.loss_device
    }

    /// The output folder.
    pub fn out(&self) -> &Path {
        &self.out
    }

    /// How to run.
    pub fn options(&self) -> &RunOptions {
        &self.options
    }

    /// The settings.
    pub fn settings(&self) -> &StyleSettings {
        &self.settings
    }

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
        }

        if !options.resume {
            checkpoint::discard_finished(out)?;
        }
        create_folder(out)?;
        write_json(&out.join(CONFIG_JSON), config)?;
        let train_config = TrainConfig {
            steps: settings.steps,
            background,
        };
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
            trainer.train(
                &views,
                &mut ClampedObjective::new(&mut objective, render_clamp),
                &mut sampler,
                &train_config,
                |report| {
                    let step = StepLosses::from_report(report);
                    progress.update(report.step, &describe(&step));
                    losses.push(step);
                    if report.step.checked_rem(every) == Some(0)
                        || options.stop.load(Ordering::SeqCst)
                    {
                        ControlFlow::Break(())
                    } else {
                        ControlFlow::Continue(())
                    }
                },
            )?;
            let stopped =
                options.stop.load(Ordering::SeqCst) && trainer.step_count() < settings.steps;
            if stopped || trainer.step_count().checked_rem(every) == Some(0) {
                save(&mut trainer, &objective, &losses)?;
                saved_at = trainer.step_count();
            }
            if stopped {
                progress.finish();
                return Err(StylizeError::Interrupted {
                    step: trainer.step_count(),
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

/// Checks the output folder of a run before any work: it can be written
/// ([`check_output_folder`]); a fresh run (`resume == false`) refuses a folder that holds the
/// checkpoint of an unfinished run (a finished run's is replaced); a resumed one needs a
/// checkpoint, and one of a finished run continues only with more `steps` than it took. A
/// checkpoint that an interrupted save left parked is put back first. [`prepare`] calls it,
/// before any long preparation (loading a scene, a fit).
pub fn check_out_folder(out: &Path, resume: bool, steps: u64) -> Result<(), StylizeError> {
    check_output_folder(out)?;
    checkpoint::recover_interrupted_save(out)?;
    let dir = checkpoint::checkpoint_dir(out);
    match (resume, dir.exists(), checkpoint::finished_step(out)) {
        (false, true, None) => Err(StylizeError::Input(format!(
            "{} holds the checkpoint of an unfinished run: pass --resume to continue it, or \
             choose another output folder",
            out.display()
        ))),
        (true, false, _) => Err(StylizeError::Checkpoint {
            path: dir,
            message: "there is no checkpoint to resume from: run without --resume".into(),
        }),
        (true, true, Some(done)) if steps <= done => Err(StylizeError::Checkpoint {
            path: dir,
            message: format!(
                "the run finished all its {done} steps and wrote its outputs, so there is \
                 nothing to resume: raise --steps above {done} to continue it, or run without \
                 --resume to start again"
            ),
        }),
        _ => Ok(()),
    }
}

/// Checks that the style image of `settings` decodes and that its CLIP configuration parses.
fn check_style_image_and_clip_config(settings: &StyleSettings) -> Result<(), StylizeError> {
    if let Some(path) = &settings.style_image {
        load_style_picture(path, &Device::Cpu).map_err(StylizeError::StyleImage)?;
    }
    if let Some(path) = &settings.clip_config {
        ClipConfig::from_json_file(path)?;
    }
    Ok(())
}

/// The style loss's models, loaded and checked by [`prepare`], before any long work (a fit
/// whose run would then fail on a bad model file writes nothing).
#[derive(Clone, Debug)]
struct StyleModels {
    clip: ClipModel,
    vgg: Option<Vgg19Features>,
    direction: StyleDirection,
}

/// The lines that say which formats CLIP and VGG run in, for those not asked for f32.
fn precision_lines(settings: &StyleSettings, models: &StyleModels) -> Vec<String> {
    let clip = models.clip.precision();
    let clip_bf16 = clip == ClipPrecision::Bf16;
    let clip_runs = if clip_bf16 {
        "bf16 products".to_string()
    } else {
        clip.to_string()
    };
    let asked = settings.clip_precision;
    let clip_line = (asked != ClipPrecision::F32).then(|| {
        let auto = (asked == ClipPrecision::Auto).then_some(clip_bf16);
        precision_line("CLIP", &clip_runs, auto)
    });
    let asked = settings.vgg_precision;
    let vgg_line = models
        .vgg
        .as_ref()
        .filter(|_| asked != VggPrecision::F32)
        .map(|vgg| {
            let bf16 = vgg.precision() == VggPrecision::Bf16;
            let runs = if bf16 {
                "bf16 backward products"
            } else {
                "f32"
            };
            precision_line("VGG", runs, (asked == VggPrecision::Auto).then_some(bf16))
        });
    [clip_line, vgg_line].into_iter().flatten().collect()
}

/// The line that says which format a network (CLIP, VGG) runs in, printed when it was not
/// asked for f32: what `runs`, and, when `auto` chose it, whether that is bf16 and why.
fn precision_line(network: &str, runs: &str, auto_chose_bf16: Option<bool>) -> String {
    let reason = match auto_chose_bf16 {
        Some(true) => " (auto: this CPU has AVX-512 BF16)".to_string(),
        Some(false) => {
            format!(" (auto: bf16 only on a CPU with AVX-512 BF16, unless {CPU_BF16_ENV}=0)")
        }
        None => String::new(),
    };
    format!("{network} precision: {runs}{reason}")
}

/// The line a run prints before it loads the style models (about 1.3 GB of weights: seconds on
/// a CPU, with nothing else to show meanwhile), naming the files.
fn loading_line(files: &WeightFiles) -> String {
    match &files.vgg {
        Some(vgg) => format!(
            "loading CLIP ({}) and VGG-19 ({})",
            files.clip.display(),
            vgg.display()
        ),
        None => format!("loading CLIP ({})", files.clip.display()),
    }
}

/// Loads the models of `settings`' loss from `files` on `device`, with the style's direction
/// in CLIP space (from the style image's stored colours, alpha ignored, as the authors read
/// it; the text tower is dropped once the direction is computed).
fn load_style_models(
    settings: &StyleSettings,
    files: &WeightFiles,
    device: &Device,
) -> Result<StyleModels, StylizeError> {
    let style_image = match &settings.style_image {
        Some(path) => Some(load_style_picture(path, device).map_err(StylizeError::StyleImage)?),
        None => None,
    };
    let clip_config = match &settings.clip_config {
        Some(path) => ClipConfig::from_json_file(path)?,
        None => ClipConfig::vit_b_32(),
    };
    let tokenizer = ClipTokenizer::from_file(&files.tokenizer)?;
    let mut clip =
        ClipModel::load_with_precision(&clip_config, &files.clip, device, settings.clip_precision)?;
    let direction = match (&style_image, &settings.style_prompt) {
        (Some(image), _) => {
            StyleDirection::from_image(&clip, &tokenizer, image, &settings.source_prompt)?
        }
        (None, Some(prompt)) => {
            StyleDirection::from_text(&clip, &tokenizer, prompt, &settings.source_prompt)?
        }
        (None, None) => {
            return Err(StylizeError::Config(
                "style_prompt, style_image: a style is required: --style-prompt TEXT or \
                 --style-image PICTURE"
                    .into(),
            ))
        }
    };
    clip.drop_text_tower();
    let vgg = match &files.vgg {
        Some(path) => Some(Vgg19Features::load_with_precision(
            path,
            Vgg19Widths(settings.vgg_widths),
            device,
            settings.vgg_precision,
        )?),
        None => None,
    };
    Ok(StyleModels {
        clip,
        vgg,
        direction,
    })
}

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
    fn prepare_reports_every_problem_at_once() {
        let dir = tempfile::tempdir().unwrap();
        let out_file = dir.path().join("taken");
        std::fs::write(&out_file, b"a file").unwrap();
        let broken_style = dir.path().join("style.png");
        std::fs::write(&broken_style, b"not a png").unwrap();
        let mut settings = StyleSettings::paper_3d();
        settings.style_prompt = None;
        settings.style_image = Some(broken_style);
        settings.clip_weights = Some(dir.path().join("missing-clip.safetensors"));
        settings.tokenizer = Some(dir.path().join("missing-tokenizer.json"));
        settings.vgg_weights = Some(dir.path().join("missing-vgg.safetensors"));
        settings.device = DeviceChoice::Cpu;
        let err = prepare(&settings, &out_file, RunOptions::default()).unwrap_err();
        let StylizeError::Several(problems) = &err else {
            panic!("expected several problems, got {err}");
        };
        let text = err.to_string();
        assert_eq!(problems.len(), 3, "{text}");
        for part in ["taken", "style image", "missing-clip", "missing-vgg"] {
            assert!(text.contains(part), "{part} in {text}");
        }
    }

    #[test]
    fn prepare_opens_the_device_and_loads_the_models_when_all_is_well() {
        let dir = tempfile::tempdir().unwrap();
        let models = style_loss::test_models::write_tiny_models(dir.path());
        let mut settings = StyleSettings::paper_3d();
        settings.clip_config = Some(models.clip_config.clone());
        settings.clip_weights = Some(models.clip_weights.clone());
        settings.tokenizer = Some(models.tokenizer.clone());
        settings.vgg_weights = Some(models.vgg_weights.clone());
        settings.vgg_widths = models.vgg_widths.0;
        settings.style_prompt = Some("fire".into());
        settings.device = DeviceChoice::Cpu;
        let out = dir.path().join("out");
        let run = prepare(&settings, &out, RunOptions::default()).unwrap();
        assert_eq!(run.out(), out);
        assert!(matches!(run.backend(), Backend::Cpu));
        assert!(run.models.vgg.is_some());
        assert!(!out.exists(), "nothing is written before the run");

        // A model file that exists but does not load is refused here, before any fit.
        let garbage = dir.path().join("garbage.safetensors");
        std::fs::write(&garbage, b"not a safetensors file").unwrap();
        settings.vgg_weights = Some(garbage);
        let e = prepare(&settings, &out, RunOptions::default()).unwrap_err();
        assert!(e.to_string().contains("garbage.safetensors"), "{e}");
        settings.vgg_weights = Some(models.vgg_weights.clone());
        settings.vgg_widths = [8, 8, 16, 32, 32];
        let e = prepare(&settings, &out, RunOptions::default()).unwrap_err();
        assert!(e.to_string().contains("shape"), "{e}");
        assert!(!out.exists(), "nothing is written before the run");
    }
}
