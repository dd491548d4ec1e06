//! The wgpu backend's backward pass against the cpu backend's, for every parameter kind, on
//! random scenes of every SH degree and on each degenerate case of docs/conventions.md, with
//! native f32 atomics and with the compare-exchange fallback, and with frozen groups. Needs a
//! GPU adapter (lavapipe in CI): without one these tests fail, naming what to install.

/// The scenes and GPU contexts of gs-core's rasterizer tests, shared with them.
#[path = "../../gs-core/tests/common/mod.rs"]
mod common;

use common::{
    degenerate_cases, edge_on_flat, front_camera, gpu, gpu_per_parameter_binding, gpu_with,
    oblique_camera, poisoned_scene, random_scene, stacked_scene, weights, SMALL_BINDING,
};
use gs_core::gaussians::PARAM_NAMES;
use gs_core::raster::{backward, render, GradMask, OutputGrads};
use gs_core::{Camera, GaussianSet};
use gs_wgpu::{self as gpu_backend, GpuContext, GpuGaussians, GpuOptions};

fn f32s(v: Vec<f64>) -> Vec<f32> {
    v.into_iter().map(|x| x as f32).collect()
}

/// Entries of `got` within 1e-4 of the largest magnitude of `want`, and the whole array within
/// 1e-4 relative (f32 sums in another order, nothing more).
fn assert_close(what: &str, want: &[f32], got: &[f32]) {
    assert_eq!(want.len(), got.len(), "{what}: sizes");
    let max = want.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let norm = want.iter().map(|v| v * v).sum::<f32>().sqrt();
    let diff: Vec<f32> = want.iter().zip(got).map(|(a, b)| a - b).collect();
    let worst = diff.iter().fold(0.0f32, |m, d| m.max(d.abs()));
    let rel = diff.iter().map(|d| d * d).sum::<f32>().sqrt() / norm.max(1e-30);
    assert!(
        worst <= 1e-4 * max.max(1e-30) && rel <= 1e-4,
        "{what}: worst entry {worst:e} (largest {max:e}), relative {rel:e}\ncpu {want:?}\ngpu {got:?}"
    );
}

/// Renders and differentiates `case` on both backends with random output gradients (RGB, and
/// alpha and depth when `all_outputs`), and checks every gradient `mask` asks for.
fn check(
    case: &str,
    ctx: &GpuContext,
    g: &GaussianSet,
    cam: &Camera,
    mask: GradMask,
    all_outputs: bool,
) {
    let bg = [0.2, 0.5, 0.9];
    let n = cam.pixel_count();
    let rgb = f32s(weights(11, 3 * n));
    let alpha = f32s(weights(12, n));
    let depth: Vec<f32> = f32s(weights(13, n)).iter().map(|v| 0.1 * v).collect();
    let out = OutputGrads {
        rgb: &rgb,
        alpha: all_outputs.then_some(&alpha[..]),
        depth: all_outputs.then_some(&depth[..]),
    };
    let cpu_r = render(g, cam, bg);
    let cpu = backward(g, cam, &cpu_r, &out, mask);
    let gg = GpuGaussians::upload(ctx, g).expect("upload");
    let r = gpu_backend::render(ctx, &gg, cam, bg).expect("render");
    let gpu = gpu_backend::backward(ctx, &gg, &r, &out, mask)
        .expect("backward")
        .download(ctx);
    for (name, (want, got)) in PARAM_NAMES.iter().zip(
        cpu.gaussians
            .arrays()
            .into_iter()
            .zip(gpu.gaussians.arrays()),
    ) {
        assert_close(&format!("{case}: {name}"), want, got);
    }
    assert_close(
        &format!("{case}: background"),
        &cpu.background,
        &gpu.background,
    );
}

#[test]
fn random_scenes_every_degree() {
    let Some(ctx) = gpu() else { return };
    for degree in 0..=3 {
        let g = random_scene::<f32>(30 + degree as u64, 40, degree);
        let case = format!("degree {degree}");
        check(&case, ctx, &g, &oblique_camera(48, 40), GradMask::ALL, true);
        check(&case, ctx, &g, &front_camera(37, 29), GradMask::ALL, false);
    }
}

#[test]
fn compare_exchange_accumulation_gives_the_same_gradients() {
    let Some(ctx) = gpu_with(GpuOptions {
        float_atomics: false,
        ..GpuOptions::default()
    }) else {
        return;
    };
    assert!(!ctx.float_atomics());
    for degree in [0, 3] {
        let g = random_scene::<f32>(50 + degree as u64, 40, degree);
        check(
            "cas",
            &ctx,
            &g,
            &oblique_camera(48, 40),
            GradMask::ALL,
            true,
        );
    }
}

#[test]
fn arrays_past_the_binding_limit_give_the_same_gradients() {
    // Under a 64 KiB binding limit, 3000 Gaussians of degree 3 run in 12 chunks of 256 and
    // accumulate into 3 parts of 1024; the compare-exchange variant covers its own part switch.
    for float_atomics in [true, false] {
        let Some(ctx) = gpu_with(GpuOptions {
            float_atomics,
            max_binding_bytes: Some(SMALL_BINDING),
            ..GpuOptions::default()
        }) else {
            return;
        };
        let mut g = random_scene::<f32>(14, 3000, 3);
        for v in &mut g.log_scales {
            *v -= 1.0;
        }
        check(
            &format!("split arrays, f32 atomics {float_atomics}"),
            &ctx,
            &g,
            &oblique_camera(64, 48),
            GradMask::ALL,
            true,
        );
    }
}

