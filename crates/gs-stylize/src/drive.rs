//! The order every stylization runs in, written once: a modality's configuration implements
//! [`Modality`] (what is its own: its inputs, its base model, its fit, its views, its outputs)
//! and [`run`] calls it in this order:
//!
//! 1. the modality's own checks ([`Modality::check`]), then [`prepare`]: settings, output
//!    folder and checkpoint, weights, style image, devices, every problem at once;
//! 2. the inputs ([`Modality::load_inputs`]: the picture, the video, the scene), checked
//!    against the settings (the patch size) before any long work; where their sizes can be
//!    read without decoding them ([`Modality::input_pixels`]), a run too large for this
//!    machine's memory is refused first;
//! 3. the base model: the one given (`--model`), this run's own fit when it resumes, or a fit
//!    with progress ([`fit_with_progress`]; Ctrl-C ends it with
//!    [`StylizeError::InterruptedFit`], nothing written), kept as `BASE_MODEL` in the output
//!    folder ([`Modality::keep_fit`]) with `fit.json` (its steps, time and PSNR:
//!    [`crate::outputs::FitReport`]);
//! 4. the job ([`Modality::job`]: views, ground truths, optimizer groups from the
//!    configuration's `learning_rates`) and the stylization ([`PreparedRun::stylize`]);
//! 5. the modality's outputs ([`Modality::write_outputs`]), then the checkpoint is marked
//!    finished ([`mark_finished`]).
//!
//! A binary's `fit` subcommand runs in one order too ([`run_fit`]): the output folder checked,
//! the inputs loaded with their progress, the device opened, the fit with progress (Ctrl-C
//! ends it with nothing written), then the folder made and the outputs written (the folder
//! removed again when this run made it and writing fails).

use std::error::Error;
use std::ops::ControlFlow;
use std::path::Path;
use std::time::Instant;

use gs_core::dataset::ImageProgress;
use gs_core::device::DeviceChoice;
use gs_core::train::StepReport;
use gs_wgpu::backend::Backend;
use gs_wgpu::GpuModel;
use serde::Serialize;

use crate::checkpoint::{checkpoint_dir, mark_finished};
use crate::interrupt::stop_on_ctrl_c;
use crate::memory_estimate::{check_memory, machine_memory, MemoryEstimate};
use crate::outputs::{
    create_folder, into_new_folder, into_new_folder_unless, write_json, FitReport, FIT_JSON,
};
use crate::progress::{fit_with_progress, with_loading_progress};
use crate::writable::check_output_folder;
use crate::{
    open_device, prepare, PreparedRun, RunOptions, StyleSettings, StylizeError, StylizeJob,
    StylizeOutcome,
};

/// The per-step callback a fit calls: it shows the progress and asks the fit to stop (Ctrl-C).
pub type OnStep<'a> = &'a mut dyn FnMut(&StepReport) -> ControlFlow<()>;

/// One modality's part of a stylization run, implemented by its configuration (serialized
/// whole into the run's `config.json`). [`run`] calls these in the module's order.
pub trait Modality: Serialize {
    /// The model the run stylizes.
    type Model: GpuModel;
    /// What the run loads before its base model (the picture, the video, the scene) and what
    /// it keeps for its outputs.
    type Inputs;
    /// What a fit returns (the model, and what the fit measured).
    type Fit;
    /// What a finished run returns.
    type Outputs;
    /// The modality's error; every shared failure converts into it.
    type Error: From<StylizeError>;

    /// The file, in the output folder, a run that fits its base model keeps it in (a resumed
    /// run reads it back instead of fitting again).
    const BASE_MODEL: &'static str;
    /// What a fit fits, in messages (`the picture`).
    const FITTED: &'static str;

    /// The settings every modality shares.
    fn settings(&self) -> &StyleSettings;

    /// The output folder.
    fn out(&self) -> Result<&Path, Self::Error>;

    /// Checks the modality's own fields (and its `learning_rates` against its groups) before
    /// any work; [`prepare`] checks the shared settings.
    fn check(&self) -> Result<(), Self::Error>;

    /// The base model given by the user; none when the run fits its own.
    fn given_model(&self) -> Option<&Path>;

    /// The training views' sizes in pixels (after any shrinking) and the stored size of the
    /// largest input picture, read without decoding anything, where that is cheap: the run is
    /// refused before it decodes a picture too large for this machine. None (the default):
    /// the estimate comes once the inputs are loaded ([`PreparedRun::stylize`]).
    fn input_pixels(&self) -> Result<Option<InputPixels>, Self::Error> {
        Ok(None)
    }

