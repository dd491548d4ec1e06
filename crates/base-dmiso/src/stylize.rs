//! Dynamic-scene stylization (CLIPGaussian on D-MiSo): a D-NeRF scene, fitted first unless a
//! fitted model is given (ours, or one the authors' code saved), is stylized with the paper's 4D
//! settings (`configs/4d.json`; `configs/4d-keep-background.json` adds the background term):
//! batches of up to 4 consecutive training views with their losses summed and divided by 4, the
//! sub-Gaussians, the
//! triangles, the deformation network and the time-rotation layer trained together.
//!
//! Every input (configuration, output folder and checkpoint, dataset, model, patch size, style
//! image, CLIP configuration, weight files) is checked before the fit. Outputs in `out`:
//! - `model.safetensors`: the stylized model, to stylize again, render or interpolate;
//! - `base.safetensors`: the fitted model when this run fitted it (a resumed run reuses it);
//! - `frames/00000.png ...`: the test views at their times, when the scene has a test split;
//! - `sweep/00000.png ...`, `preview.gif` (original | stylized) and `sweep.mp4` (with
//!   `ffmpeg`): the scene through time from its first test camera (else its first camera);
//! - `config.json`, `losses.json`, `losses.png` and `checkpoint/` (see gs-stylize).

use std::path::{Path, PathBuf};

use candle_core::Device;
use gs_core::adam::{GroupConfig, RateAt};
use gs_core::dataset::nerf_synthetic::{self, load_with_times, Split, TrainSplits};
use gs_core::dataset::{Background, Dataset, DatasetError, ImageProgress, LoadOptions};
use gs_core::model::View;
use gs_core::orbit::RobustBounds;
use gs_core::sampler::BatchOrder;
use gs_core::{GaussianSet, Image};
use gs_stylize::animation::{
    write_frames, write_mp4_or_warn, write_preview_gif, FRAMES_DIR, PREVIEW_GIF,
};
use gs_stylize::drive::{InputPixels, Modality, OnStep};
use gs_stylize::export::gaussians_at;
use gs_stylize::model_views::{all_empty, model_dataset, model_picture, nothing_seen, ModelViews};
use gs_stylize::outputs::{write_pair, PREVIEW_PNG};
use gs_stylize::progress::with_loading_progress;
use gs_stylize::rates::{GroupRate, GroupRates};
use gs_stylize::stylize::check_patches_fit;
use gs_stylize::viewer;
use gs_stylize::{
    Batches, PreparedRun, RenderClamp, RunError, RunOptions, StyleSettings, StylizeError,
    StylizeJob, StylizeOutcome,
};
use serde::{Deserialize, Serialize};

use crate::fit::{fit, mean_psnr, render_views, DynamicSceneFitSettings};
use crate::model::{group, Dmiso, GROUP_NAMES, TORCH_ADAM_EPS};
use crate::model_file::{self, read_authors, AuthorsFiles, DmisoFileError};

/// The stylized model.
pub const MODEL_FILE: &str = "model.safetensors";
/// The model fitted by this run.
pub const BASE_FILE: &str = "base.safetensors";

/// The most times a run's viewer page holds (frames of its time slider).
pub const VIEWER_TIMES: usize = 24;

/// The frames of the sweep through time.
pub const SWEEP_DIR: &str = "sweep";
/// The sweep as a video, when `ffmpeg` is installed.
pub const SWEEP_MP4: &str = "sweep.mp4";

