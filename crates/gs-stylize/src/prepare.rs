//! The first phase of a stylization, which [`crate::drive::run`] calls before any long work:
//! [`prepare`] checks everything a run needs (settings, output folder and checkpoint, weights,
//! style image, CLIP configuration, devices), reports every problem at once, opens the devices
//! and loads the loss's models. [`PreparedRun::stylize`] ([`crate::stylize`]) is the second.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use candle_core::Device;
use gs_wgpu::backend::OpenDevice;
use gs_wgpu::backend::{Backend, DeviceChoice};
use style_loss::auto_precision::{
    choose_clip, choose_vgg, cpu_bf16_switch, AutoChoice, ClipProducts,
};
use style_loss::compute_device;
use style_loss::{
    ClipConfig, ClipModel, ClipPrecision, ClipTokenizer, StyleDirection, Vgg19Features,
    Vgg19Widths, VggPrecision,
};

use crate::checkpoint;
use crate::picture::load_style_picture;
use crate::weights::{resolve_weights, WeightFiles};
use crate::writable::check_output_folder;
use crate::{StyleSettings, StylizeError};

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

/// Opens the device `choice` names and prints it in one line (`device: ...`).
pub fn open_device(choice: DeviceChoice) -> Result<Backend, StylizeError> {
    let backend = choice.open()?;
    println!("device: {}", backend.describe());
    Ok(backend)
}

/// A stylization run whose inputs are all checked ([`prepare`]), on an opened device.
#[derive(Debug)]
pub struct PreparedRun {
    pub(crate) settings: StyleSettings,
    pub(crate) out: PathBuf,
    pub(crate) options: RunOptions,
    pub(crate) backend: Backend,
    pub(crate) loss_device: Device,
    pub(crate) models: StyleModels,
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
    check(cpu_bf16_switch().map(drop).map_err(StylizeError::from));
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
}

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
pub(crate) struct StyleModels {
    pub(crate) clip: ClipModel,
    pub(crate) vgg: Option<Vgg19Features>,
    pub(crate) direction: StyleDirection,
    /// What CLIP's `auto` chose and why, when it was asked.
    pub(crate) clip_auto: Option<AutoChoice>,
    /// What VGG's `auto` chose and why, when it was asked.
    pub(crate) vgg_auto: Option<AutoChoice>,
}

/// The lines that say which formats CLIP and VGG run in, for those not asked for f32, with
/// what `auto` found where it chose.
fn precision_lines(settings: &StyleSettings, models: &StyleModels) -> Vec<String> {
    let clip = models.clip.precision();
    let clip_runs = if clip == ClipPrecision::Bf16 {
        "bf16 products".to_string()
    } else {
        clip.to_string()
    };
    let clip_line = (settings.clip_precision != ClipPrecision::F32)
        .then(|| precision_line("CLIP", &clip_runs, models.clip_auto.as_ref()));
    let vgg_line = models
        .vgg
        .as_ref()
        .filter(|_| settings.vgg_precision != VggPrecision::F32)
        .map(|vgg| {
            let runs = if vgg.precision() == VggPrecision::Bf16 {
                "bf16 backward products"
            } else {
                "f32"
            };
            precision_line("VGG", runs, models.vgg_auto.as_ref())
        });
    [clip_line, vgg_line].into_iter().flatten().collect()
}

/// The line that says which format a network (CLIP, VGG) runs in: what `runs`, and, when
/// `auto` chose it, why ("CLIP precision: bf16 products (auto: bf16 1.6x faster here)").
fn precision_line(network: &str, runs: &str, auto: Option<&AutoChoice>) -> String {
    match auto {
        Some(choice) => format!("{network} precision: {runs} (auto: {choice})"),
        None => format!("{network} precision: {runs}"),
    }
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
    // `auto` times the run's own batch: its patches and the whole view.
    let clip_auto = match settings.clip_precision {
        ClipPrecision::Auto => Some(choose_clip(
            device,
            ClipProducts::of(&clip_config.vision, settings.num_patches + 1),
        )?),
        _ => None,
    };
    let clip_precision = match &clip_auto {
        Some(choice) => settings.clip_precision.resolve(choice),
        None => settings.clip_precision,
    };
    let mut clip =
        ClipModel::load_with_precision(&clip_config, &files.clip, device, clip_precision)?;
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
    let widths = Vgg19Widths(settings.vgg_widths);
    let vgg_auto = match (&files.vgg, settings.vgg_precision) {
        (Some(_), VggPrecision::Auto) => Some(choose_vgg(device, widths)?),
        _ => None,
    };
    let vgg = match &files.vgg {
        Some(path) => {
            let precision = match &vgg_auto {
                Some(choice) => settings.vgg_precision.resolve(choice),
                None => settings.vgg_precision,
            };
            Some(Vgg19Features::load_with_precision(
                path, widths, device, precision,
            )?)
        }
        None => None,
    };
    Ok(StyleModels {
        clip,
        vgg,
        direction,
        clip_auto,
        vgg_auto,
    })
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
