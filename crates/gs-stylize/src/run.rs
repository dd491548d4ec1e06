//! The stylization driver of every modality: check the job, build the style objective and the
//! optimizer, resume or refuse an earlier run's checkpoint, then (and only then) create the
//! output folder, train with checkpoints and a progress bar, and write the loss log and plot.
//! The modality loads its model and views before and writes its own results after.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use candle_core::Device;
use gs_core::adam::{AdamHyper, GroupConfig};
use gs_core::backend::{Backend, DeviceChoice, TrainableModel, Trainer};
use gs_core::model::{BaseModel, View};
use gs_core::train::{resumed_sampler, TrainConfig};
use gs_core::Image;
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use style_loss::weight_resolution::{CLIP_TOKENIZER, CLIP_VIT_B_32_WEIGHTS, VGG19_WEIGHTS};
use style_loss::{
    ClipConfig, ClipModel, ClipTokenizer, LossWeights, PatchSettings, StyleDirection, StyleLoss,
    StyleObjective, Vgg19Features, Vgg19Widths,
};

use crate::checkpoint::{self, changed_fields, restore_params, Checkpoint, ParamGroup};
use crate::loss_plot::write_plot;
use crate::outputs::{write_json, StepLosses, CONFIG_JSON, LOSSES_JSON, LOSSES_PNG};
use crate::picture::load_picture;
use crate::{StyleSettings, StylizeError};

/// The patch stream is seeded with `seed + PATCH_SEED_OFFSET`, so that it is not the same
/// ChaCha8 stream as the view order (seeded with `seed`).
const PATCH_SEED_OFFSET: u64 = 1;

/// How to run, beyond the configuration.
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    /// Continue from the checkpoint in `<out>/checkpoint/` (the configuration must be the
    /// saved one except for [`checkpoint::RESUMABLE_CHANGES`]).
    pub resume: bool,
    /// Draw a progress bar on the terminal.
    pub progress: bool,
    /// Set (e.g. by a Ctrl-C handler) to stop after the current step: the run then writes a
    /// checkpoint and returns [`StylizeError::Interrupted`].
    pub stop: Arc<AtomicBool>,
}

/// What a modality hands to [`stylize`]: its loaded model and views. `views`, `images`,
/// `labels` and `masks` (when given) have one entry per view, in the same order.
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
    /// The colour renders are composited over, also behind transparent style-image pixels.
    pub background: [f32; 3],
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

