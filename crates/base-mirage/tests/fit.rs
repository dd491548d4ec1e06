//! Fitting a small generated picture: the front camera reproduces the picture and the mirror
//! camera its mirror image, at the PSNR stated here, with the Gaussian count unchanged, on the
//! cpu and on the GPU (lavapipe in CI).

use std::ops::ControlFlow;
use std::sync::Arc;

use base_mirage::fit::{fit, render_picture, PictureFitSettings};
use base_mirage::mirror::mirrored;
use gs_core::image_loss::psnr;
use gs_core::Image;
use gs_wgpu::backend::Backend;
use gs_wgpu::{test_context, GpuOptions};

/// A 64x40 picture: a horizontal colour ramp, a dark disc and a bright bar.
fn picture() -> Image {
    let (w, h) = (64u32, 40u32);
    let mut data = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let (u, v) = (x as f32 / w as f32, y as f32 / h as f32);
            let disc = (u - 0.3).powi(2) + (v - 0.5).powi(2) < 0.04;
            let bar = (0.65..0.8).contains(&u) && (0.2..0.9).contains(&v);
            data.extend_from_slice(&if disc {
                [0.1, 0.1, 0.3]
            } else if bar {
                [0.95, 0.9, 0.2]
            } else {
                [0.2 + 0.6 * u, 0.5, 0.8 - 0.5 * v]
            });
        }
    }
    Image {
        width: w,
        height: h,
        data,
    }
}

/// The PSNR (dB) the fit must reach on both cameras.
const REQUIRED_PSNR: f64 = 35.0;

#[test]
fn fitting_a_picture_reaches_the_stated_psnr_on_both_cameras() {
    let settings = PictureFitSettings {
        gaussians: 2000,
        steps: 600,
        sh_degree: 1,
        ..PictureFitSettings::default()
    };
    let (p_front, p_back) = fit_psnr(&Backend::Cpu, &settings);
    assert!(p_front >= REQUIRED_PSNR, "front PSNR {p_front:.2} dB");
    assert!(p_back >= REQUIRED_PSNR, "mirror PSNR {p_back:.2} dB");
}

/// A GPU fit lands in the cpu fit's PSNR band (a shorter fit than the test above: lavapipe is
/// slow).
#[test]
fn fitting_on_the_gpu_reaches_the_psnr_of_the_cpu() {
    let Some(ctx) = test_context(GpuOptions::default()) else {
        return;
    };
    let settings = PictureFitSettings {
        gaussians: 600,
        steps: 250,
        sh_degree: 1,
        ..PictureFitSettings::default()
    };
    let (cpu_front, cpu_back) = fit_psnr(&Backend::Cpu, &settings);
    let (gpu_front, gpu_back) = fit_psnr(&Backend::Gpu(Arc::new(ctx)), &settings);
    assert!(
        cpu_front > 20.0,
        "the short fit learned the picture: {cpu_front:.2} dB"
    );
    for (cpu, gpu) in [(cpu_front, gpu_front), (cpu_back, gpu_back)] {
        assert!((cpu - gpu).abs() < 1.0, "cpu {cpu:.2} dB, gpu {gpu:.2} dB");
    }
}

/// Fits the picture on `backend` and returns the PSNR of the front and the mirror camera.
fn fit_psnr(backend: &Backend, settings: &PictureFitSettings) -> (f64, f64) {
    let target = picture();
    let mut first_loss = None;
    let mut last_loss = 0.0;
    let mut model = fit(&target, settings, backend, |r| {
        first_loss.get_or_insert(r.value.loss);
        last_loss = r.value.loss;
        ControlFlow::Continue(())
    })
    .unwrap();
    assert_eq!(model.params().len(), settings.gaussians);
    let (w, h) = (target.width, target.height);
    let mut view = |mirror| {
        render_picture(
            &mut model,
            w,
            h,
            settings.distance,
            mirror,
            settings.background,
            backend,
        )
        .unwrap()
    };
    let (front, back) = (view(false), view(true));
    let (p_front, p_back) = (psnr(&front, &target), psnr(&back, &mirrored(&target)));
    eprintln!(
        "{}: PSNR front {p_front:.2} dB, mirror {p_back:.2} dB; loss {first_loss:?} -> \
         {last_loss}",
        backend.describe()
    );
    (p_front, p_back)
}

#[test]
fn bad_fit_settings_are_named() {
    let target = picture();
    for (settings, field) in [
        (
            PictureFitSettings {
                gaussians: 0,
                ..PictureFitSettings::default()
            },
            "gaussians",
        ),
        (
            PictureFitSettings {
                steps: 0,
                ..PictureFitSettings::default()
            },
            "steps",
        ),
        (
            PictureFitSettings {
                sh_degree: 4,
                ..PictureFitSettings::default()
            },
            "sh_degree",
        ),
        (
            PictureFitSettings {
                distance: 0.0,
                ..PictureFitSettings::default()
            },
            "distance",
        ),
    ] {
        let err = fit(&target, &settings, &Backend::Cpu, |_| {
            ControlFlow::Continue(())
        })
        .unwrap_err()
        .to_string();
        assert!(err.contains(field), "{field}: {err}");
    }
}