/// Everything a dynamic-scene stylization needs (a flat JSON object: `configs/4d.json`). The
/// defaults are the paper's 4D settings ([`StyleSettings::paper_4d`]) and D-MiSo's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct DynamicSceneStylizeConfig {
    /// The D-NeRF scene: `transforms_train.json` (and `transforms_test.json`), every frame
    /// with a `time` in `[0, 1]`. Without it a given model is stylized alone: views from
    /// `views`, each view's ground truth the model's own render.
    pub data: Option<PathBuf>,
    /// A fitted model: our `.safetensors` file, or the folder D-MiSo's `train.py` wrote; none:
    /// fit one first.
    pub model: Option<PathBuf>,
    /// The iteration of the authors' folder to read (`best`, or a number); none: `best`, else
    /// the highest.
    #[serde(deserialize_with = "iteration_name")]
    pub iteration: Option<String>,
    /// Without `data`: where the views come from (`cameras`, `orbit`, `orbit_views`,
    /// `width`, `height`, `up`; see [`ModelViews`]; `up` is `[0, 0, 1]` here, D-NeRF's
    /// Blender frame). View `i` of `n` is at time `i / (n - 1)` (a camera file records no
    /// times) unless `times` says otherwise, its ground truth the model's render at that time.
    #[serde(flatten)]
    pub views: ModelViews,
    /// Without `data`: the views' times, this many evenly spaced in `[0, 1]` (`k / (N - 1)`,
    /// time 0 for one), view `i` at the `(i mod N)`-th; at least 1 and at most the number of
    /// views. None: view `i` of `n` at `i / (n - 1)`.
    pub times: Option<usize>,
    /// The output folder.
    pub out: Option<PathBuf>,
    /// The colour the pictures are composited over and the scene renders over: `white`
    /// (D-MiSo's `-w`), `black`, `"R,G,B"` or `[r, g, b]` in `[0, 1]`; none: the background the
    /// model records (our file's, or the authors' `cfg_args`), else white (CLIPGaussian's 4D
    /// examples).
    #[serde(deserialize_with = "gs_stylize::background::deserialize_optional")]
    pub background: Option<[f32; 3]>,
    /// Pictures wider than this many pixels are shrunk to it, the cameras with them (Pillow's
    /// bicubic of the 8-bit picture), as D-MiSo's loader does at its default `-r -1` (default
    /// 1600); 0 keeps every picture at its size (D-MiSo's `-r 1`).
    pub max_width: u32,
    /// Which splits train (and are fitted, when no model is given): `train_and_test` (D-MiSo's
    /// loader without `--eval`: the test frames after the training ones, the extent of both) or
    /// `train`. Unset (the default): as the authors' model folder's `cfg_args` says (`eval`
    /// overrides the command line in the authors' 4D code), else `train_and_test` (their
    /// example fit passes no `--eval`). The test views are rendered into `frames/` either way.
    pub train_splits: Option<TrainSplits>,
    /// Consecutive training views per step (runs of the views left in the epoch), their losses
    /// summed and divided by this size.
    pub batch_size: usize,
    /// The learning rate of each parameter group (`pseudomesh`, `alpha`, `attached_scale`,
    /// `attached_rotation`, `attached_opacity`, `attached_features_dc`,
    /// `attached_features_rest`, `deform`, `time_net`), by name, or `"frozen"` (see
    /// gs-stylize's `rates`); the defaults are the paper's and D-MiSo's ([`stylize_rates`]).
    pub learning_rates: GroupRates,
    /// Frames of the sweep through time.
    pub sweep_frames: usize,
    /// Frame rate of the sweep's preview and video.
    pub sweep_fps: f64,
    /// Cores of the fit (when no model is given; `--gaussians`).
    pub fit_gaussians: usize,
    /// Steps of the fit.
    pub fit_steps: u64,
    /// Static warm-up steps of the fit.
    pub fit_warm_up: u64,
    /// The fit's step at which the sub-Gaussians are created.
    pub fit_subs_from: u64,
    /// Cores kept with sub-Gaussians.
    pub fit_sub_cores: usize,
    /// Sub-Gaussians per core.
    pub fit_subs_per_core: usize,
    /// Views per step of the fit.
    pub fit_batch: usize,
    /// Width of the fitted deformation network.
    pub deform_width: usize,
    /// The style, the losses, the Gaussians' learning rates and the model files.
    #[serde(flatten)]
    pub style: StyleSettings,
}

impl Default for DynamicSceneStylizeConfig {
    fn default() -> Self {
        let fit = DynamicSceneFitSettings::default();
        Self {
            data: None,
            model: None,
            iteration: None,
            views: ModelViews {
                up: [0.0, 0.0, 1.0],
                ..ModelViews::default()
            },
            times: None,
            out: None,
            background: None,
            max_width: gs_core::wide_pictures::AUTHORS_MAX_WIDTH,
            train_splits: None,
            batch_size: 4,
            learning_rates: stylize_rates(),
            sweep_frames: 60,
            sweep_fps: 24.0,
            fit_gaussians: fit.points,
            fit_steps: fit.steps,
            fit_warm_up: fit.warm_up,
            fit_subs_from: fit.subs_from,
            fit_sub_cores: fit.sub_cores,
            fit_subs_per_core: fit.subs_per_core,
            fit_batch: fit.batch,
            deform_width: fit.deform_width,
            style: StyleSettings::paper_4d(),
        }
    }
}

