//! Fitting a picture (CLIPGaussian stage 1 for 2D): flat Gaussians initialised on the plane
//! ([`crate::init`]) are trained with `(1 - 0.2) L1 + 0.2 D-SSIM` against the picture from the
//! front camera and against its mirror image from the mirror camera, one camera per step in
//! shuffled order, as MiraGe's `train.py` does. Unlike MiraGe there is no densification,
//! pruning or opacity reset: the Gaussian count is the one asked for, and SH are trained at
//! their full degree from the first step.
//!
//! Every step also logs the PSNR of the render it trained on against that camera's target
//! ([`fit_logged`]; one pass over the pixels, next to the SSIM the step computes anyway), and
//! [`write_psnr_plot`] draws that log (as [`FIT_PSNR_PNG`] in an output folder).

use std::ops::ControlFlow;
use std::path::Path;

use gs_core::adam::{AdamHyper, GroupConfig, LrSchedule};
use gs_core::image_loss::{check_fit_settings, PhotometricObjective, PsnrLog};
use gs_core::model::{GaussianLrs, View};
use gs_core::sampler::ViewSampler;
use gs_core::train::{StepReport, TrainConfig};
use gs_core::Image;
use gs_stylize::plot::{Chart, Series, PALETTE};
use gs_stylize::StylizeError;
use gs_wgpu::backend::{Backend, Trainer};
pub use gs_wgpu::FitError;

use crate::flat::FlatGaussians;
use crate::init::initial_gaussians;
use crate::mirror::{extent, mirror_views, mirrored, plane_camera, plane_half_size};

/// How to fit a picture. The learning rates are MiraGe's (3DGS's) defaults.
#[derive(Clone, Debug, PartialEq)]
pub struct PictureFitSettings {
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

impl Default for PictureFitSettings {
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

/// Checks the settings.
fn check(settings: &PictureFitSettings) -> Result<(), FitError> {
    check_fit_settings(
        settings.gaussians,
        settings.steps,
        settings.lambda_dssim,
        settings.background,
    )
    .map_err(FitError::Settings)?;
    if settings.sh_degree > gs_core::gaussians::MAX_SH_DEGREE {
        return Err(FitError::Settings(format!(
            "sh_degree: {} is above the supported {}",
            settings.sh_degree,
            gs_core::gaussians::MAX_SH_DEGREE
        )));
    }
    Ok(())
}

pub use gs_stylize::outputs::FIT_PSNR_PNG;

/// The PSNR of one fit step: the render the step trained on against its camera's target,
/// before the step's update.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PsnrPoint {
    /// The step, 1-based.
    pub step: u64,
    /// Whether the step used the mirror camera (else the front one).
    pub mirrored: bool,
    /// The PSNR, dB (as [`gs_core::image_loss::psnr`]).
    pub psnr_db: f64,
}

/// A fitted model and the PSNR of every step it took.
#[derive(Clone, Debug)]
pub struct Fitted {
    /// The model.
    pub model: FlatGaussians,
    /// One point per step, in step order.
    pub psnr: Vec<PsnrPoint>,
}

/// Fits `picture` with `settings` on `backend`, calling `on_step` after every step (return
/// `ControlFlow::Break` to stop early). The picture is fitted at its own resolution.
pub fn fit<F>(
    picture: &Image,
    settings: &PictureFitSettings,
    backend: &Backend,
    on_step: F,
) -> Result<FlatGaussians, FitError>
where
    F: FnMut(&StepReport) -> ControlFlow<()>,
{
    Ok(fit_logged(picture, settings, backend, on_step)?.model)
}

/// [`fit`], also returning the PSNR of every step.
pub fn fit_logged<F>(
    picture: &Image,
    settings: &PictureFitSettings,
    backend: &Backend,
    on_step: F,
) -> Result<Fitted, FitError>
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
    let mut objective = PsnrLog {
        inner: PhotometricObjective::new(
            vec![picture.clone(), mirrored(picture)],
            settings.lambda_dssim,
        ),
        log: Vec::new(),
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
    // One view a step: entry k is step k + 1's; view 1 is the mirror camera.
    let psnr = (1..)
        .zip(objective.log)
        .map(|(step, (view, psnr_db))| PsnrPoint {
            step,
            mirrored: view == 1,
            psnr_db,
        })
        .collect();
    Ok(Fitted {
        model: trainer.into_model(),
        psnr,
    })
}

/// The chart of a fit's PSNR against the step, one curve per camera.
pub fn psnr_chart(log: &[PsnrPoint]) -> Chart {
    let camera = |mirrored: bool, name: &str, color: [u8; 3]| Series {
        name: name.into(),
        color,
        points: log
            .iter()
            .filter(|p| p.mirrored == mirrored)
            .map(|p| (p.step as f64, p.psnr_db))
            .collect(),
        dashed: false,
    };
    Chart {
        title: "Fit PSNR (each step's render before its update)".into(),
        x_label: "step".into(),
        y_label: "PSNR (dB)".into(),
        series: vec![
            camera(false, "front camera", PALETTE[0]),
            camera(true, "mirror camera", PALETTE[1]),
        ],
    }
}

/// Writes the chart of a fit's PSNR to `path` as a PNG.
pub fn write_psnr_plot(path: &Path, log: &[PsnrPoint]) -> Result<(), StylizeError> {
    psnr_chart(log).write_png(path)
}

/// The picture the model holds, seen by the front camera (`mirrored == false`) or the mirror
/// camera, at `width x height` pixels, rendered on `backend`.
pub fn render_picture(
    model: &mut FlatGaussians,
    width: u32,
    height: u32,
    distance: f64,
    mirrored: bool,
    background: [f32; 3],
    backend: &Backend,
) -> Result<Image, FitError> {
    let view = View::still(plane_camera(width, height, distance, mirrored)?);
    Ok(backend.model_renderer(model)?.render(&view, background)?)
}

#[cfg(test)]
mod tests {
    use gs_stylize::plot::{LEGEND_WIDTH, PLOT_WIDTH};