    /// Loads and checks the inputs. `model` is the file the base model will be read from (the
    /// given one, or this run's own fit when resuming; none before a fit), for what it records.
    fn load_inputs(
        &self,
        run: &PreparedRun,
        model: Option<&Path>,
    ) -> Result<Self::Inputs, Self::Error>;

    /// Reads the base model at `path` and checks it against the inputs; `own_fit` when it is
    /// this run's earlier fit (a resumed run), which must match this configuration's fit.
    fn read_model(
        &self,
        inputs: &Self::Inputs,
        path: &Path,
        own_fit: bool,
        run: &PreparedRun,
    ) -> Result<Self::Model, Self::Error>;

    /// Steps of the fit.
    fn fit_steps(&self) -> u64;

    /// The step counts after which the fit's later stages begin, for the time left
    /// ([`crate::progress::Progress::with_stages`]); none by default (a fit of one stage).
    fn fit_stages(&self) -> Vec<u64> {
        Vec::new()
    }

    /// Fits the base model to the inputs on the run's device, calling `on_step` after every
    /// step and stopping when it breaks.
    fn fit(
        &self,
        inputs: &Self::Inputs,
        run: &PreparedRun,
        on_step: OnStep<'_>,
    ) -> Result<Self::Fit, Self::Error>;

    /// Writes the fitted base model to `path` (the output folder's `BASE_MODEL`, the folder
    /// made) with what the fit measured, and returns the model.
    fn keep_fit(
        &self,
        inputs: &Self::Inputs,
        fit: Self::Fit,
        path: &Path,
    ) -> Result<Self::Model, Self::Error>;

    /// The mean PSNR of the fitted `model` over the training views, dB, for the run's
    /// `fit.json` and summary; none by default (not measured).
    fn fit_psnr(
        &self,
        _inputs: &Self::Inputs,
        _model: &mut Self::Model,
        _run: &PreparedRun,
    ) -> Result<Option<f64>, Self::Error> {
        Ok(None)
    }

    /// The stylization job of `model` over the inputs (which it may add to, e.g. renders of
    /// the model before stylization for a preview).
    fn job(
        &self,
        inputs: &mut Self::Inputs,
        model: Self::Model,
        run: &PreparedRun,
    ) -> Result<StylizeJob<Self::Model>, Self::Error>;

    /// Writes the modality's outputs of the stylized model into the output folder.
    fn write_outputs(
        &self,
        inputs: Self::Inputs,
        outcome: StylizeOutcome<Self::Model>,
        run: &PreparedRun,
    ) -> Result<Self::Outputs, Self::Error>;
}

/// The pixels of a run's inputs, read from their headers ([`Modality::input_pixels`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct InputPixels {
    /// Pixels of each training view, as trained (after any shrinking).
    pub views: Vec<u64>,
    /// Pixels of the largest input picture as stored.
    pub largest_stored: u64,
}

impl InputPixels {
    /// The pixels of `views` (as trained) and of the largest picture as stored, the pair a
    /// dataset reader gives (`gs_core::dataset::nerf_synthetic::training_pixels`).
    pub fn new((views, largest_stored): (Vec<u64>, u64)) -> Self {
        Self {
            views,
            largest_stored,
        }
    }
}

/// Runs the stylization `modality` describes, in the order of the module documentation. A run
/// that fails leaves no output folder it made, unless it saved a checkpoint to resume from
/// (an interruption, or a failure after the first checkpoint).
pub fn run<M: Modality>(modality: &M, options: &RunOptions) -> Result<M::Outputs, M::Error> {
    modality.check()?;
    let out = modality.out()?;
    let resumable = |out: &Path| checkpoint_dir(out).is_dir();
    into_new_folder_unless(out, resumable, || run_into(modality, out, options))
}