impl DynamicSceneStylizeConfig {
    /// The background colour: the configured one, else `recorded` (the model's), else white.
    pub fn background(&self, recorded: Option<Background>) -> Background {
        background_of(self.background, recorded)
    }

    /// The fit this configuration asks for.
    pub fn fit_settings(&self) -> DynamicSceneFitSettings {
        DynamicSceneFitSettings {
            points: self.fit_gaussians,
            steps: self.fit_steps,
            warm_up: self.fit_warm_up,
            subs_from: self.fit_subs_from,
            sub_cores: self.fit_sub_cores,
            subs_per_core: self.fit_subs_per_core,
            batch: self.fit_batch,
            deform_width: self.deform_width,
            seed: self.style.seed,
            background: self.background(None).rgb(),
            ..DynamicSceneFitSettings::default()
        }
    }

    /// Checks the fields of this configuration that gs-stylize does not.
    fn check_fields(&self) -> Result<(), DynamicSceneStylizeError> {
        let bad = |m: String| Err(DynamicSceneStylizeError::Config(m));
        if self.batch_size == 0 {
            return bad("batch_size: must be at least 1 (--batch-size)".into());
        }
        self.learning_rates.check(&GROUP_NAMES)?;
        self.views.validate(self.data.is_some())?;
        match self.times {
            Some(_) if self.data.is_some() => {
                return bad("times: the views of data have their own times; drop --times".into())
            }
            Some(0) => return bad("times: 0: give at least 1 (--times)".into()),
            _ => {}
        }
        if !(self.sweep_fps.is_finite() && self.sweep_fps > 0.0) {
            return bad(format!(
                "sweep_fps: {} must be positive (--set sweep_fps=24)",
                self.sweep_fps
            ));
        }
        Ok(())
    }
}

/// The background of a run: the colour `given` (linear RGB), else the one the model records
/// (`recorded`), else white.
pub fn background_of(given: Option<[f32; 3]>, recorded: Option<Background>) -> Background {
    given
        .map(Background::from_rgb)
        .or(recorded)
        .unwrap_or(Background::White)
}

/// An iteration given as `"best"`, `"5000"` or `5000`.
fn iteration_name<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Option<String>, D::Error> {
    use serde::de::Error;
    match Option::<serde_json::Value>::deserialize(d)? {
        None | Some(serde_json::Value::Null) => Ok(None),
        Some(serde_json::Value::String(s)) => Ok(Some(s)),
        Some(serde_json::Value::Number(n)) => Ok(Some(n.to_string())),
        Some(other) => Err(D::Error::custom(format!(
            "{other} is not an iteration (best, or a number)"
        ))),
    }
}

/// The paper's 4D stylization rates with D-MiSo's (in [`GROUP_NAMES`] order): the
/// triangles' vertices (the "means") `1e-5 -> 1e-6` times the extent over 5000 steps, offsets
/// 1e-5, log-scales 0.001, quaternions 0.001, opacity 0.05, SH of every degree `feature_lr`
/// 0.025, the network `5e-5 -> 1e-6` over 5000 steps, the time-rotation layer 0.1.
pub fn stylize_rates() -> GroupRates {
    let constant = GroupRate::Constant;
    let decay = |start, end, times_extent| GroupRate::Decay {
        start,
        end,
        steps: 5000,
        times_extent,
    };
    GroupRates::new(GROUP_NAMES.into_iter().zip([
        decay(1e-5, 1e-6, true),
        constant(1e-5),
        constant(0.001),
        constant(0.001),
        constant(0.05),
        constant(0.025),
        constant(0.025),
        decay(5e-5, 1e-6, false),
        constant(0.1),
    ]))
}

/// The optimizer groups of a stylization of a scene of extent `extent` with `rates` (in
/// [`GROUP_NAMES`] order), with the authors' update rules.
pub fn stylize_groups(rates: &GroupRates, extent: f64) -> Result<Vec<GroupConfig>, StylizeError> {
    let names: Vec<String> = GROUP_NAMES.iter().map(|n| n.to_string()).collect();
    let mut groups = rates.optimizer_groups(&names, extent)?;
    authors_update_rules(&mut groups);
    Ok(groups)
}

