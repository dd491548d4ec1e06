//! A VeGaS model in `viewer.html`, in headless Chromium: the page makes each frame in
//! JavaScript (`viewer_frame.js`) and draws what gs-core renders of `build_frame` at that
//! frame's learned time (PSNR >= 30 dB over the model's pixels), at the ends and middle of the
//! time and style sliders; the page makes no network request. Skipped, saying so, without a
//! browser unless `CLIPGAUSSIAN_REQUIRE_BROWSER_TESTS=1`.

#[path = "../../gs-stylize/tests/browser/mod.rs"]
mod browser;

use std::sync::atomic::Ordering;

use base_vegas::frame::build_frame;
use base_vegas::init::initial_model;
use base_vegas::viewer::animation;
use gs_core::mirror_pair::{plane_camera, plane_half_size, DEFAULT_DISTANCE};
use gs_core::model::BaseModel;
use gs_stylize::viewer::{write_viewer, Shown, ViewerScene};

#[test]
fn the_viewer_plays_a_video_model_as_its_frames_render() {
    let Some(chromium) = browser::chromium_or_skip() else {
        return;
    };
    let (width, height) = (160u32, 120u32);
    let (half_width, half_height) = plane_half_size(width, height, DEFAULT_DISTANCE);
    let frames = 5;
    let mut base = initial_model(400, frames, half_width, half_height, 3);
    // Moving, fading Gaussians with uneven frame times: every part of the frame's formula and
    // of the time function is exercised.
    for (k, g) in base.groups_mut().into_iter().enumerate() {
        for (i, v) in g.iter_mut().enumerate() {
            let wiggle = ((k * 37 + i * 11) % 23) as f32 / 23.0 - 0.5;
            *v += match k {
                3 => 2.0 * wiggle, // m: the temporal centres spread over the video
                5 => 0.2 * wiggle, // w: motion
                7 => 1.5 * wiggle, // colour
                8 => 0.8 * wiggle, // time logits: uneven frame times
                _ => 0.02 * wiggle,
            };
        }
    }
    let mut stylized = base.clone();
    for (k, g) in stylized.groups_mut().into_iter().enumerate() {
        for (i, v) in g.iter_mut().enumerate() {
            if k == 7 || k == 0 {
                *v += 0.3 * (((i * 7) % 13) as f32 / 13.0 - 0.5);
            }
        }
    }
    let camera = plane_camera(width, height, DEFAULT_DISTANCE, false).unwrap();
    let background = [0.0f32, 0.0, 0.0];
    let dir = tempfile::tempdir().unwrap();
    let page = dir.path().join("viewer.html");
    write_viewer(
        &page,
        &ViewerScene {
            title: "video".into(),
            shown: Shown::Animated(animation(&base, Some(&stylized))),
            cameras: vec![("frame".into(), camera.clone())],
            background,
        },
    )
    .unwrap();
    let (port, requests, stop) = browser::proxy();
    for (frame, t) in [(0usize, 0.0f32), (frames - 1, 1.0), (2, 0.5)] {
        let blended = gs_core::interpolate::blend_groups(&base, &stylized, t).unwrap();
        let (set, _) = build_frame(blended.params(), blended.time_of(frame));
        let rendered = gs_core::raster::render(&set, &camera, background);
        let shot = browser::screenshot(
            &chromium,
            &page,
            &format!("frame={frame}&t={t}&clean"),
            (width, height),
            port,
        );
        let (psnr, pixels) = browser::psnr_over_model(&shot, &rendered.image, &rendered.alpha);
        eprintln!("frame {frame}, slider {t}: {psnr:.1} dB over {pixels} pixels");
        assert!(
            pixels > 2000,
            "frame {frame}: the model covers the view: {pixels} pixels"
        );
        assert!(psnr >= 30.0, "frame {frame}, slider {t}: {psnr:.1} dB");
    }
    stop.store(true, Ordering::SeqCst);
    let page_requests = browser::page_requests(&requests);
    assert!(page_requests.is_empty(), "{page_requests:?}");
}