/// [`run`] into the output folder `out`.
fn run_into<M: Modality>(
    modality: &M,
    out: &Path,
    options: &RunOptions,
) -> Result<M::Outputs, M::Error> {
    let prepared = prepare(modality.settings(), out, options.clone())?;
    if let Some(pixels) = modality.input_pixels()? {
        let estimate = MemoryEstimate::of(modality.settings(), &pixels.views, 0)
            .before_decoding(pixels.largest_stored);
        check_memory(&estimate, machine_memory())?;
    }
    let base = out.join(M::BASE_MODEL);
    let own_fit = modality.given_model().is_none() && options.resume && base.exists();
    let source = match modality.given_model() {
        Some(path) => Some(path),
        None => own_fit.then_some(base.as_path()),
    };
    let mut inputs = modality.load_inputs(&prepared, source)?;
    let model = match source {
        Some(path) => modality.read_model(&inputs, path, own_fit, &prepared)?,
        None => {
            let (steps, stages) = (modality.fit_steps(), modality.fit_stages());
            let started = Instant::now();
            let fit = fit_with_progress(M::FITTED, steps, &stages, options, |on_step| {
                modality.fit(&inputs, &prepared, on_step)
            })?;
            let seconds = started.elapsed().as_secs_f64();
            create_folder(out)?;
            let mut model = modality.keep_fit(&inputs, fit, &base)?;
            let psnr_db = modality.fit_psnr(&inputs, &mut model, &prepared)?;
            let report = FitReport {
                steps,
                seconds,
                psnr_db,
                gaussians: None,
                test_psnr_db: None,
            };
            write_json(&out.join(FIT_JSON), &report)?;
            model
        }
    };
    let job = modality.job(&mut inputs, model, &prepared)?;
    let outcome = prepared.stylize(modality, job)?;
    let outputs = modality.write_outputs(inputs, outcome, &prepared)?;
    mark_finished(out, modality.settings().steps)?;
    Ok(outputs)
}

/// What a binary's `fit` subcommand asks of [`run_fit`].
#[derive(Clone, Debug)]
pub struct FitCommand<'a> {
    /// The output folder.
    pub out: &'a Path,
    /// The device the fit runs on.
    pub device: DeviceChoice,
    /// Whether the progress is shown (not `--quiet`).
    pub progress: bool,
    /// What is fitted, in messages (`the picture`).
    pub what: &'static str,
    /// Steps of the fit.
    pub steps: u64,
    /// Step counts after which the fit's later stages begin (see [`Modality::fit_stages`]).
    pub stages: Vec<u64>,
}

/// What a `fit` subcommand's outputs say: the line it prints, and the fitted model's mean PSNR
/// over the training views (dB), for its `fit.json`.
#[derive(Clone, Debug)]
pub struct FitWritten {
    /// The line printed once the outputs are written.
    pub line: String,
    /// The mean PSNR of the fit over the training views, dB.
    pub psnr_db: f64,
    /// Gaussians of the fitted model.
    pub gaussians: usize,
    /// The mean PSNR over held-out test views, dB, when the fit held some out.
    pub test_psnr_db: Option<f64>,
    /// The fit's wall time, seconds: this run's, and that of any stopped run it went on from.
    pub seconds: f64,
}

/// Runs a `fit` subcommand in the order of the module documentation: `load` reads the inputs
/// (reporting each picture to the progress it is given), `fit` fits them on the opened
/// device calling its per-step callback, and `write` writes the outputs into `command.out`
/// (made by then) from the inputs, the fit, the device and this run's wall time in seconds
/// (to which a fit that went on from a stopped one adds that one's, [`FitWritten::seconds`]);
/// then `fit.json` ([`FitReport`], as a `stylize` that fits writes it) is written and the
/// line printed.
pub fn run_fit<I, F>(
    command: &FitCommand<'_>,
    load: impl FnOnce(&ImageProgress) -> Result<I, Box<dyn Error>>,
    fit: impl FnOnce(&I, &Backend, OnStep<'_>) -> Result<F, Box<dyn Error>>,
    write: impl FnOnce(&I, F, &Backend, f64) -> Result<FitWritten, Box<dyn Error>>,
) -> Result<(), Box<dyn Error>> {
    let out = command.out;
    check_output_folder(out)?;
    let inputs = with_loading_progress(command.progress, "loading pictures", load)?;
    let options = RunOptions {
        resume: false,
        progress: command.progress,
        stop: stop_on_ctrl_c()?,
    };
    let backend = open_device(command.device)?;
    let started = Instant::now();
    let fitted = fit_with_progress(
        command.what,
        command.steps,
        &command.stages,
        &options,
        |on_step| fit(&inputs, &backend, on_step),
    )?;
    let seconds = started.elapsed().as_secs_f64();
    let written = into_new_folder(out, || {
        create_folder(out)?;
        let written = write(&inputs, fitted, &backend, seconds)?;
        let report = FitReport {
            steps: command.steps,
            seconds: written.seconds,
            psnr_db: Some(written.psnr_db),
            gaussians: Some(written.gaussians),
            test_psnr_db: written.test_psnr_db,
        };
        write_json(&out.join(FIT_JSON), &report)?;
        Ok::<_, Box<dyn Error>>(written)
    })?;
    println!("{}", written.line);
    Ok(())
}
