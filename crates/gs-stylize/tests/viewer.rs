//! `viewer.html` in headless Chromium (Debian's `chromium`, software WebGL): the page's picture
//! from a fixed camera is gs-core's cpu render of it (PSNR >= 30 dB over the model's pixels),
//! at the style slider's 0 (the base model), 1 (the stylized one) and 0.5 (`interpolate`'s
//! blend), and the page makes no network request (every request goes through a proxy the test
//! holds; only Chromium's own background calls to Google's hosts may reach it).
//!
//! Without a browser the test says so and passes, unless `CLIPGAUSSIAN_REQUIRE_BROWSER_TESTS=1`
//! (CI's `.ci/run` installs Chromium and sets it).

mod browser;

use std::sync::atomic::Ordering;

use gs_core::{Camera, GaussianSet};
use gs_stylize::viewer::{write_viewer, write_viewer_as, Animation, Shown, ViewerScene};
use rand::{Rng, SeedableRng};

/// A small scene of `n` Gaussians of SH degree 3 around the origin, from `seed`.
fn scene(n: usize, seed: u64) -> GaussianSet {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut set = GaussianSet::zeros(n, 3);
    for v in set.means.iter_mut() {
        *v = rng.random_range(-1.0..1.0);
    }
    for v in set.log_scales.iter_mut() {
        *v = rng.random_range(-3.5..-1.8);
    }
    for v in set.quats.iter_mut() {
        *v = rng.random_range(-1.0..1.0);
    }
    for v in set.opacity_logits.iter_mut() {
        *v = rng.random_range(-1.0..3.0);
    }
    for v in set.sh_dc.iter_mut() {
        *v = rng.random_range(-1.5..1.5);
    }
    for v in set.sh_rest.iter_mut() {
        *v = rng.random_range(-0.2..0.2);
    }
    set
}

/// A base scene of 300 Gaussians, its stylization (the same Gaussians moved, recoloured and
/// resized), and a camera that sees them whole.
fn base_and_stylized() -> (GaussianSet, GaussianSet, Camera) {
    let base = scene(300, 1);
    let mut stylized = scene(300, 2);
    for (s, b) in stylized.means.iter_mut().zip(&base.means) {
        *s = b + 0.1 * *s;
    }
    let camera =
        Camera::look_at([0.4, -0.6, -4.0], [0.0; 3], [0.0, -1.0, 0.0], 0.8, 160, 120).unwrap();
    (base, stylized, camera)
}

#[test]
fn the_viewer_draws_what_gs_core_renders_at_every_slider_position() {
    let Some(chromium) = browser::chromium_or_skip() else {
        return;
    };
    let (base, stylized, camera) = base_and_stylized();
    let background = [1.0f32, 1.0, 1.0];
    let dir = tempfile::tempdir().unwrap();
    let page = dir.path().join("viewer.html");
    write_viewer(
        &page,
        &ViewerScene {
            title: "test".into(),
            shown: Shown::Still {
                base: &base,
                stylized: Some(&stylized),
            },
            cameras: vec![("view 0".into(), camera.clone())],
            background,
        },
    )
    .unwrap();
    let (port, requests, stop) = browser::proxy();
    for t in [0.0f32, 1.0, 0.5] {
        let blended = gs_core::interpolate::interpolate(&base, &stylized, t).unwrap();
        let rendered = gs_core::raster::render(&blended, &camera, background);
        let shot = browser::screenshot(
            &chromium,
            &page,
            &format!("camera=0&t={t}&clean"),
            (160, 120),
            port,
        );
        assert_eq!(shot.dimensions(), (160, 120));
        let (psnr, pixels) = browser::psnr_over_model(&shot, &rendered.image, &rendered.alpha);
        eprintln!("slider {t}: {psnr:.1} dB over {pixels} pixels");
        assert!(pixels > 2000, "the model covers the view: {pixels} pixels");
        assert!(psnr >= 30.0, "slider {t}: {psnr:.1} dB");
    }
    stop.store(true, Ordering::SeqCst);
    let page_requests = browser::page_requests(&requests);
    assert!(
        page_requests.is_empty(),
        "the page made network requests: {page_requests:?}"
    );
}

