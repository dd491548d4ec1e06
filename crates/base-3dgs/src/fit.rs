//! The first stage in 3D: a 3DGS scene fitted to a dataset's pictures as INRIA's `train.py`
//! does it (commit 54c035f; `docs/fidelity.md` lists what differs). One view a step, drawn
//! without replacement each epoch; the loss `(1 - 0.2) L1 + 0.2 (1 - SSIM)` of the render
//! clamped to `[0, 1]`; Adam (epsilon 1e-15) with INRIA's rates and the positions' exponential
//! decay; one more SH degree every 1,000 steps; densification by the view-space gradient
//! (`gs_core::densify`) and the opacity reset.
//!
//! A densification changes the number of Gaussians, so the fit runs in segments between such
//! events, each a trainer whose optimizer moments follow the rows ([`rearrange_state`]).

use std::ops::ControlFlow;
use std::path::Path;

use gs_core::adam::{rearrange_state, AdamHyper, GroupConfig, LrSchedule, RowChange};
use gs_core::dataset::nerf_synthetic::{self, Split, TrainSplits};
use gs_core::dataset::{colmap, Dataset, DatasetError, Layout, LoadOptions, PointCloud};
use gs_core::densify::{densify, raise_sh_degree, reset_opacity, DensifySettings, ScreenStats};
use gs_core::fs::write_atomic;
use gs_core::gaussians::{GaussianSet, MAX_SH_DEGREE, PARAM_NAMES};
use gs_core::image::Image;
use gs_core::image_loss::{PhotometricObjective, PsnrLog};
use gs_core::model::{BaseModel, View};
use gs_core::plane_neighbours::{mean_nearest_dist2, MIN_DIST2};
use gs_core::ply::{read_ply, write_ply, PlyFormat, PlyGaussians};
use gs_core::render_clamp::{ClampedObjective, RenderClamp};
use gs_core::sampler::{BatchOrder, ViewSampler};
use gs_core::sh::C0 as SH_C0;
use gs_core::train::{StepReport, TrainConfig};
use gs_core::GsError;
use gs_stylize::plot::{Chart, Series, PALETTE};
use gs_wgpu::backend::{Backend, DeviceError, Trainer};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// INRIA's `OptimizationParams` and `ModelParams` defaults, each a setting.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneFitSettings {
    /// Optimizer steps (`iterations`, 30,000).
    pub steps: u64,
    /// The highest SH degree (`sh_degree`, 3); the fit starts at 0 and adds one every
    /// `sh_every` steps.
    pub sh_degree: usize,
    /// Steps between SH degree raises (1,000, fixed in `train.py`).
    pub sh_every: u64,
    /// Weight of the D-SSIM term (`lambda_dssim`, 0.2).
    pub lambda_dssim: f32,
    /// The positions' rate at the start and end of its decay, times the scene extent
    /// (`position_lr_init` 1.6e-4, `position_lr_final` 1.6e-6).
    pub position_lr: (f64, f64),
    /// Steps of the positions' decay (`position_lr_max_steps`, 30,000).
    pub position_lr_steps: u64,
    /// The SH DC rate (`feature_lr`, 0.0025; the higher degrees take a twentieth).
    pub feature_lr: f64,
    /// `opacity_lr` (0.025).
    pub opacity_lr: f64,
    /// `scaling_lr` (0.005).
    pub scaling_lr: f64,
    /// `rotation_lr` (0.001).
    pub rotation_lr: f64,
    /// Random starting points when the dataset has none (NeRF-synthetic: 100,000 in the cube
    /// `[-1.3, 1.3]^3`).
    pub random_points: usize,
    /// The densification (its `max_len` the cap a user can set); `None` fits the starting
    /// Gaussians only.
    pub densify: Option<DensifySettings>,
    /// The colour pictures are composited over and renders drawn on.
    pub background: [f32; 3],
    /// Seed of the random points, the view order and the split samples.
    pub seed: u64,
}

impl Default for SceneFitSettings {
    fn default() -> Self {
        Self {
            steps: 30_000,
            sh_degree: 3,
            sh_every: 1000,
            lambda_dssim: 0.2,
            position_lr: (1.6e-4, 1.6e-6),
            position_lr_steps: 30_000,
            feature_lr: 0.0025,
            opacity_lr: 0.025,
            scaling_lr: 0.005,
            rotation_lr: 0.001,
            random_points: 100_000,
            densify: Some(DensifySettings::default()),
            background: [0.0; 3],
            seed: 0,
        }
    }
}

