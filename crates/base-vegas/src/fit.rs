//! Fitting a video (CLIPGaussian stage 1 for videos), as VeGaS's `train.py` trains: folded
//! Gaussians initialised on the plane ([`crate::init`]) are trained with
//! `(1 - 0.2) L1 + 0.2 D-SSIM` against every frame from the front camera and its mirror image
//! from the mirror camera, with VeGaS's learning rates. Where this differs from VeGaS: one view
//! per step (VeGaS averages a batch of three; the same number of renders takes three times the
//! steps), and no densification, pruning or opacity reset, so the Gaussian count is the one
//! asked for, which stylization keeps.

use std::ops::ControlFlow;

use gs_core::adam::{AdamHyper, GroupConfig, LrSchedule};
pub use gs_core::image_loss::mean_psnr;
use gs_core::image_loss::{check_fit_settings, PhotometricObjective};
use gs_core::mirror_pair::{extent, mirrored, plane_camera, plane_half_size, DEFAULT_DISTANCE};
use gs_core::model::View;
use gs_core::sampler::ViewSampler;
use gs_core::train::{StepReport, TrainConfig};
use gs_core::{GsError, Image};
use gs_wgpu::backend::{Backend, Trainer};
pub use gs_wgpu::FitError;

use crate::folded::{view_time, FoldedGaussians, GROUP_NAMES};
use crate::init::initial_model;

/// How to fit a video. The defaults are VeGaS's.
#[derive(Clone, Debug, PartialEq)]
pub struct VideoFitSettings {
    /// Number of folded Gaussians (fixed for the whole fit and for stylization).
    pub gaussians: usize,
    /// Optimizer steps (one view each).
    pub steps: u64,
    /// Seed of the initial Gaussians and of the view order.
    pub seed: u64,
    /// Weight of the D-SSIM term (VeGaS: 0.2).
    pub lambda_dssim: f32,
    /// Distance of both cameras from the plane, world units (VeGaS: 1).
    pub distance: f64,
    /// Background colour, linear RGB in `[0, 1]` (VeGaS: black).
    pub background: [f32; 3],
}

impl Default for VideoFitSettings {
    fn default() -> Self {
        Self {
            gaussians: 100_000,
            steps: 30_000,
            seed: 0,
            lambda_dssim: 0.2,
            distance: DEFAULT_DISTANCE,
            background: [0.0; 3],
        }
    }
}

/// VeGaS's Adam groups (in [`GROUP_NAMES`] order) for a scene of extent `extent`: xyz
/// `1.6e-4 extent -> 1.6e-6 extent` over 30,000 steps, scaling 0.005, rotation 0.001, m, sigma,
/// w and the time logits 0.001 each, opacity 0.025, f_dc 0.0025.
pub fn fit_groups(extent: f64) -> Vec<GroupConfig> {
    let rates = [
        LrSchedule::Exponential {
            start: 1.6e-4 * extent,
            end: 1.6e-6 * extent,
            steps: 30_000,
        },
        LrSchedule::Constant(0.005),
        LrSchedule::Constant(0.001),
        LrSchedule::Constant(0.001),
        LrSchedule::Constant(0.001),
        LrSchedule::Constant(0.001),
        LrSchedule::Constant(0.025),
        LrSchedule::Constant(0.0025),
        LrSchedule::Constant(0.001),
    ];
    GROUP_NAMES
        .iter()
        .zip(rates)
        .map(|(name, rate)| GroupConfig::new(*name, rate))
        .collect()
}

/// The training views of a `width x height` video of `frames` frames: for each frame in order,
/// the front camera then the mirror camera, at the frame's view time.
pub fn training_views(
    width: u32,
    height: u32,
    frames: usize,
    distance: f64,
) -> Result<Vec<View>, GsError> {
    let mut views = Vec::with_capacity(2 * frames);
    for f in 0..frames {
        for mirror in [false, true] {
            views.push(View {
                camera: plane_camera(width, height, distance, mirror)?,
                time: view_time(f, frames),
            });
        }
    }
    Ok(views)
}

/// The targets of [`training_views`]: each frame and its mirror image.
pub fn training_targets(frames: &[Image]) -> Vec<Image> {
    frames
        .iter()
        .flat_map(|f| [f.clone(), mirrored(f)])
        .collect()
}

/// Checks the settings and that there are at least two frames.
fn check(settings: &VideoFitSettings, frames: &[Image]) -> Result<(), FitError> {
    check_fit_settings(
        settings.gaussians,
        settings.steps,
        settings.lambda_dssim,
        settings.background,
    )
    .map_err(FitError::Settings)?;
    if frames.len() < 2 {
        return Err(FitError::Settings(format!(
            "frames: {} frames; a video needs at least 2",
            frames.len()
        )));
    }
    Ok(())
}

/// Fits the video `frames` (all of one size) with `settings` on `backend`, calling `on_step`
/// after every step (return `ControlFlow::Break` to stop early).
pub fn fit<F>(
    frames: &[Image],
    settings: &VideoFitSettings,
    backend: &Backend,
    on_step: F,
) -> Result<FoldedGaussians, FitError>
where
    F: FnMut(&StepReport) -> ControlFlow<()>,
{
    check(settings, frames)?;
    let (width, height) = (frames[0].width, frames[0].height);
    let views = training_views(width, height, frames.len(), settings.distance)?;
    let (half_w, half_h) = plane_half_size(width, height, settings.distance);
    let model = initial_model(
        settings.gaussians,
        frames.len(),
        half_w,
        half_h,
        settings.seed,
    );
    let mut objective = PhotometricObjective::new(training_targets(frames), settings.lambda_dssim);
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

/// The frames of a model as the front camera sees them, rendered one at a time (so a long
/// video is written frame by frame, never held whole).
pub struct FrameRenderer<'m> {
    renderer: gs_wgpu::backend::ModelRenderer<'m, FoldedGaussians>,
    camera: gs_core::Camera,
    frames: usize,
    background: [f32; 3],
}

impl<'m> FrameRenderer<'m> {
    /// Renders `model`'s frames at `width x height` pixels from `distance` over `background`
    /// on `backend`.
    pub fn new(
        model: &'m mut FoldedGaussians,
        width: u32,
        height: u32,
        distance: f64,
        background: [f32; 3],
        backend: &Backend,
    ) -> Result<Self, FitError> {
        let frames = model.frames();
        let camera = plane_camera(width, height, distance, false)?;
        Ok(Self {
            renderer: backend.model_renderer(model)?,
            camera,
            frames,
            background,
        })
    }

    /// The model's number of frames.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// Frame `frame` (from 0).
    pub fn render(&mut self, frame: usize) -> Result<Image, FitError> {
        let view = View {
            camera: self.camera.clone(),
            time: view_time(frame, self.frames),
        };
        Ok(self.renderer.render(&view, self.background)?)
    }
}

/// Every frame of `model` as the front camera sees it, at `width x height` pixels.
pub fn render_frames(
    model: &mut FoldedGaussians,
    width: u32,
    height: u32,
    distance: f64,
    background: [f32; 3],
    backend: &Backend,
) -> Result<Vec<Image>, FitError> {
    let mut renderer = FrameRenderer::new(model, width, height, distance, background, backend)?;
    (0..renderer.frames()).map(|f| renderer.render(f)).collect()
}
