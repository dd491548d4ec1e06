//! One stylization run: load the PLY, the dataset and the models, check that they fit together,
//! then (and only then) create the output folder, train with checkpoints, and write the outputs.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use candle_core::Device;
use gs_core::adam::{Adam, AdamHyper, GroupConfig, LrSchedule};
use gs_core::model::{BaseModel, GaussianLrs};
use gs_core::raster::render;
use gs_core::train::{resumed_sampler, train, StepReport, TrainConfig};
use gs_core::{GaussianSet, Image};
use indicatif::{ProgressBar, ProgressStyle};
use style_loss::image_layout::hwc_to_tensor;
use style_loss::weight_resolution::{CLIP_TOKENIZER, CLIP_VIT_B_32_WEIGHTS, VGG19_WEIGHTS};
use style_loss::{
    ClipConfig, ClipModel, ClipTokenizer, LossWeights, PatchSettings, StyleDirection, StyleLoss,
    StyleObjective, Vgg19Features, Vgg19Widths,
};

use super::checkpoint::{self, changed_fields, Checkpoint};
use super::loss_plot::write_plot;
use super::outputs::{
    write_json, write_preview, StepLosses, CONFIG_JSON, LOSSES_JSON, LOSSES_PNG, STYLIZED_PLY,
};
use super::{StylizeConfig, StylizeError};
use crate::dataset::nerf_synthetic::{self, Split};
use crate::dataset::{colmap, Background, Dataset, Layout, LoadOptions};
use gs_core::ply::{read_ply_with_format, write_ply, PlyGaussians};

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

/// What a finished run produced.
#[derive(Clone, Debug)]
pub struct RunSummary {
    /// The stylized parameters.
    pub gaussians: GaussianSet,
    /// The losses of every step, including those before a resume.
    pub losses: Vec<StepLosses>,
    /// The stylized PLY.
    pub stylized_ply: PathBuf,
}