/// What the authors' 4D loop does beyond the rates: the network's rate is updated after each
/// step (update `k` uses `lr(k - 1)`, the triangles' `lr(k)`), and the time-rotation layer has
/// its own Adam with torch's default epsilon 1e-8 (every other group 1e-15).
fn authors_update_rules(groups: &mut [GroupConfig]) {
    groups[group::DEFORM].rate_at = RateAt::PreviousIteration;
    groups[group::TIME_NET].eps = Some(TORCH_ADAM_EPS);
}

/// Why a 4D run could not run: the failures every modality shares, and the 4D run's own
/// ([`DynamicSceneFailure`]).
pub type DynamicSceneStylizeError = RunError<DynamicSceneFailure>;

/// What fails in a 4D run only; each names the file at fault.
#[derive(Debug, thiserror::Error)]
pub enum DynamicSceneFailure {
    /// A model file.
    #[error("{0}")]
    Model(#[from] DmisoFileError),
}

impl From<DmisoFileError> for DynamicSceneStylizeError {
    fn from(e: DmisoFileError) -> Self {
        Self::Own(e.into())
    }
}

/// What a finished run produced.
#[derive(Clone, Debug)]
pub struct DynamicSceneSummary {
    /// The stylized model.
    pub model: Dmiso,
    /// The renders of the test views (empty without a test split).
    pub test_renders: Vec<Image>,
    /// The frames of the sweep through time.
    pub sweep: Vec<Image>,
    /// Whether `sweep.mp4` was written (ffmpeg installed).
    pub wrote_mp4: bool,
}

/// The training and (when present) test splits of the D-NeRF scene in `data`, pictures wider
/// than `max_width` shrunk to it (0 keeps every size; see [`LoadOptions::max_width`]), each
/// picture told to `progress` as it is decoded.
pub fn load_scene(
    data: &Path,
    background: Background,
    max_width: u32,
    progress: Option<ImageProgress>,
) -> Result<(Dataset, Option<Dataset>), DatasetError> {
    let options = LoadOptions {
        background,
        downscale: 1,
        max_width,
        progress,
        ..LoadOptions::default()
    };
    let train = load_with_times(data, Split::Train, &options)?;
    let test = if nerf_synthetic::has_split(data, Split::Test)? {
        let test = load_with_times(data, Split::Test, &options)?;
        let (tw, th) = (train.images[0].width, train.images[0].height);
        if let Some((i, image)) = test
            .images
            .iter()
            .enumerate()
            .find(|(_, im)| (im.width, im.height) != (tw, th))
        {
            return Err(DatasetError::ImageSize {
                path: test.image_paths[i].clone(),
                expected: (tw, th),
                found: (image.width, image.height),
                says: format!(
                    "the train split's first picture, {},",
                    train.image_paths[0].display()
                ),
            });
        }
        Some(test)
    } else {
        None
    };
    Ok((train, test))
}

/// Reads a model: our file, or the folder the authors' code saved (at `iteration`).
pub fn read_model(
    path: &Path,
    iteration: Option<&str>,
    device: &Device,
) -> Result<Dmiso, DmisoFileError> {
    if path.is_dir() {
        read_authors(&AuthorsFiles::find(path, iteration)?, device)
    } else {
        model_file::load(path, device)
    }
}

/// `frames` views from `camera` at times evenly spread over `[0, 1]`.
pub fn sweep_views(camera: &gs_core::Camera, frames: usize) -> Vec<View> {
    (0..frames)
        .map(|i| View {
            camera: camera.clone(),
            time: if frames > 1 {
                i as f64 / (frames - 1) as f64
            } else {
                0.0
            },
        })
        .collect()
}

/// Runs the stylization `config` describes (see the module documentation).
pub fn run(
    config: &DynamicSceneStylizeConfig,
    options: &RunOptions,
) -> Result<DynamicSceneSummary, DynamicSceneStylizeError> {
    gs_stylize::drive::run(config, options)
}

/// The scene of a 4D run: its training views (the test split's appended where they train),
/// its test split, the background and, once the job is made, the sweep through time before
/// stylization.
#[derive(Debug)]
pub struct DynamicSceneInput {
    train: Dataset,
    test: Option<Dataset>,
    labels: Vec<String>,
    background: Background,
    device: Device,
    sweep: Vec<View>,
    original: Vec<Image>,
}

/// The times of `n` views made without data: with `times` `Some(k)`, view `i` at the `(i mod
/// k)`-th of `k` times evenly spaced in `[0, 1]` (time 0 for one); with `None`, view `i` at
/// `i / (n - 1)`. An error names `times` when it is 0 or more than `n`.
pub fn view_times(n: usize, times: Option<usize>) -> Result<Vec<f64>, DynamicSceneStylizeError> {
    let k = match times {
        None => n,
        Some(k) if (1..=n).contains(&k) => k,
        Some(k) => {
            return Err(DynamicSceneStylizeError::Config(format!(
                "times: {k}: give from 1 to the {n} views (lower --times or raise --orbit-views)"
            )))
        }
    };
    let at = |j: usize| {
        if k > 1 {
            j as f64 / (k - 1) as f64
        } else {
            0.0
        }
    };
    Ok((0..n).map(|i| at(i % k.max(1))).collect())
}

impl DynamicSceneStylizeConfig {
    /// `viewer.html`: the base model (the one given, or this run's fit) and the stylized one at
    /// up to [`VIEWER_TIMES`] times evenly spread over `[0, 1]` (fewer where the page would
    /// hold more than [`viewer::MAX_ANIMATED_GAUSSIANS`] Gaussians in all; none, said, where even one
    /// time would), seen from the training cameras.
    fn write_viewer(
        &self,
        out: &Path,
        stylized: &Dmiso,
        scene: &DynamicSceneInput,
        run: &PreparedRun,
    ) -> Result<(), DynamicSceneStylizeError> {
        let count = gaussians_at(stylized, 0.0)
            .map_err(StylizeError::Input)?
            .len();
        let times = (viewer::MAX_ANIMATED_GAUSSIANS / count.max(1)).min(VIEWER_TIMES);
        if times == 0 {
            if run.options().progress {
                eprintln!(
                    "{}: not written for {count} Gaussians (a viewer holds at most {} for now)",
                    viewer::VIEWER_HTML,
                    viewer::MAX_ANIMATED_GAUSSIANS
                );
            }
            return Ok(());
        }
        let base_path = self.model.clone().unwrap_or_else(|| out.join(BASE_FILE));
        let base = read_model(&base_path, self.iteration.as_deref(), run.loss_device())?;
        let at = |m: &Dmiso| -> Result<Vec<GaussianSet>, StylizeError> {
            (0..times)
                .map(|k| {
                    let t = if times > 1 {
                        k as f64 / (times - 1) as f64
                    } else {
                        0.0
                    };
                    gaussians_at(m, t).map_err(StylizeError::Input)
                })
                .collect()
        };
        let (before, after) = (at(&base)?, at(stylized)?);
        let animation =
            viewer::Animation::snapshots(&before, Some(&after)).map_err(StylizeError::Input)?;
        viewer::write_viewer(
            &out.join(viewer::VIEWER_HTML),
            &viewer::ViewerScene {
                title: format!("{}: {}", base_path.display(), self.style.label()),
                shown: viewer::Shown::Animated(animation),
                cameras: viewer::named_cameras(&scene.train.views, &scene.train.image_paths),
                background: scene.background.rgb(),
            },
        )?;
        Ok(())
    }

