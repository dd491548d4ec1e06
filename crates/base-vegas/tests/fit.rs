//! Fitting a small generated clip: the PSNR a fit reaches, and the same training steps on the
//! wgpu backend (lavapipe in CI) equal to the cpu ones.

use std::ops::ControlFlow;
use std::time::Instant;

use base_vegas::fit::{fit, mean_psnr, render_frames, training_views, VideoFitSettings};
use base_vegas::init::initial_model;
use gs_core::mirror_pair::plane_half_size;
use gs_core::model::BaseModel;
use gs_core::raster::{backward, render, OutputGrads};
use gs_core::Image;
use gs_wgpu::backend::Backend;
use gs_wgpu::{
    self as gpu, read_f32, test_context, GpuModel, GpuOptions, GpuParams, GpuScratch, GpuStep,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// `frames` frames of `w x h`: a colour ramp that brightens over time and a red disc moving
/// left to right.
fn clip(frames: usize, w: u32, h: u32) -> Vec<Image> {
    (0..frames)
        .map(|f| {
            let s = f as f32 / (frames - 1) as f32;
            let (cx, cy, r) = (0.2 + 0.6 * s, 0.5, 0.18);
            let data = (0..h)
                .flat_map(|y| (0..w).map(move |x| (x, y)))
                .flat_map(|(x, y)| {
                    let (u, v) = (x as f32 / w as f32, y as f32 / h as f32);
                    let (dx, dy) = ((u - cx) * w as f32 / h as f32, v - cy);
                    if dx * dx + dy * dy < r * r {
                        [0.9, 0.15, 0.1]
                    } else {
                        [0.2 + 0.5 * u, 0.3 + 0.3 * s, 0.8 - 0.5 * v]
                    }
                })
                .collect();
            Image {
                width: w,
                height: h,
                data,
            }
        })
        .collect()
}

#[test]
fn fitting_a_small_clip_reaches_the_stated_psnr() {
    let frames = clip(12, 96, 64);
    let settings = VideoFitSettings {
        gaussians: 3000,
        steps: 1500,
        seed: 1,
        ..VideoFitSettings::default()
    };
    let start = Instant::now();
    let mut model = fit(&frames, &settings, &Backend::Cpu, |_| {
        ControlFlow::Continue(())
    })
    .unwrap();
    let renders = render_frames(
        &mut model,
        96,
        64,
        settings.distance,
        settings.background,
        &Backend::Cpu,
    )
    .unwrap();
    let psnr = mean_psnr(&renders, &frames);
    println!(
        "fit: {psnr:.2} dB mean PSNR in {:.1} s",
        start.elapsed().as_secs_f64()
    );
    assert_eq!(renders.len(), 12);
    assert_eq!(model.params().len(), 3000, "the Gaussian count is kept");
    assert!(psnr > 30.0, "mean PSNR {psnr:.2} dB (33.99 measured)");
}

/// Within 1e-4 of the largest magnitude (f32 sums in another order, nothing more).
fn assert_close(what: &str, want: &[f32], got: &[f32]) {
    assert_eq!(want.len(), got.len(), "{what}: sizes");
    let max = want.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    assert!(max > 0.0, "{what}: all zero");
    for (k, (a, b)) in want.iter().zip(got).enumerate() {
        assert!(
            (a - b).abs() <= 1e-4 * max,
            "{what}[{k}]: cpu {a} gpu {b} (largest {max})"
        );
    }
}

/// A frame's Gaussians built through the wgpu path (`gpu_forward`, `gpu_backward`) against the
/// cpu path: the Gaussians, the image and the gradient of every parameter group (time logits
/// included), at the first, a middle and the last frame, front and mirror camera.
#[test]
fn the_wgpu_path_equals_the_cpu_path() {
    let (w, h) = (40, 28);
    let frames = 5;
    let (hw, hh) = plane_half_size(w, h, 1.0);
    let mut model = initial_model(400, frames, hw, hh, 5);
    // Unequal in-plane scales, so that the rotation matters.
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    for s in model.groups_mut()[1].iter_mut() {
        *s += rng.random_range(-0.7..0.7);
    }
    let Some(ctx) = test_context(GpuOptions::default()) else {
        return;
    };
    let params = GpuParams::upload(&ctx, &mut model).unwrap();
    let mut scratch = GpuScratch::default();
    let mut step = GpuStep {
        ctx: &ctx,
        params: &params,
        scratch: &mut scratch,
    };
    let views = training_views(w, h, frames, 1.0).unwrap();
    let bg = [0.1, 0.2, 0.3];
    let dl: Vec<f32> = (0..3 * w * h)
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    let out = OutputGrads {
        rgb: &dl,
        alpha: None,
        depth: None,
    };
    let trained = [true; 9];
    for view in [&views[0], &views[5], &views[9]] {
        let forward = model.forward(view).unwrap();
        let (cpu_set, tape) = (forward.gaussians.into_owned(), forward.tape);
        let on_gpu = model.gpu_forward(&mut step, view).unwrap();
        assert_eq!(
            on_gpu.gaussians.download(&ctx),
            cpu_set,
            "frame Gaussians, bit for bit"
        );
        let cpu_r = render(&cpu_set, &view.camera, bg);
        let gpu_r = gpu::render(&ctx, &on_gpu.gaussians, &view.camera, bg).unwrap();
        assert_close("image", &cpu_r.image.data, &gpu_r.image(&ctx).data);
        let mask = model.grad_mask(&trained);
        let cpu_grads = backward(&cpu_set, &view.camera, &cpu_r, &out, mask);
        let mut want: Vec<Vec<f32>> = model.group_lens().iter().map(|&n| vec![0.0; n]).collect();
        model
            .backward(view, tape, &cpu_grads.gaussians, &trained, &mut want)
            .unwrap();
        let gpu_grads = gpu::backward(&ctx, &on_gpu.gaussians, &gpu_r, &out, mask).unwrap();
        let got = model
            .gpu_backward(&mut step, view, on_gpu.tape, gpu_grads, &trained)
            .unwrap();
        for ((name, want), got) in model.group_names().iter().zip(&want).zip(got) {
            let buffer = got.unwrap_or_else(|| panic!("no gradient of {name}"));
            let what = format!("time {}: gradient of {name}", view.time);
            let got = read_f32(&ctx, &buffer, want.len());
            if name == "time" && (view.time == 0.0 || view.time == 1.0) {
                // The first and last frames sit at times 0 and 1 whatever the logits.
                let largest = want.iter().chain(&got).fold(0.0f32, |m, g| m.max(g.abs()));
                assert!(largest < 1e-6, "{what}: {largest}");
                continue;
            }
            assert_close(&what, want, &got);
        }
    }
}