/// A page of snapshots (a dynamic scene's Gaussians at a few times): frame k at slider t draws
/// gs-core's render of `interpolate`(base k, stylized k, t).
#[test]
fn a_page_of_snapshots_draws_each_time_as_gs_core_renders_it() {
    let Some(chromium) = browser::chromium_or_skip() else {
        return;
    };
    let base: Vec<GaussianSet> = (0..3)
        .map(|k| {
            let mut set = scene(250, 5);
            set.means
                .iter_mut()
                .step_by(3)
                .for_each(|x| *x += 0.3 * k as f32);
            set
        })
        .collect();
    let stylized: Vec<GaussianSet> = base
        .iter()
        .enumerate()
        .map(|(k, b)| {
            let mut s = scene(250, 10 + k as u64);
            s.means.clone_from(&b.means);
            s
        })
        .collect();
    let background = [0.0f32, 0.0, 0.0];
    let camera = Camera::look_at(
        [0.0, -0.5, -4.0],
        [0.3, 0.0, 0.0],
        [0.0, -1.0, 0.0],
        0.9,
        160,
        120,
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let page = dir.path().join("viewer.html");
    write_viewer(
        &page,
        &ViewerScene {
            title: "snapshots".into(),
            shown: Shown::Animated(Animation::snapshots(&base, Some(&stylized)).unwrap()),
            cameras: vec![("view 0".into(), camera.clone())],
            background,
        },
    )
    .unwrap();
    let (port, requests, stop) = browser::proxy();
    for (frame, t) in [(0usize, 0.0f32), (2, 1.0), (1, 0.5)] {
        let blended = gs_core::interpolate::interpolate(&base[frame], &stylized[frame], t).unwrap();
        let rendered = gs_core::raster::render(&blended, &camera, background);
        let shot = browser::screenshot(
            &chromium,
            &page,
            &format!("frame={frame}&t={t}&clean"),
            (160, 120),
            port,
        );
        let (psnr, pixels) = browser::psnr_over_model(&shot, &rendered.image, &rendered.alpha);
        eprintln!("frame {frame}, slider {t}: {psnr:.1} dB over {pixels} pixels");
        assert!(pixels > 2000, "{pixels} pixels");
        assert!(psnr >= 30.0, "frame {frame}, slider {t}: {psnr:.1} dB");
    }
    stop.store(true, Ordering::SeqCst);
    assert!(browser::page_requests(&requests).is_empty());
    // Snapshots of other Gaussians are refused.
    let other = vec![scene(10, 1)];
    let e = Animation::snapshots(&base, Some(&other)).err().unwrap();
    assert!(
        e.contains("another number of snapshots") || e.contains("250 and 10"),
        "{e}"
    );
}

/// A page in the compact form (what scenes above `COMPACT_ABOVE` Gaussians get) still draws
/// what gs-core renders of the unquantised models, within the format's quantisation.
#[test]
fn a_compact_page_draws_what_gs_core_renders_within_its_quantisation() {
    let Some(chromium) = browser::chromium_or_skip() else {
        return;
    };
    let (base, stylized, camera) = base_and_stylized();
    let background = [1.0f32, 1.0, 1.0];
    let dir = tempfile::tempdir().unwrap();
    let (full, compact) = (
        dir.path().join("full.html"),
        dir.path().join("compact.html"),
    );
    let scene_of = || ViewerScene {
        title: "compact".into(),
        shown: Shown::Still {
            base: &base,
            stylized: Some(&stylized),
        },
        cameras: vec![("view 0".into(), camera.clone())],
        background,
    };
    write_viewer_as(&full, &scene_of(), false).unwrap();
    write_viewer_as(&compact, &scene_of(), true).unwrap();
    let (full_size, compact_size) = (
        std::fs::metadata(&full).unwrap().len(),
        std::fs::metadata(&compact).unwrap().len(),
    );
    eprintln!("page: {full_size} bytes as floats, {compact_size} compact");
    let (port, _, stop) = browser::proxy();
    for t in [0.0f32, 1.0, 0.5] {
        let blended = gs_core::interpolate::interpolate(&base, &stylized, t).unwrap();
        let rendered = gs_core::raster::render(&blended, &camera, background);
        let shot = browser::screenshot(
            &chromium,
            &compact,
            &format!("camera=0&t={t}&clean"),
            (160, 120),
            port,
        );
        let (psnr, pixels) = browser::psnr_over_model(&shot, &rendered.image, &rendered.alpha);
        eprintln!("compact, slider {t}: {psnr:.1} dB over {pixels} pixels");
        assert!(psnr >= 30.0, "slider {t}: {psnr:.1} dB");
    }
    stop.store(true, Ordering::SeqCst);
}