    /// The inputs of a run: its training views, each named by its picture, checked against
    /// the patch size and the batch size.
    fn scene_input(
        &self,
        train: Dataset,
        test: Option<Dataset>,
        background: Background,
        run: &PreparedRun,
    ) -> Result<DynamicSceneInput, DynamicSceneStylizeError> {
        let labels: Vec<String> = train
            .image_paths
            .iter()
            .map(|p| p.display().to_string())
            .collect();
        check_patches_fit(&self.style, &train.images[..1], &labels[..1])?;
        if self.batch_size > train.views.len() {
            return Err(DynamicSceneStylizeError::Config(format!(
                "batch_size: {} is more than the {} training views (lower --batch-size)",
                self.batch_size,
                train.views.len()
            )));
        }
        Ok(DynamicSceneInput {
            train,
            test,
            labels,
            background,
            device: run.loss_device().clone(),
            sweep: Vec::new(),
            original: Vec::new(),
        })
    }

    /// The training views of the model at `path` given without data: the views
    /// [`ModelViews::views`] chooses around its Gaussians at time 0, at [`view_times`], each with the model's render at that time over `background` (clamped to
    /// `[0, 1]`) as its picture; the extent INRIA's rule gives their cameras, or the model's
    /// robust radius where they stand at one point. Prints where the cameras came from when
    /// the run shows progress.
    fn model_scene(
        &self,
        path: &Path,
        background: Background,
        run: &PreparedRun,
    ) -> Result<Dataset, DynamicSceneStylizeError> {
        let mut model = read_model(path, self.iteration.as_deref(), run.loss_device())?;
        let at_start = gaussians_at(&model, 0.0)
            .map_err(|e| StylizeError::Input(format!("model {}: {e}", path.display())))?;
        let bounds = RobustBounds::of(&at_start)
            .map_err(|e| StylizeError::Input(format!("model {}: {e}", path.display())))?;
        let options = LoadOptions {
            max_width: self.max_width,
            ..LoadOptions::default()
        };
        let splits = self.train_splits.unwrap_or_default();
        let (found, from) = self.views.views(path, &bounds, splits, &options)?;
        let n = found.len();
        let times = view_times(n, self.times)?;
        let views: Vec<View> = found
            .into_iter()
            .zip(&times)
            .map(|(v, &time)| View {
                camera: v.view.camera,
                time,
            })
            .collect();
        let show = run.options().progress;
        if show {
            let spread = match self.times {
                Some(k) => format!("{k} time(s) evenly from 0 to 1"),
                None => "times evenly from 0 to 1".into(),
            };
            eprintln!(
                "cameras: {n} view(s) {from}, at {spread}; the ground truth is the model's own \
                 render"
            );
        }
        let rgb = background.rgb();
        let images: Vec<Image> =
            with_loading_progress(show, "rendering the model's views", |progress| {
                let rendered = render_views(&mut model, &views, rgb, run.backend());
                progress.report(n, n);
                rendered
            })?
            .into_iter()
            .map(model_picture)
            .collect();
        if all_empty(&images, rgb) {
            return Err(nothing_seen(path, n, &from).into());
        }
        Ok(model_dataset(views, images, rgb, &bounds))
    }
}

impl Modality for DynamicSceneStylizeConfig {
    type Model = Dmiso;
    type Inputs = DynamicSceneInput;
    type Fit = Dmiso;
    type Outputs = DynamicSceneSummary;
    type Error = DynamicSceneStylizeError;