#[test]
fn parameter_blocks_bound_either_way_give_the_same_gradients() {
    // Uniforms (hardware adapters) and read-only storage (software ones), whichever adapter
    // runs this, in chunks and parts.
    for ctx in gpu_per_parameter_binding(GpuOptions {
        max_binding_bytes: Some(SMALL_BINDING),
        ..GpuOptions::default()
    }) {
        let binding = ctx.parameter_binding();
        let mut g = random_scene::<f32>(15, 3000, 3);
        for v in &mut g.log_scales {
            *v -= 1.0;
        }
        check(
            &format!("{binding:?}"),
            &ctx,
            &g,
            &oblique_camera(64, 48),
            GradMask::ALL,
            true,
        );
    }
}

#[test]
fn frozen_groups_get_zero_and_the_rest_is_unchanged() {
    let Some(ctx) = gpu() else { return };
    let g = random_scene::<f32>(8, 30, 2);
    let cam = oblique_camera(40, 30);
    check("colours", ctx, &g, &cam, GradMask::COLORS, true);
    let scales_only = GradMask {
        means: false,
        rotations: false,
        opacities: false,
        sh_dc: false,
        sh_rest: false,
        ..GradMask::ALL
    };
    check("scales only", ctx, &g, &cam, scales_only, true);
    let opacity_and_rest = GradMask {
        opacities: true,
        sh_rest: true,
        ..GradMask::COLORS
    };
    check(
        "opacity and sh_rest",
        ctx,
        &g,
        &cam,
        opacity_and_rest,
        false,
    );
}

#[test]
fn many_gaussians() {
    let Some(ctx) = gpu() else { return };
    let mut g = random_scene::<f32>(5, 3000, 1);
    for v in &mut g.log_scales {
        *v -= 1.0;
    }
    check(
        "3000 Gaussians",
        ctx,
        &g,
        &oblique_camera(120, 90),
        GradMask::ALL,
        true,
    );
}

#[test]
fn degenerate_cases_match_the_cpu() {
    let Some(ctx) = gpu() else { return };
    let cam = front_camera(24, 24);
    for (name, g) in degenerate_cases() {
        let g = g.cast();
        check(name, ctx, &g, &cam, GradMask::ALL, true);
    }
    let (flat, side) = edge_on_flat();
    let flat = flat.cast();
    check("flat, seen edge-on", ctx, &flat, &side, GradMask::ALL, true);

    let stacked = stacked_scene();
    check(
        "pixels that stop early",
        ctx,
        &stacked,
        &cam,
        GradMask::ALL,
        true,
    );
}

#[test]
fn non_finite_and_extreme_parameters_get_zero_gradient() {
    let Some(ctx) = gpu() else { return };
    let g = poisoned_scene();
    check(
        "non-finite",
        ctx,
        &g,
        &oblique_camera(48, 40),
        GradMask::ALL,
        true,
    );
}

/// 3DGS's densification statistics gathered on the device against the cpu's twin
/// (`ScreenStats::add_view`) over two views, with Gaussians behind the camera and off the
/// picture (counted by neither), on whole arrays and past a small binding limit (chunks).
#[test]
fn densification_statistics_match_the_cpus() {
    use gs_core::densify::ScreenStats;
    use gs_core::raster::backward_with_screen_grads;
    use gs_wgpu::GpuScreenStats;

    for small in [false, true] {
        let Some(ctx) = gpu_with(GpuOptions {
            max_binding_bytes: small.then_some(SMALL_BINDING),
            ..GpuOptions::default()
        }) else {
            return;
        };
        let n = if small { 3000 } else { 300 };
        let mut g = random_scene::<f32>(21, n, 1);
        for v in &mut g.log_scales {
            *v -= 1.0;
        }
        // Behind the cameras and far off to the side: culled in both views.
        g.means[0..3].copy_from_slice(&[0.0, 0.0, -9.0]);
        g.means[3..6].copy_from_slice(&[60.0, 0.0, 0.0]);
        let mut cpu = ScreenStats::new(n);
        let gg = GpuGaussians::upload(&ctx, &g).expect("upload");
        let device = GpuScreenStats::upload(&ctx, &ScreenStats::new(n)).expect("stats");
        for (k, cam) in [front_camera(40, 32), oblique_camera(48, 40)]
            .iter()
            .enumerate()
        {
            let rgb = f32s(weights(30 + k as u64, 3 * cam.pixel_count()));
            let out = OutputGrads {
                rgb: &rgb,
                alpha: None,
                depth: None,
            };
            let rendered = render(&g, cam, [0.1; 3]);
            let (_, screen) = backward_with_screen_grads(&g, cam, &rendered, &out, GradMask::ALL);
            cpu.add_view(&rendered, &screen, (cam.width, cam.height));
            let r = gpu_backend::render(&ctx, &gg, cam, [0.1; 3]).expect("render");
            gpu_backend::backward_with_stats(&ctx, &gg, &r, &out, GradMask::ALL, Some(&device))
                .expect("backward");
        }
        let got = device.download(&ctx);
        assert_eq!(got.count, cpu.count, "small binding {small}");
        assert_eq!(
            cpu.count[0] + cpu.count[1],
            0,
            "the culled ones count nowhere"
        );
        assert!(cpu.count.iter().filter(|&&c| c == 2).count() > n / 4);
        assert_close(
            &format!("gradient sums, small binding {small}"),
            &cpu.grad_sum,
            &got.grad_sum,
        );
    }
}
