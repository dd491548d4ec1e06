//! Fitting a small generated picture: the front camera reproduces the picture and the mirror
//! camera its mirror image, at the PSNR stated here, with the Gaussian count unchanged.

use std::ops::ControlFlow;

use base_mirage::fit::{fit, render_picture, FitSettings};
use base_mirage::mirror::mirrored;
use gs_core::image_loss::psnr;
use gs_core::Image;

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
    let target = picture();
    let settings = FitSettings {
        gaussians: 2000,
        steps: 600,
        sh_degree: 1,
        ..FitSettings::default()
    };
    let mut first_loss = None;
    let mut last_loss = 0.0;
    let model = fit(&target, &settings, |r| {
        first_loss.get_or_insert(r.value.loss);
        last_loss = r.value.loss;
        ControlFlow::Continue(())
    })
    .unwrap();
    assert_eq!(model.params().len(), 2000);
    let (w, h) = (target.width, target.height);
    let front =
        render_picture(&model, w, h, settings.distance, false, settings.background).unwrap();
    let back = render_picture(&model, w, h, settings.distance, true, settings.background).unwrap();
    let (p_front, p_back) = (psnr(&front, &target), psnr(&back, &mirrored(&target)));
    let start = render_picture(
        &base_mirage::init::initial_gaussians(2000, 1, 0.1, 0.1, 0),
        w,
        h,
        1.0,
        false,
        [0.0; 3],
    )
    .unwrap();
    eprintln!(
        "PSNR front {p_front:.2} dB, mirror {p_back:.2} dB (start {:.2} dB); loss {:?} -> {last_loss}",
        psnr(&start, &target),
        first_loss
    );
    assert!(p_front >= REQUIRED_PSNR, "front PSNR {p_front:.2} dB");
    assert!(p_back >= REQUIRED_PSNR, "mirror PSNR {p_back:.2} dB");
}

#[test]
fn bad_fit_settings_are_named() {
    let target = picture();
    for (settings, field) in [
        (
            FitSettings {
                gaussians: 0,
                ..FitSettings::default()
            },
            "gaussians",
        ),
        (
            FitSettings {
                steps: 0,
                ..FitSettings::default()
            },
            "steps",
        ),
        (
            FitSettings {
                sh_degree: 4,
                ..FitSettings::default()
            },
            "sh_degree",
        ),
        (
            FitSettings {
                distance: 0.0,
                ..FitSettings::default()
            },
            "distance",
        ),
    ] {
        let err = fit(&target, &settings, |_| ControlFlow::Continue(()))
            .unwrap_err()
            .to_string();
        assert!(err.contains(field), "{field}: {err}");
    }
}