    const BASE_MODEL: &'static str = BASE_FILE;
    const FITTED: &'static str = "the scene";

    fn settings(&self) -> &StyleSettings {
        &self.style
    }

    fn out(&self) -> Result<&Path, DynamicSceneStylizeError> {
        self.out.as_deref().ok_or_else(|| {
            DynamicSceneStylizeError::Config("out: is required (--out FOLDER)".into())
        })
    }

    fn check(&self) -> Result<(), DynamicSceneStylizeError> {
        self.check_fields()?;
        if self.data.is_none() && self.model.is_none() {
            return Err(DynamicSceneStylizeError::Config(
                "data: is required (--data FOLDER, a D-NeRF scene), unless a model is given \
                 alone (--model, whose own renders are then the pictures)"
                    .into(),
            ));
        }
        Ok(())
    }

    fn given_model(&self) -> Option<&Path> {
        self.model.as_deref()
    }

    /// The D-NeRF scene's sizes from its json files (and one picture header a split), the
    /// test split counted whichever splits train (it is rendered either way); none when they
    /// do not read (the loading reports them).
    fn input_pixels(&self) -> Result<Option<InputPixels>, DynamicSceneStylizeError> {
        let Some(data) = self.data.as_deref() else {
            return Ok(None);
        };
        let options = LoadOptions {
            max_width: self.max_width,
            ..LoadOptions::default()
        };
        Ok(
            nerf_synthetic::training_pixels(data, TrainSplits::TrainAndTest, &options)
                .ok()
                .map(InputPixels::new),
        )
    }