impl SceneFitSettings {
    /// A setting that cannot run, named as its flag.
    pub fn check(&self) -> Result<(), String> {
        if self.steps == 0 {
            return Err("--steps: must be at least 1".into());
        }
        if self.sh_degree > MAX_SH_DEGREE {
            return Err(format!(
                "--sh-degree {}: must be at most {MAX_SH_DEGREE}",
                self.sh_degree
            ));
        }
        if self.sh_every == 0 {
            return Err("sh_every: must be at least 1".into());
        }
        if !(0.0..=1.0).contains(&self.lambda_dssim) {
            return Err(format!(
                "--lambda-dssim {}: must be in [0, 1]",
                self.lambda_dssim
            ));
        }
        if self.random_points == 0 {
            return Err("--random-points: must be at least 1".into());
        }
        if let Some(d) = &self.densify {
            d.check()?;
        }
        if self.background.iter().any(|c| !(0.0..=1.0).contains(c)) {
            return Err(format!(
                "--background {:?}: channels must be in [0, 1]",
                self.background
            ));
        }
        Ok(())
    }

    /// The optimizer's groups for a scene of camera extent `extent` (INRIA's
    /// `training_setup`; the positions' rates scale with the extent).
    pub fn groups(&self, extent: f64) -> Vec<GroupConfig> {
        let schedule = |name: &str| match name {
            "means" => LrSchedule::Exponential {
                start: self.position_lr.0 * extent,
                end: self.position_lr.1 * extent,
                steps: self.position_lr_steps,
            },
            "scales" => LrSchedule::Constant(self.scaling_lr),
            "rotations" => LrSchedule::Constant(self.rotation_lr),
            "opacities" => LrSchedule::Constant(self.opacity_lr),
            "sh_dc" => LrSchedule::Constant(self.feature_lr),
            _ => LrSchedule::Constant(self.feature_lr / 20.0),
        };
        PARAM_NAMES
            .iter()
            .map(|&name| GroupConfig::new(name, schedule(name)))
            .collect()
    }

    /// Whether the SH degree is raised after step `step`: INRIA raises it before the render of
    /// every 1,000th iteration, so after steps 999, 1,999, 2,999, until the highest degree.
    fn raises_sh_after(&self, step: u64) -> bool {
        let next = step + 1;
        next.is_multiple_of(self.sh_every) && next / self.sh_every <= self.sh_degree as u64
    }

    /// Whether renders are drawn on white (INRIA's `-w`, which also resets the opacities at
    /// the densification's start).
    fn white_background(&self) -> bool {
        self.background == [1.0; 3]
    }
}