/// Runs the stylization `config` describes (see the module documentation). Bad inputs are
/// reported before anything is written; a fresh run refuses an output folder that holds a
/// checkpoint. When [`RunOptions::stop`] is set, the run ends after the current step with a
/// checkpoint of it and [`StylizeError::Interrupted`].
pub fn run(config: &StylizeConfig, options: &RunOptions) -> Result<RunSummary, StylizeError> {
    config.validate()?;
    let (ply, format) = read_ply_with_format(config.ply_path())?;
    let dataset = load_dataset(config)?;
    check_inputs(config, &dataset)?;
    let device = Device::Cpu;
    let (loss, masks) = build_loss(config, &dataset, &device)?;
    let mut objective = StyleObjective::new(
        loss,
        &dataset.images,
        masks.as_deref(),
        config.seed.wrapping_add(PATCH_SEED_OFFSET),
        &device,
    )?;
    let mut model = ply.gaussians.clone();
    let mut adam = Adam::new(
        optimizer_groups(config, dataset.extent),
        &model.group_lens(),
        AdamHyper::default(),
    );
    let config_json = serde_json::to_value(config).expect("the config serializes");
    let out = config.out_path();
    let mut losses = Vec::new();
    if options.resume {
        let saved = checkpoint::load(out)?;
        let bad = |message: String| StylizeError::Checkpoint {
            path: checkpoint::checkpoint_dir(out),
            message,
        };
        let changed = changed_fields(&saved.config, &config_json);
        if !changed.is_empty() {
            return Err(bad(format!(
                "saved by a run with different values of {}; resume with the same settings",
                changed.join(", ")
            )));
        }
        if saved.gaussians.len() != model.len() || saved.gaussians.sh_degree() != model.sh_degree()
        {
            return Err(bad(format!(
                "{} Gaussians of SH degree {}, the PLY has {} of degree {}",
                saved.gaussians.len(),
                saved.gaussians.sh_degree(),
                model.len(),
                model.sh_degree()
            )));
        }
        adam.restore_state(&saved.adam_state)?;
        if adam.step_count() != saved.step {
            return Err(bad(format!(
                "the optimizer took {} steps, the state says {}",
                adam.step_count(),
                saved.step
            )));
        }
        if saved.step > config.steps {
            return Err(bad(format!(
                "saved at step {}, past the {} steps asked for",
                saved.step, config.steps
            )));
        }
        model = saved.gaussians;
        objective.set_rng(saved.rng);
        losses = saved.losses;
    } else {
        checkpoint::recover_interrupted_save(out)?;
        if checkpoint::checkpoint_dir(out).exists() {
            return Err(StylizeError::Input(format!(
                "{} holds a checkpoint of an earlier run: pass --resume to continue it, or choose \
                 another output folder",
                out.display()
            )));
        }
    }

    std::fs::create_dir_all(out).map_err(|source| StylizeError::Io {
        path: out.to_path_buf(),
        source,
    })?;
    write_json(&out.join(CONFIG_JSON), config)?;
    let train_config = TrainConfig {
        steps: config.steps,
        background: dataset.background,
    };
    let mut sampler = resumed_sampler(dataset.views.len(), config.seed, adam.step_count());
    let bar = progress_bar(options.progress, config.steps, adam.step_count());
    let every = config.checkpoint_every;
    while adam.step_count() < config.steps {
        train(
            &mut model,
            &dataset.views,
            &mut objective,
            &mut adam,
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
        let stopped = options.stop.load(Ordering::SeqCst) && adam.step_count() < config.steps;
        if stopped || adam.step_count().checked_rem(every) == Some(0) {
            checkpoint::save(
                out,
                &Checkpoint {
                    step: adam.step_count(),
                    gaussians: model.clone(),
                    adam_state: adam.save_state(),
                    rng: objective.rng().clone(),
                    config: config_json.clone(),
                    losses: losses.clone(),
                },
            )?;
        }
        if stopped {
            bar.abandon();
            return Err(StylizeError::Interrupted {
                step: adam.step_count(),
                out: out.to_path_buf(),
            });
        }
    }
    bar.finish();

    let stylized_ply = out.join(STYLIZED_PLY);
    let stylized = PlyGaussians {
        gaussians: model,
        extras: ply.extras,
    };
    write_ply(&stylized_ply, &stylized, format)?;
    for &v in &config.preview_views {
        let camera = &dataset.views[v].camera;
        let before = render(&ply.gaussians, camera, dataset.background).image;
        let after = render(&stylized.gaussians, camera, dataset.background).image;
        write_preview(out, v, &before, &after)?;
    }
    write_json(&out.join(LOSSES_JSON), &losses)?;
    let totals: Vec<f32> = losses.iter().map(|l| l.total).collect();
    write_plot(&out.join(LOSSES_PNG), &totals)?;
    Ok(RunSummary {
        gaussians: stylized.gaussians,
        losses,
        stylized_ply,
    })
}

impl StepLosses {
    /// The losses of a training step's report.
    pub fn from_report(report: &StepReport) -> Self {
        Self {
            step: report.step,
            view: report.view,
            total: report.value.loss,
            terms: report.value.terms.iter().cloned().collect(),
        }
    }
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

fn progress_bar(show: bool, steps: u64, done: u64) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(steps);
    bar.set_style(
        ProgressStyle::with_template(
            "{bar:30} {pos}/{len} [{elapsed_precise} < {eta_precise}] {msg}",
        )
        .expect("a valid template"),
    );
    bar.set_position(done);
    bar.reset_eta();
    bar
}

/// The dataset in `data`: NeRF-synthetic when `transforms_train.json` is there, COLMAP when
/// `sparse/` is.
fn load_dataset(config: &StylizeConfig) -> Result<Dataset, StylizeError> {
    let data = config.data_path();
    let options = LoadOptions {
        background: if config.white_background {
            Background::White
        } else {
            Background::Black
        },
        downscale: config.resolution,
    };
    let wrap = |source| StylizeError::Dataset {
        path: data.to_path_buf(),
        source: Box::new(source),
    };
    match Layout::detect(data) {
        Some(Layout::NerfSynthetic) => {
            nerf_synthetic::load(data, Split::Train, &options).map_err(wrap)
        }
        Some(Layout::Colmap) => colmap::load(data, &options).map_err(wrap),
        None => Err(StylizeError::Input(format!(
            "dataset {}: neither {} (NeRF-synthetic) nor sparse/ (COLMAP) was found",
            data.display(),
            Split::Train.file_name()
        ))),
    }
}

/// Checks that the patches fit every view and that the preview views exist.
fn check_inputs(config: &StylizeConfig, dataset: &Dataset) -> Result<(), StylizeError> {
    if config.lambda_patch > 0.0 {
        for (i, img) in dataset.images.iter().enumerate() {
            if (img.width as usize) < config.patch_size || (img.height as usize) < config.patch_size
            {
                return Err(StylizeError::Input(format!(
                    "patch_size {} is larger than view {i} ({}, {}x{}); lower patch_size or \
                     the resolution divisor",
                    config.patch_size,
                    dataset.image_paths[i].display(),
                    img.width,
                    img.height
                )));
            }
        }
    }
    let count = dataset.views.len();
    if let Some(v) = config.preview_views.iter().find(|&&v| v >= count) {
        return Err(StylizeError::Input(format!(
            "preview_views: view {v} does not exist (the dataset has {count})"
        )));
    }
    Ok(())
}

/// The style image as a `[1, 3, h, w]` tensor, transparent pixels over `background`.
fn load_style_image(
    path: &Path,
    background: [f32; 3],
    device: &Device,
) -> Result<candle_core::Tensor, StylizeError> {
    let image = Image::load(path, background)
        .map_err(|e| StylizeError::Input(format!("style image: {e}")))?;
    Ok(hwc_to_tensor(
        &image.data,
        image.height as usize,
        image.width as usize,
        device,
    )?)
}

/// One background mask per view, `[h * w]` each, 1 = background.
type ViewMasks = Vec<Vec<f32>>;

/// The style loss and the background masks (when every view has one and the background weight
/// is positive).
fn build_loss(
    config: &StylizeConfig,
    dataset: &Dataset,
    device: &Device,
) -> Result<(StyleLoss, Option<ViewMasks>), StylizeError> {
    let style_image = match &config.style_image {
        Some(path) => Some(load_style_image(path, dataset.background, device)?),
        None => None,
    };
    let clip_config = match &config.clip_config {
        Some(path) => ClipConfig::from_json_file(path)?,
        None => ClipConfig::vit_b_32(),
    };
    let clip_weights = CLIP_VIT_B_32_WEIGHTS.resolve(config.clip_weights.as_deref())?;
    let tokenizer =
        ClipTokenizer::from_file(&CLIP_TOKENIZER.resolve(config.tokenizer.as_deref())?)?;
    let mut clip = ClipModel::load(&clip_config, &clip_weights, device)?;
    let direction = match (&style_image, &config.style_prompt) {
        (Some(image), _) => {
            StyleDirection::from_image(&clip, &tokenizer, image, &config.source_prompt)?
        }
        (None, Some(prompt)) => {
            StyleDirection::from_text(&clip, &tokenizer, prompt, &config.source_prompt)?
        }
        (None, None) => {
            return Err(StylizeError::Config(
                "style_prompt, style_image: a style is required".into(),
            ))
        }
    };
    clip.drop_text_tower();
    let vgg = if config.lambda_content > 0.0 {
        let path = VGG19_WEIGHTS.resolve(config.vgg_weights.as_deref())?;
        Some(Vgg19Features::load(
            &path,
            Vgg19Widths(config.vgg_widths),
            device,
        )?)
    } else {
        None
    };
    let masks: Option<ViewMasks> = dataset
        .masks
        .iter()
        .map(|m| m.as_ref().map(|m| m.data.clone()))
        .collect();
    let masks = masks.filter(|_| config.lambda_background > 0.0);
    let weights = LossWeights {
        directional: config.lambda_directional,
        patch: config.lambda_patch,
        content: config.lambda_content,
        background: if masks.is_some() {
            config.lambda_background
        } else {
            0.0
        },
    };
    let patches = PatchSettings {
        patch_size: config.patch_size,
        num_patches: config.num_patches,
        distortion_scale: config.distortion_scale,
    };
    Ok((
        StyleLoss::new(clip, vgg, direction, weights, patches)?,
        masks,
    ))
}

/// The Adam groups of method.md, in [`gs_core::gaussians::PARAM_NAMES`] order: means
/// `means_lr_start * extent -> means_lr_end * extent` over `means_lr_steps`, then scales,
/// rotations, opacities, SH DC (`feature_lr`) and SH rest (`feature_lr / 20`).
pub fn optimizer_groups(config: &StylizeConfig, extent: f64) -> Vec<GroupConfig> {
    GaussianLrs {
        means: LrSchedule::Exponential {
            start: config.means_lr_start * extent,
            end: config.means_lr_end * extent,
            steps: config.means_lr_steps,
        },
        scales: config.scales_lr,
        rotations: config.rotations_lr,
        opacities: config.opacity_lr,
        feature: config.feature_lr,
    }
    .groups()
}