    /// The scene over the background this configuration or the model (`model`) records, with
    /// the splits that train (this configuration's, else as the given model's `cfg_args`
    /// says), checked against the patch size and the batch size.
    fn load_inputs(
        &self,
        run: &PreparedRun,
        model: Option<&Path>,
    ) -> Result<DynamicSceneInput, DynamicSceneStylizeError> {
        let recorded = model.map(model_file::recorded_background).transpose()?;
        let background = self.background(recorded.flatten());
        let Some(data) = self.data.as_deref() else {
            let path = self
                .model
                .as_deref()
                .expect("checked: data or a model is given");
            let train = self.model_scene(path, background, run)?;
            return self.scene_input(train, None, background, run);
        };
        let recorded_eval = match &self.model {
            Some(path) => model_file::recorded_eval(path)?,
            None => None,
        };
        let train_splits = self.train_splits.unwrap_or(match recorded_eval {
            Some(true) => TrainSplits::Train,
            Some(false) | None => TrainSplits::TrainAndTest,
        });
        let (mut train, test) =
            with_loading_progress(run.options().progress, "loading pictures", |progress| {
                load_scene(data, background, self.max_width, Some(progress.clone()))
            })?;
        if let (TrainSplits::TrainAndTest, Some(test)) = (train_splits, &test) {
            train.append(test.clone());
        }
        self.scene_input(train, test, background, run)
    }

    /// Our `.safetensors` file or the authors' folder (at `iteration`).
    fn read_model(
        &self,
        scene: &DynamicSceneInput,
        path: &Path,
        own_fit: bool,
        _run: &PreparedRun,
    ) -> Result<Dmiso, DynamicSceneStylizeError> {
        if own_fit {
            Ok(model_file::load(path, &scene.device)?)
        } else {
            Ok(read_model(path, self.iteration.as_deref(), &scene.device)?)
        }
    }

    fn fit_steps(&self) -> u64 {
        self.fit_steps
    }

    /// The deformation network's start and the sub-Gaussians' ([`DynamicSceneFitSettings::stages`]).
    fn fit_stages(&self) -> Vec<u64> {
        self.fit_settings().stages().to_vec()
    }

    fn fit(
        &self,
        scene: &DynamicSceneInput,
        run: &PreparedRun,
        on_step: OnStep<'_>,
    ) -> Result<Dmiso, DynamicSceneStylizeError> {
        let train = &scene.train;
        Ok(fit(
            &train.views,
            &train.images,
            train.extent,
            &self.fit_settings(),
            run.backend(),
            &scene.device,
            on_step,
        )?)
    }

    fn keep_fit(
        &self,
        scene: &DynamicSceneInput,
        fit: Dmiso,
        path: &Path,
    ) -> Result<Dmiso, DynamicSceneStylizeError> {
        model_file::save(&fit, path, Some(scene.background))?;
        Ok(fit)
    }

    /// The mean PSNR of the fitted scene over its training views.
    fn fit_psnr(
        &self,
        scene: &DynamicSceneInput,
        model: &mut Dmiso,
        run: &PreparedRun,
    ) -> Result<Option<f64>, DynamicSceneStylizeError> {
        let train = &scene.train;
        let renders = render_views(model, &train.views, scene.background.rgb(), run.backend())?;
        Ok(Some(mean_psnr(&renders, &train.images)))
    }

    /// Batches of consecutive training views; renders the sweep through time of the model
    /// before stylization first, for the preview.
    fn job(
        &self,
        scene: &mut DynamicSceneInput,
        mut model: Dmiso,
        run: &PreparedRun,
    ) -> Result<StylizeJob<Dmiso>, DynamicSceneStylizeError> {
        let train = &scene.train;
        let camera = &scene.test.as_ref().unwrap_or(train).views[0].camera;
        scene.sweep = sweep_views(camera, self.sweep_frames.max(1));
        scene.original = render_views(
            &mut model,
            &scene.sweep,
            scene.background.rgb(),
            run.backend(),
        )?;
        let masks = train
            .masks
            .iter()
            .map(|m| m.as_ref().map(|m| m.data.clone()))
            .collect::<Option<Vec<_>>>();
        Ok(StylizeJob {
            groups: stylize_groups(&self.learning_rates, train.extent)?,
            model,
            views: train.views.clone(),
            images: train.images.clone(),
            labels: scene.labels.clone(),
            masks,
            background: scene.background.rgb(),
            batches: Batches {
                size: self.batch_size,
                order: BatchOrder::Consecutive,
            },
            render_clamp: RenderClamp::Off,
        })
    }