/// Why a fit failed.
#[derive(Debug, thiserror::Error)]
pub enum SceneFitError {
    /// A setting or an input that cannot be fitted.
    #[error("{0}")]
    Settings(String),
    /// The device failed.
    #[error(transparent)]
    Device(#[from] DeviceError),
    /// A step failed.
    #[error(transparent)]
    Train(#[from] gs_core::train::TrainError<GsError>),
    /// The optimizer state could not follow the Gaussians.
    #[error(transparent)]
    State(#[from] GsError),
}

/// The starting Gaussians (INRIA's `create_from_pcd`), SH degree 0: one at each of `points`
/// (COLMAP's, or `settings.random_points` drawn in the cube `[-1.3, 1.3]^3` of grey 127/255
/// when `None`, as INRIA's NeRF-synthetic reader writes and reads them back through a u8 PLY),
/// its colour as the DC term, its three scales the square root of the mean squared distance
/// to its three nearest neighbours (at least `1e-7`), no rotation, opacity 0.1.
pub fn initial_gaussians(points: Option<&PointCloud>, settings: &SceneFitSettings) -> GaussianSet {
    let (positions, colors) = match points {
        Some(cloud) => (cloud.positions.clone(), cloud.colors.clone()),
        None => {
            let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
            let positions: Vec<[f64; 3]> = (0..settings.random_points)
                .map(|_| [0; 3].map(|_| rng.random::<f64>() * 2.6 - 1.3))
                .collect();
            let colors = vec![[127u8; 3]; positions.len()];
            (positions, colors)
        }
    };
    let n = positions.len();
    let dist2 = mean_nearest_dist2::<3>(&positions, 3);
    let mut set = GaussianSet::zeros(n, 0);
    let opacity = (0.1f64 / 0.9).ln() as f32;
    for i in 0..n {
        let log_scale = (0.5 * dist2[i].max(MIN_DIST2).ln()) as f32;
        for a in 0..3 {
            set.means[3 * i + a] = positions[i][a] as f32;
            set.log_scales[3 * i + a] = if log_scale.is_finite() {
                log_scale
            } else {
                0.0
            };
            set.sh_dc[3 * i + a] = ((f64::from(colors[i][a]) / 255.0 - 0.5) / SH_C0) as f32;
        }
        set.opacity_logits[i] = opacity;
    }
    set
}

/// Where a fit stands between two steps: all it needs to go on exactly as if it had not
/// stopped (the view order and the split samples follow from the settings' seed and the step).
#[derive(Clone, Debug, PartialEq)]
pub struct SceneFit {
    /// The Gaussians, at the SH degree reached (every degree of the settings once finished,
    /// as INRIA's file holds them).
    pub gaussians: GaussianSet,
    /// Each step's training view PSNR (its render before the update), in step order.
    pub psnr: Vec<f64>,
    /// Gaussians after each densification: `(step, count)`.
    pub counts: Vec<(u64, usize)>,
    /// Steps taken (fewer than asked when stopped).
    pub steps: u64,
    /// The optimizer's state ([`gs_core::adam::Adam::save_state`]'s format); `None` before
    /// the first step.
    pub optimizer: Option<Vec<u8>>,
    /// The densification statistics gathered since the last densification, while gathering.
    pub stats: Option<ScreenStats>,
    /// Wall time of the runs of this fit that stopped (Ctrl-C) before, seconds: [`fit`] leaves
    /// it as it is, a run that stops adds its own before its checkpoint, and `fit.json`
    /// reports the sum.
    pub seconds: f64,
}

impl SceneFit {
    /// A fit that has not started, from `start` (see [`initial_gaussians`]).
    pub fn new(start: GaussianSet) -> Self {
        Self {
            gaussians: start,
            psnr: Vec::new(),
            counts: Vec::new(),
            steps: 0,
            optimizer: None,
            stats: None,
            seconds: 0.0,
        }
    }
}

/// Fits `views` to `images` (one per view) from `start` ([`SceneFit::new`], or a stopped fit
/// to go on with) in a scene of camera extent `extent`, on `backend`. `on_step` is called after
/// every step (return `ControlFlow::Break` to stop: the fit so far is returned, which goes on
/// from there as if it had not stopped).
pub fn fit<F>(
    views: &[View],
    images: &[Image],
    start: SceneFit,
    extent: f64,
    settings: &SceneFitSettings,
    backend: &Backend,
    mut on_step: F,
) -> Result<SceneFit, SceneFitError>
where
    F: FnMut(&StepReport) -> ControlFlow<()>,
{
    settings.check().map_err(SceneFitError::Settings)?;
    if views.is_empty() || views.len() != images.len() {
        return Err(SceneFitError::Settings(format!(
            "{} views and {} pictures: one picture per view, at least one",
            views.len(),
            images.len()
        )));
    }
    if start.gaussians.is_empty() {
        return Err(SceneFitError::Settings(
            "the scene starts with no Gaussians (its point cloud is empty)".into(),
        ));
    }
    if !(extent.is_finite() && extent > 0.0) {
        return Err(SceneFitError::Settings(format!(
            "the scene extent is {extent}: the cameras must not all stand at one point"
        )));
    }
    let groups = settings.groups(extent);
    let SceneFit {
        gaussians: mut model,
        psnr,
        mut counts,
        steps: mut done,
        optimizer: mut state,
        mut stats,
        seconds,
    } = start;
    if psnr.len() as u64 != done {
        return Err(SceneFitError::Settings(format!(
            "a fit stopped after step {done} holds {} PSNR values",
            psnr.len()
        )));
    }
    let mut objective = PsnrLog {
        inner: PhotometricObjective::new(images.to_vec(), settings.lambda_dssim),
        log: psnr.into_iter().map(|p| (0, p)).collect(),
    };
    // One view a step: the order goes on from the steps taken.
    let mut sampler = ViewSampler::batches(views.len(), 1, BatchOrder::Shuffled, settings.seed);
    for _ in 0..done {
        sampler.next_batch();
    }
    let white = settings.white_background();
    let densifying = settings.densify.as_ref();
    let mut stopped = false;
    while done < settings.steps {
        let end = next_event(settings, done);
        // The segment: a trainer from `done` to `end`.
        let gathering = densifying.is_some_and(|d| d.gathers_at(done + 1));
        let n = model.len();
        let mut trainer = Trainer::new(backend, model, groups.clone(), AdamHyper::default())?;
        if let Some(bytes) = &state {
            trainer.restore_optimizer(bytes)?;
        }
        if gathering {
            trainer.gather_screen_stats(stats.take().unwrap_or_else(|| ScreenStats::new(n)))?;
        }
        let config = TrainConfig {
            steps: end,
            background: settings.background,
        };
        let mut clamped = ClampedObjective::new(&mut objective, RenderClamp::Unit);
        trainer.train(views, &mut clamped, &mut sampler, &config, |report| {
            let flow = on_step(report);
            stopped |= flow.is_break();
            flow
        })?;
        done = trainer.step_count();
        stats = trainer.take_screen_stats();
        let mut bytes = trainer.save_optimizer();
        model = trainer.into_model();
        if done >= settings.steps {
            state = Some(bytes);
            break;
        }
        // The events after step `done`, in INRIA's order: densify, reset, then (at the next
        // iteration's start) the SH degree.
        if let Some(d) = densifying {
            if d.densifies_at(done) {
                let current = stats.take().ok_or_else(|| {
                    SceneFitError::Settings("no statistics were gathered to densify".into())
                })?;
                // The split samples of each densification from the seed and its step, so that
                // a resumed fit draws the same ones.
                let seed = settings.seed ^ done.wrapping_mul(SPLIT_SEED);
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                let (dense, rows) = densify(
                    &model,
                    &current,
                    extent as f32,
                    d,
                    d.prunes_large_at(done),
                    &mut rng,
                )
                .map_err(SceneFitError::Settings)?;
                bytes = rearrange(&bytes, &groups, &model, &rows)?;
                model = dense;
                counts.push((done, model.len()));
            }
            if d.resets_opacity_at(done, white) {
                let rows = reset_opacity(&mut model);
                bytes = rearrange(&bytes, &groups, &model, &rows)?;
            }
        }
        if settings.raises_sh_after(done) && model.sh_degree() < settings.sh_degree {
            if let Some((wider, rows)) = raise_sh_degree(&model) {
                bytes = rearrange(&bytes, &groups, &model, &rows)?;
                model = wider;
            }
        }
        state = Some(bytes);
        // Stopped: after the events of the step reached, as a fit that goes on would be.
        if stopped {
            break;
        }
    }
    // A finished fit's file holds every degree, as INRIA's (those not reached are zero).
    while done >= settings.steps && model.sh_degree() < settings.sh_degree {
        match raise_sh_degree(&model) {
            Some((wider, _)) => model = wider,
            None => break,
        }
    }
    Ok(SceneFit {
        gaussians: model,
        psnr: objective.log.into_iter().map(|(_, p)| p).collect(),
        counts,
        steps: done,
        optimizer: state,
        stats,
        seconds,
    })
}

/// The renders of `gaussians` at `views` over `background` on `backend` (a fit's training and
/// held-out views, for their PSNR and frames).
pub fn render_views(
    gaussians: &GaussianSet,
    views: &[View],
    background: [f32; 3],
    backend: &Backend,
) -> Result<Vec<Image>, DeviceError> {
    let renderer = backend.renderer(gaussians)?;
    views
        .iter()
        .map(|v| renderer.render(&v.camera, background))
        .collect()
}

/// Mixed into the seed of each densification's split samples, times its step.
const SPLIT_SEED: u64 = 0x9E37_79B9_7F4A_7C15;

/// `bytes` (the optimizer of `groups` over `model`) with its moments following `rows`.
fn rearrange(
    bytes: &[u8],
    groups: &[GroupConfig],
    model: &GaussianSet,
    rows: &[RowChange],
) -> Result<Vec<u8>, GsError> {
    let lens: Vec<Option<usize>> = model.group_lens().into_iter().map(Some).collect();
    rearrange_state(bytes, groups, &lens, rows)
}

/// The next step after `done` at which the Gaussians change (a densification, an opacity
/// reset, an SH degree raise), or the last step.
fn next_event(settings: &SceneFitSettings, done: u64) -> u64 {
    ((done + 1)..settings.steps)
        .find(|&s| {
            let densify = settings.densify.as_ref().is_some_and(|d| {
                d.densifies_at(s) || d.resets_opacity_at(s, settings.white_background())
            });
            densify || settings.raises_sh_after(s)
        })
        .unwrap_or(settings.steps)
}

/// What a fit trains on and is tested on.
#[derive(Clone, Debug)]
pub struct FitData {
    /// The training views and their pictures; `extent` is theirs (INRIA's `cameras_extent`).
    pub train: Dataset,
    /// The held-out views and pictures (`--eval`), when any.
    pub test: Option<(Vec<View>, Vec<Image>)>,
}

/// COLMAP's held-out views under `--eval`: every 8th of the pictures sorted by name (INRIA's
/// `llffhold`).
pub const LLFF_HOLD: usize = 8;

/// The dataset in `data` with `options` (NeRF-synthetic or COLMAP), as INRIA's loaders read
/// it: without `eval` every view trains (NeRF-synthetic's test split too); with it
/// NeRF-synthetic's test split and every [`LLFF_HOLD`]th COLMAP picture by name are held out.
pub fn load_fit_data(
    data: &Path,
    options: &LoadOptions,
    eval: bool,
) -> Result<FitData, DatasetError> {
    match Layout::detect(data) {
        Some(Layout::NerfSynthetic) => {
            let splits = if eval {
                TrainSplits::Train
            } else {
                TrainSplits::TrainAndTest
            };
            let train = nerf_synthetic::load_training(data, splits, options)?;
            let test = if eval {
                let test = nerf_synthetic::load(data, Split::Test, options)?;
                Some((test.views, test.images))
            } else {
                None
            };
            Ok(FitData { train, test })
        }
        Some(Layout::Colmap) => {
            let all = colmap::load(data, options)?;
            if !eval {
                return Ok(FitData {
                    train: all,
                    test: None,
                });
            }
            let mut by_name: Vec<usize> = (0..all.views.len()).collect();
            by_name.sort_by(|&a, &b| all.image_paths[a].cmp(&all.image_paths[b]));
            let mut held = vec![false; all.views.len()];
            for (k, &i) in by_name.iter().enumerate() {
                held[i] = k % LLFF_HOLD == 0;
            }
            let (train, test) = all.partition(&held);
            Ok(FitData {
                train,
                test: Some((test.views, test.images)),
            })
        }
        None => Err(DatasetError::Format {
            path: data.to_path_buf(),
            message: Layout::LOOKED_FOR.into(),
        }),
    }
}

/// The chart of a fit's PSNR against the step: each step's training view, and the mean of
/// every 100 steps.
pub fn psnr_chart(psnr: &[f64]) -> Chart {
    let each = psnr
        .iter()
        .enumerate()
        .map(|(i, &p)| ((i + 1) as f64, p))
        .collect();
    let means = psnr
        .chunks(100)
        .enumerate()
        .map(|(k, c)| {
            let mid = (k * 100) as f64 + (c.len() as f64 + 1.0) / 2.0;
            (mid, c.iter().sum::<f64>() / c.len() as f64)
        })
        .collect();
    Chart {
        title: "Fit PSNR (each step's training view, before its update)".into(),
        x_label: "step".into(),
        y_label: "PSNR (dB)".into(),
        series: vec![
            Series {
                name: "each step".into(),
                color: PALETTE[0],
                points: each,
                dashed: false,
            },
            Series {
                name: "mean of 100 steps".into(),
                color: PALETTE[1],
                points: means,
                dashed: false,
            },
        ],
    }
}

/// The files of a stopped fit in its checkpoint folder: the Gaussians (INRIA PLY, exact f32),
/// the optimizer's state, the statistics (Gaussians as u64, then the sums as f32, then the
/// counts as u32, little-endian) and, written last so that it marks a whole checkpoint, the
/// record of the steps.
const CHECKPOINT_PLY: &str = "gaussians.ply";
const CHECKPOINT_OPTIMIZER: &str = "optimizer.bin";
const CHECKPOINT_STATS: &str = "stats.bin";
const CHECKPOINT_STATE: &str = "fit_state.json";

/// The record of a stopped fit's steps (`fit_state.json`).
#[derive(Serialize, Deserialize)]
struct CheckpointRecord {
    steps: u64,
    psnr: Vec<f64>,
    counts: Vec<(u64, usize)>,
    optimizer: bool,
    stats: bool,
    /// Wall time so far, seconds (0 in a checkpoint written before it was recorded).
    #[serde(default)]
    seconds: f64,
}

/// Writes `fit` into the folder `dir` (created), each file through a temporary name; the
/// record last.
pub fn save_checkpoint(dir: &Path, fit: &SceneFit) -> Result<(), SceneFitError> {
    let io = |path: &Path, e: std::io::Error| {
        SceneFitError::Settings(format!("checkpoint {}: {e}", path.display()))
    };
    std::fs::create_dir_all(dir).map_err(|e| io(dir, e))?;
    let ply = dir.join(CHECKPOINT_PLY);
    write_ply(
        &ply,
        &PlyGaussians::new(fit.gaussians.clone()),
        PlyFormat::BinaryLittleEndian,
    )
    .map_err(|e| SceneFitError::Settings(e.to_string()))?;
    if let Some(bytes) = &fit.optimizer {
        let path = dir.join(CHECKPOINT_OPTIMIZER);
        write_atomic(&path, bytes).map_err(|e| io(&path, e))?;
    }
    if let Some(stats) = &fit.stats {
        let mut bytes = (stats.len() as u64).to_le_bytes().to_vec();
        bytes.extend(stats.grad_sum.iter().flat_map(|v| v.to_le_bytes()));
        bytes.extend(stats.count.iter().flat_map(|v| v.to_le_bytes()));
        let path = dir.join(CHECKPOINT_STATS);
        write_atomic(&path, &bytes).map_err(|e| io(&path, e))?;
    }
    let record = CheckpointRecord {
        steps: fit.steps,
        psnr: fit.psnr.clone(),
        counts: fit.counts.clone(),
        optimizer: fit.optimizer.is_some(),
        stats: fit.stats.is_some(),
        seconds: fit.seconds,
    };
    let path = dir.join(CHECKPOINT_STATE);
    let text = serde_json::to_string(&record).map_err(|e| io(&path, e.into()))?;
    write_atomic(&path, text.as_bytes()).map_err(|e| io(&path, e))
}

/// Whether `dir` holds a whole checkpoint of a stopped fit.
pub fn has_checkpoint(dir: &Path) -> bool {
    dir.join(CHECKPOINT_STATE).is_file()
}

/// The stopped fit in the folder `dir` ([`save_checkpoint`]); an error names the file.
pub fn load_checkpoint(dir: &Path) -> Result<SceneFit, SceneFitError> {
    let bad = |path: &Path, why: String| {
        SceneFitError::Settings(format!("checkpoint {}: {why}", path.display()))
    };
    let read = |name: &str| {
        let path = dir.join(name);
        std::fs::read(&path).map_err(|e| bad(&path, e.to_string()))
    };
    let state_path = dir.join(CHECKPOINT_STATE);
    let record: CheckpointRecord = serde_json::from_slice(&read(CHECKPOINT_STATE)?)
        .map_err(|e| bad(&state_path, e.to_string()))?;
    let gaussians = read_ply(&dir.join(CHECKPOINT_PLY))
        .map_err(|e| SceneFitError::Settings(e.to_string()))?
        .gaussians;
    let optimizer = if record.optimizer {
        Some(read(CHECKPOINT_OPTIMIZER)?)
    } else {
        None
    };
    let stats = if record.stats {
        let path = dir.join(CHECKPOINT_STATS);
        let bytes = read(CHECKPOINT_STATS)?;
        let n = bytes
            .get(..8)
            .map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")) as usize)
            .filter(|&n| n == gaussians.len() && bytes.len() == 8 + 8 * n)
            .ok_or_else(|| {
                bad(
                    &path,
                    format!(
                        "does not hold the statistics of {} Gaussians",
                        gaussians.len()
                    ),
                )
            })?;
        let word = |i: usize| -> [u8; 4] { bytes[8 + 4 * i..12 + 4 * i].try_into().expect("4") };
        Some(ScreenStats {
            grad_sum: (0..n).map(|i| f32::from_le_bytes(word(i))).collect(),
            count: (0..n).map(|i| u32::from_le_bytes(word(n + i))).collect(),
        })
    } else {
        None
    };
    if record.psnr.len() as u64 != record.steps {
        return Err(bad(
            &state_path,
            format!(
                "{} steps but {} PSNR values",
                record.steps,
                record.psnr.len()
            ),
        ));
    }
    Ok(SceneFit {
        gaussians,
        psnr: record.psnr,
        counts: record.counts,
        steps: record.steps,
        optimizer,
        stats,
        seconds: record.seconds,
    })
}