/// Stylizes `job.model` on `backend` ([`open_device`]) with `settings` (see the module
/// documentation), writing to `out`:
/// `config.json` (`config`, the modality's whole resolved configuration, whose `settings` these
/// are), checkpoints, `losses.json` and `losses.png`. Bad inputs are reported before anything
/// is written; a fresh run refuses an output folder that holds a checkpoint, a resumed one a
/// checkpoint of another configuration ([`checkpoint::changed_fields`]) or model. When
/// [`RunOptions::stop`] is set, the run ends after the current step with a checkpoint of it and
/// [`StylizeError::Interrupted`].
pub fn stylize<M, C>(
    settings: &StyleSettings,
    config: &C,
    job: StylizeJob<M>,
    out: &Path,
    options: &RunOptions,
    backend: &Backend,
) -> Result<StylizeOutcome<M>, StylizeError>
where
    M: TrainableModel,
    C: Serialize,
{
    settings.validate()?;
    check_job(settings, &job)?;
    let StylizeJob {
        mut model,
        groups,
        views,
        images,
        masks,
        background,
        ..
    } = job;
    let device = Device::Cpu;
    let (loss, masks) = build_loss(settings, masks, background, &device)?;
    let mut objective = StyleObjective::new(
        loss,
        &images,
        masks.as_deref(),
        settings.seed.wrapping_add(PATCH_SEED_OFFSET),
        &device,
    )?;
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
        check_out_folder(out, false)?;
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

    std::fs::create_dir_all(out).map_err(|source| StylizeError::Io {
        path: out.to_path_buf(),
        source,
    })?;
    write_json(&out.join(CONFIG_JSON), config)?;
    let train_config = TrainConfig {
        steps: settings.steps,
        background,
    };
    let mut sampler = resumed_sampler(views.len(), settings.seed, trainer.step_count());
    let bar = progress_bar(
        options.progress,
        "stylize",
        settings.steps,
        trainer.step_count(),
    );
    let every = settings.checkpoint_every;
    while trainer.step_count() < settings.steps {
        trainer.train(
            &views,
            &mut objective,
            &mut sampler,
            &train_config,
            |report| {
                let step = StepLosses::from_report(report);
                bar.set_position(report.step);
                bar.set_message(describe(&step));
                losses.push(step);
                if report.step.checked_rem(every) == Some(0) || options.stop.load(Ordering::SeqCst)
                {
                    ControlFlow::Break(())
                } else {
                    ControlFlow::Continue(())
                }
            },
        )?;
        let stopped = options.stop.load(Ordering::SeqCst) && trainer.step_count() < settings.steps;
        if stopped || trainer.step_count().checked_rem(every) == Some(0) {
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
                    losses: losses.clone(),
                },
            )?;
        }
        if stopped {
            bar.abandon();
            return Err(StylizeError::Interrupted {
                step: trainer.step_count(),
                out: out.to_path_buf(),
            });
        }
    }
    bar.finish();

    write_json(&out.join(LOSSES_JSON), &losses)?;
    let totals: Vec<f32> = losses.iter().map(|l| l.total).collect();
    write_plot(&out.join(LOSSES_PNG), &totals)?;
    Ok(StylizeOutcome {
        model: trainer.into_model(),
        losses,
    })
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
                    "patch_size {size} is larger than view {i} ({label}, {}x{}); lower \
                     patch_size (or the resolution divisor of a dataset)",
                    img.width, img.height
                )));
            }
        }
    }
    Ok(())
}

/// `loss 1.234 (directional 0.5, patch 0.7)`, for the progress bar.
fn describe(step: &StepLosses) -> String {
    let terms: Vec<String> = step
        .terms
        .iter()
        .map(|(name, v)| format!("{name} {v:.4}"))
        .collect();
    format!("loss {:.4} ({})", step.total, terms.join(", "))
}

/// A progress bar over `steps` steps with `done` already taken, elapsed time, ETA and a
/// message (hidden when `show` is false); `label` (e.g. "fit") is shown before the bar.
pub fn progress_bar(show: bool, label: &str, steps: u64, done: u64) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(steps);
    bar.set_style(
        ProgressStyle::with_template(
            "{prefix}{bar:30} {pos}/{len} [{elapsed_precise} < {eta_precise}] {msg}",
        )
        .expect("a valid template"),
    );
    if !label.is_empty() {
        bar.set_prefix(format!("{label} "));
    }
    bar.set_position(done);
    bar.reset_eta();
    bar
}

/// One background mask per view, `[h * w]` each, 1 = background.
type ViewMasks = Vec<Vec<f32>>;

/// Checks the output folder for a run: a fresh run (`resume == false`) refuses a folder that
/// holds a checkpoint, a resumed one needs it. A checkpoint that an interrupted save left
/// parked is put back first. A modality calls it before any long preparation (a fit).
pub fn check_out_folder(out: &Path, resume: bool) -> Result<(), StylizeError> {
    checkpoint::recover_interrupted_save(out)?;
    let dir = checkpoint::checkpoint_dir(out);
    match (resume, dir.exists()) {
        (false, true) => Err(StylizeError::Input(format!(
            "{} holds a checkpoint of an earlier run: pass --resume to continue it, or choose \
             another output folder",
            out.display()
        ))),
        (true, false) => Err(StylizeError::Checkpoint {
            path: dir,
            message: "there is no checkpoint to resume from: run without --resume".into(),
        }),
        _ => Ok(()),
    }
}