    use super::*;

    /// A 24x16 picture: a colour ramp with a dark square.
    fn picture() -> Image {
        let (w, h) = (24u32, 16u32);
        let data = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .flat_map(|(x, y)| {
                let (u, v) = (x as f32 / w as f32, y as f32 / h as f32);
                if (6..12).contains(&x) && (4..10).contains(&y) {
                    [0.1, 0.1, 0.2]
                } else {
                    [0.2 + 0.7 * u, 0.5, 0.9 - 0.6 * v]
                }
            })
            .collect();
        Image {
            width: w,
            height: h,
            data,
        }
    }

    #[test]
    fn every_step_logs_the_psnr_of_its_camera_and_it_rises() {
        let settings = PictureFitSettings {
            gaussians: 300,
            steps: 120,
            sh_degree: 0,
            ..PictureFitSettings::default()
        };
        let mut views = Vec::new();
        let fitted = fit_logged(&picture(), &settings, &Backend::Cpu, |r| {
            views.push((r.step, r.view == 1));
            ControlFlow::Continue(())
        })
        .unwrap();
        let logged: Vec<(u64, bool)> = fitted.psnr.iter().map(|p| (p.step, p.mirrored)).collect();
        assert_eq!(logged, views);
        assert!(views.iter().any(|v| v.1) && views.iter().any(|v| !v.1));
        let mean = |points: &[PsnrPoint]| {
            points.iter().map(|p| p.psnr_db).sum::<f64>() / points.len() as f64
        };
        let (first, last) = (mean(&fitted.psnr[..10]), mean(&fitted.psnr[110..]));
        assert!(last > first + 3.0, "PSNR {first:.2} dB -> {last:.2} dB");
    }

    /// A rising PSNR, alternating cameras: `steps` points.
    fn rising(steps: u64) -> Vec<PsnrPoint> {
        (1..=steps)
            .map(|step| PsnrPoint {
                step,
                mirrored: step % 2 == 0,
                psnr_db: 12.0 + 0.3 * step as f64 + if step % 2 == 0 { 1.0 } else { 0.0 },
            })
            .collect()
    }

    #[test]
    fn the_psnr_chart_has_one_rising_curve_per_camera() {
        let chart = psnr_chart(&rising(60));
        let legend = chart.legend();
        assert_eq!(
            legend,
            [
                ("front camera".to_string(), PALETTE[0]),
                ("mirror camera".to_string(), PALETTE[1])
            ]
        );
        assert_eq!(chart.series[1].points[0], (2.0, 13.6));
        let img = chart.render().unwrap();
        let plot_right = PLOT_WIDTH - LEGEND_WIDTH;
        for (_, color) in legend {
            let rows = |xs: std::ops::Range<u32>| {
                let rows: Vec<f64> = xs
                    .flat_map(|x| (0..img.height()).map(move |y| (x, y)))
                    .filter(|&(x, y)| img.get_pixel(x, y).0 == color)
                    .map(|(_, y)| y as f64)
                    .collect();
                assert!(!rows.is_empty(), "{color:?} is drawn");
                rows.iter().sum::<f64>() / rows.len() as f64
            };
            let (left, right) = (
                rows(0..plot_right / 3),
                rows(2 * plot_right / 3..plot_right),
            );
            assert!(
                left > right + 50.0,
                "a rising curve: rows {left} -> {right}"
            );
            rows(plot_right..PLOT_WIDTH);
        }
        let front_only: Vec<PsnrPoint> = rising(1);
        assert_eq!(psnr_chart(&front_only).legend().len(), 1);
    }
}
