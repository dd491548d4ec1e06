//! Fitting a picture (CLIPGaussian stage 1 for 2D): flat Gaussians initialised on the plane
//! ([`crate::init`]) are trained with `(1 - 0.2) L1 + 0.2 D-SSIM` against the picture from the
//! front camera and against its mirror image from the mirror camera, one camera per step in
//! shuffled order, as MiraGe's `train.py` does. Unlike MiraGe there is no densification,
//! pruning or opacity reset: the Gaussian count is the one asked for, and SH are trained at
//! their full degree from the first step.

use std::ops::ControlFlow;

use gs_core::adam::{AdamHyper, GroupConfig, LrSchedule};
use gs_core::backend::{Backend, DeviceError, Trainer};
use gs_core::image_loss::PhotometricObjective;
use gs_core::model::GaussianLrs;
use gs_core::train::{StepReport, TrainConfig, TrainError, ViewSampler};
use gs_core::{GsError, Image};

use crate::flat::FlatGaussians;
use crate::init::initial_gaussians;
use crate::mirror::{extent, mirage_camera, mirror_views, mirrored, plane_half_size};

/// How to fit a picture. The learning rates are MiraGe's (3DGS's) defaults.
#[derive(Clone, Debug, PartialEq)]
pub struct FitSettings {
    /// Number of Gaussians (fixed for the whole fit and for stylization).
    pub gaussians: usize,
    /// Optimizer steps (one camera each).
    pub steps: u64,
    /// SH degree of the colours (MiraGe: 3).
    pub sh_degree: usize,
    /// Seed of the initial Gaussians and of the camera order.
    pub seed: u64,
    /// Weight of the D-SSIM term (MiraGe: 0.2).
    pub lambda_dssim: f32,
    /// Distance of both cameras from the picture plane, world units (MiraGe: 1).
    pub distance: f64,
    /// Background colour the Gaussians are rendered over, linear RGB in `[0, 1]`.
    pub background: [f32; 3],
}

impl Default for FitSettings {
    fn default() -> Self {
        Self {
            gaussians: 100_000,
            steps: 3000,
            sh_degree: 3,
            seed: 0,
            lambda_dssim: 0.2,
            distance: crate::mirror::DEFAULT_DISTANCE,
            background: [0.0; 3],
        }
    }
}

/// Why a fit could not run.
#[derive(Debug, thiserror::Error)]
pub enum FitError {
    /// A setting out of its range.
    #[error("{0}")]
    Settings(String),
    /// A camera that could not be built.
    #[error("{0}")]
    Camera(#[from] GsError),
    /// Training stopped with an error.
    #[error("fitting: {0}")]
    Train(#[from] TrainError<GsError>),
    /// The device could not hold the model.
    #[error("fitting: {0}")]
    Device(#[from] DeviceError),
}

/// MiraGe's Adam groups for a scene of extent `extent`: means `1.6e-4 extent -> 1.6e-6 extent`
/// over 30,000 steps, scales 0.005, rotations 0.001, opacities 0.05, SH DC 0.0025 and the rest
/// a twentieth of that.
pub fn fit_groups(extent: f64) -> Vec<GroupConfig> {
    GaussianLrs {
        means: LrSchedule::Exponential {
            start: 1.6e-4 * extent,
            end: 1.6e-6 * extent,
            steps: 30_000,
        },
        scales: 0.005,
        rotations: 0.001,
        opacities: 0.05,
        feature: 0.0025,
    }
    .groups()
}

/// Checks the settings against the picture.
fn check(settings: &FitSettings) -> Result<(), FitError> {
    let bad = |field: &str, why: String| Err(FitError::Settings(format!("{field}: {why}")));
    if settings.gaussians == 0 {
        return bad("gaussians", "must be at least 1".into());
    }
    if settings.steps == 0 {
        return bad("steps", "must be at least 1".into());
    }
    if settings.sh_degree > gs_core::gaussians::MAX_SH_DEGREE {
        return bad(
            "sh_degree",
            format!(
                "{} is above the supported {}",
                settings.sh_degree,
                gs_core::gaussians::MAX_SH_DEGREE
            ),
        );
    }
    if !(settings.lambda_dssim.is_finite() && (0.0..=1.0).contains(&settings.lambda_dssim)) {
        return bad(
            "lambda_dssim",
            format!("{} must be in [0, 1]", settings.lambda_dssim),
        );
    }
    if settings.background.iter().any(|c| !(0.0..=1.0).contains(c)) {
        return bad(
            "background",
            format!("{:?} must have channels in [0, 1]", settings.background),
        );
    }
    Ok(())
}

/// Fits `picture` with `settings` on `backend`, calling `on_step` after every step (return
/// `ControlFlow::Break` to stop early). The picture is fitted at its own resolution.
pub fn fit<F>(
    picture: &Image,
    settings: &FitSettings,
    backend: &Backend,
    on_step: F,
) -> Result<FlatGaussians, FitError>
where
    F: FnMut(&StepReport) -> ControlFlow<()>,
{
    check(settings)?;
    let views = mirror_views(picture.width, picture.height, settings.distance)?;
    let (half_w, half_h) = plane_half_size(picture.width, picture.height, settings.distance);
    let model = initial_gaussians(
        settings.gaussians,
        settings.sh_degree,
        half_w,
        half_h,
        settings.seed,
    );
    let mut objective = PhotometricObjective {
        targets: vec![picture.clone(), mirrored(picture)],
        lambda: settings.lambda_dssim,
    };
    let mut trainer = Trainer::new(
        backend,
        model,
        fit_groups(extent(settings.distance)),
        AdamHyper::default(),
    )?;
    let mut sampler = ViewSampler::new(views.len(), settings.seed);
    let config = TrainConfig {
        steps: settings.steps,
        background: settings.background,
    };
    trainer.train(&views, &mut objective, &mut sampler, &config, on_step)?;
    Ok(trainer.into_model())
}

/// The picture the model holds, seen by the front camera (`mirrored == false`) or the mirror
/// camera, at `width x height` pixels, rendered on `backend`.
pub fn render_picture(
    model: &FlatGaussians,
    width: u32,
    height: u32,
    distance: f64,
    mirrored: bool,
    background: [f32; 3],
    backend: &Backend,
) -> Result<Image, FitError> {
    let camera = mirage_camera(width, height, distance, mirrored)?;
    let shown = model.renderable();
    Ok(backend.renderer(&shown)?.render(&camera, background)?)
}