    /// The model, the test views, the sweep, its previews and its video.
    fn write_outputs(
        &self,
        scene: DynamicSceneInput,
        outcome: StylizeOutcome<Dmiso>,
        run: &PreparedRun,
    ) -> Result<DynamicSceneSummary, DynamicSceneStylizeError> {
        let (out, backend) = (run.out(), run.backend());
        let background = scene.background.rgb();
        let mut model = outcome.model;
        model_file::save(&model, &out.join(MODEL_FILE), Some(scene.background))?;
        let test_renders = match &scene.test {
            Some(test) => {
                let renders = render_views(&mut model, &test.views, background, backend)?;
                write_frames(&out.join(FRAMES_DIR), &renders)?;
                renders
            }
            None => Vec::new(),
        };
        let sweep = render_views(&mut model, &scene.sweep, background, backend)?;
        let sweep_dir = out.join(SWEEP_DIR);
        write_frames(&sweep_dir, &sweep)?;
        if let (Some(first), Some(stylized)) = (scene.original.first(), sweep.first()) {
            write_pair(&out.join(PREVIEW_PNG), first, stylized)?;
        }
        write_preview_gif(
            &out.join(PREVIEW_GIF),
            &scene.original,
            &sweep,
            self.sweep_fps,
        )?;
        let wrote_mp4 = write_mp4_or_warn(&sweep_dir, self.sweep_fps, &out.join(SWEEP_MP4));
        self.write_viewer(out, &model, &scene, run)?;
        Ok(DynamicSceneSummary {
            model,
            test_renders,
            sweep,
            wrote_mp4,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn views_take_times_evenly_or_in_turn() {
        assert_eq!(view_times(5, None).unwrap(), [0.0, 0.25, 0.5, 0.75, 1.0]);
        assert_eq!(view_times(1, None).unwrap(), [0.0]);
        assert_eq!(view_times(5, Some(2)).unwrap(), [0.0, 1.0, 0.0, 1.0, 0.0]);
        assert_eq!(view_times(3, Some(1)).unwrap(), [0.0; 3]);
        assert_eq!(
            view_times(3, Some(3)).unwrap(),
            view_times(3, None).unwrap()
        );
        for bad in [0, 4] {
            let e = view_times(3, Some(bad)).unwrap_err().to_string();
            assert!(e.contains(&format!("times: {bad}")), "{e}");
        }
    }

    #[test]
    fn the_defaults_are_the_papers_4d_settings() {
        let config = DynamicSceneStylizeConfig::default();
        let s = &config.style;
        assert_eq!(
            (
                s.lambda_directional,
                s.lambda_patch,
                s.lambda_content,
                s.lambda_background
            ),
            (5.0, 90.0, 0.8, 0.0)
        );
        assert_eq!((s.steps, config.batch_size), (4999, 4));
        assert_eq!(config.train_splits, None);
        let groups = stylize_groups(&config.learning_rates, 2.0).unwrap();
        let at = |name: &str, step: u64| {
            groups
                .iter()
                .find(|g| g.name == name)
                .unwrap()
                .schedule
                .at(step)
        };
        assert!((at("pseudomesh", 0) - 2e-5).abs() < 1e-15);
        assert!((at("pseudomesh", 5000) - 2e-6).abs() < 1e-15);
        assert!((at("deform", 0) - 5e-5).abs() < 1e-15);
        assert!((at("deform", 5000) - 1e-6).abs() < 1e-15);
        let constants: Vec<f64> = [
            "alpha",
            "attached_scale",
            "attached_rotation",
            "attached_opacity",
            "attached_features_dc",
            "attached_features_rest",
            "time_net",
        ]
        .iter()
        .map(|n| at(n, 777))
        .collect();
        assert_eq!(constants, [1e-5, 0.001, 0.001, 0.05, 0.025, 0.025, 0.1]);
        assert!(groups.iter().all(|g| !g.frozen));
        // The authors' update rules: the network's rate set after each step, the time layer's
        // own Adam with torch's default epsilon; the rest as INRIA's groups.
        for g in &groups {
            let (rate_at, eps) = match g.name.as_str() {
                "deform" => (RateAt::PreviousIteration, None),
                "time_net" => (RateAt::Iteration, Some(1e-8)),
                _ => (RateAt::Iteration, None),
            };
            assert_eq!((g.rate_at, g.eps), (rate_at, eps), "{}", g.name);
        }
        assert!((groups[group::DEFORM].lr_for_update(1) - 5e-5).abs() < 1e-15);
        assert!((groups[group::PSEUDOMESH].lr_for_update(5000) - 2e-6).abs() < 1e-15);
    }
}