/// Checks the style inputs of `settings` that [`stylize`] would otherwise open only after a
/// modality's preparation: the model files exist ([`resolve_weights`]), the style image
/// decodes, the CLIP configuration parses.
pub fn check_style_inputs(settings: &StyleSettings) -> Result<(), StylizeError> {
    resolve_weights(settings)?;
    if let Some(path) = &settings.style_image {
        load_picture(path, [0.0; 3], &Device::Cpu)
            .map_err(|e| StylizeError::Input(format!("style image: {e}")))?;
    }
    if let Some(path) = &settings.clip_config {
        ClipConfig::from_json_file(path)?;
    }
    Ok(())
}

/// The model files a run reads, found by [`resolve_weights`].
#[derive(Clone, Debug, PartialEq)]
pub struct WeightFiles {
    /// CLIP weights (safetensors).
    pub clip: PathBuf,
    /// CLIP's `tokenizer.json`.
    pub tokenizer: PathBuf,
    /// VGG-19 weights, when the content loss is on.
    pub vgg: Option<PathBuf>,
}

/// Finds the CLIP, tokenizer and (when `lambda_content > 0`) VGG-19 files of `settings`:
/// the explicit path, then the environment variable, then the Hugging Face cache, then a
/// download when the `download` feature of style-loss is on. A modality calls it before any
/// long preparation (a fit), so a missing file is reported at once, naming where to put it.
///
/// Every file is looked for before an error is returned, so the error lists all the missing
/// ones at once.
pub fn resolve_weights(settings: &StyleSettings) -> Result<WeightFiles, StylizeError> {
    let clip = CLIP_VIT_B_32_WEIGHTS.resolve(settings.clip_weights.as_deref());
    let tokenizer = CLIP_TOKENIZER.resolve(settings.tokenizer.as_deref());
    let vgg = if settings.lambda_content > 0.0 {
        Some(VGG19_WEIGHTS.resolve(settings.vgg_weights.as_deref()))
    } else {
        None
    }
    .transpose();
    match (clip, tokenizer, vgg) {
        (Ok(clip), Ok(tokenizer), Ok(vgg)) => Ok(WeightFiles {
            clip,
            tokenizer,
            vgg,
        }),
        (clip, tokenizer, vgg) => {
            let missing: Vec<String> = [clip.err(), tokenizer.err(), vgg.err()]
                .into_iter()
                .flatten()
                .map(|e| e.to_string())
                .collect();
            Err(StylizeError::Input(format!(
                "{} model file(s) missing:\n- {}",
                missing.len(),
                missing.join("\n- ")
            )))
        }
    }
}

/// The style loss of `settings` (the style image over `background`) and the masks it uses:
/// `masks` when the background weight is positive, else none.
fn build_loss(
    settings: &StyleSettings,
    masks: Option<ViewMasks>,
    background: [f32; 3],
    device: &Device,
) -> Result<(StyleLoss, Option<ViewMasks>), StylizeError> {
    let style_image = match &settings.style_image {
        Some(path) => Some(
            load_picture(path, background, device)
                .map_err(|e| StylizeError::Input(format!("style image: {e}")))?,
        ),
        None => None,
    };
    let clip_config = match &settings.clip_config {
        Some(path) => ClipConfig::from_json_file(path)?,
        None => ClipConfig::vit_b_32(),
    };
    let files = resolve_weights(settings)?;
    let tokenizer = ClipTokenizer::from_file(&files.tokenizer)?;
    let mut clip = ClipModel::load(&clip_config, &files.clip, device)?;
    let direction = match (&style_image, &settings.style_prompt) {
        (Some(image), _) => {
            StyleDirection::from_image(&clip, &tokenizer, image, &settings.source_prompt)?
        }
        (None, Some(prompt)) => {
            StyleDirection::from_text(&clip, &tokenizer, prompt, &settings.source_prompt)?
        }
        (None, None) => {
            return Err(StylizeError::Config(
                "style_prompt, style_image: a style is required".into(),
            ))
        }
    };
    clip.drop_text_tower();
    let vgg = match &files.vgg {
        Some(path) => Some(Vgg19Features::load(
            path,
            Vgg19Widths(settings.vgg_widths),
            device,
        )?),
        None => None,
    };
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
    Ok((
        StyleLoss::new(clip, vgg, direction, weights, patches)?,
        masks,
    ))
}
