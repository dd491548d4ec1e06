//! Memory that stays flat over many renders and backward passes: a training run of thousands
//! of steps must not hold memory per step. Mesa's lavapipe (22.3) keeps memory for every
//! dispatch of a kernel that reads a uniform buffer (about 1.3 MB per training step of a small
//! scene), so software adapters bind parameter blocks as read-only storage
//! ([`gs_wgpu::ParameterBinding`]); this test renders and differentiates a scene 100 times and
//! bounds the growth of the process's resident memory. Alone in its test binary, so that no
//! other test allocates meanwhile. Needs a GPU adapter (lavapipe in CI); Linux only (it reads
//! `/proc/self/statm`).
#![cfg(target_os = "linux")]

/// The scenes and GPU contexts of gs-core's rasterizer tests, shared with them.
#[path = "../../gs-core/tests/common/mod.rs"]
mod common;

use common::{gpu_with, oblique_camera, random_scene, weights};
use gs_core::raster::{GradMask, OutputGrads};
use gs_wgpu::{self as gpu_backend, GpuContext, GpuGaussians, GpuOptions, ParameterBinding};

/// The process's resident memory, bytes.
fn resident_bytes() -> u64 {
    let statm = std::fs::read_to_string("/proc/self/statm").expect("/proc/self/statm");
    let pages: u64 = statm
        .split_whitespace()
        .nth(1)
        .and_then(|v| v.parse().ok())
        .expect("resident pages in /proc/self/statm");
    pages * 4096
}

/// Renders and differentiates a scene `times` times on `ctx`.
fn render_and_differentiate(ctx: &GpuContext, times: usize) {
    let g = random_scene::<f32>(3, 300, 1);
    let camera = oblique_camera(48, 40);
    let gg = GpuGaussians::upload(ctx, &g).expect("upload");
    let rgb: Vec<f32> = weights(5, 3 * camera.pixel_count())
        .into_iter()
        .map(|v| v as f32)
        .collect();
    let out = OutputGrads {
        rgb: &rgb,
        alpha: None,
        depth: None,
    };
    for _ in 0..times {
        let r = gpu_backend::render(ctx, &gg, &camera, [0.2; 3]).expect("render");
        let grads = gpu_backend::backward(ctx, &gg, &r, &out, GradMask::ALL).expect("backward");
        // Waits for the device, as a training step does.
        grads.background(ctx);
    }
}

#[test]
fn renders_and_backward_passes_hold_no_memory() {
    let Some(ctx) = gpu_with(GpuOptions::default()) else {
        return;
    };
    if ctx.is_software() {
        assert_eq!(ctx.parameter_binding(), ParameterBinding::Storage);
    }
    // Warm up: pools and caches of the driver fill in the first passes.
    render_and_differentiate(&ctx, 20);
    let before = resident_bytes();
    render_and_differentiate(&ctx, 100);
    let grown = resident_bytes().saturating_sub(before);
    // Bound as uniforms on lavapipe, 100 passes hold over 100 MB.
    assert!(
        grown < 16 << 20,
        "resident memory grew by {:.1} MB over 100 renders and backward passes on {}",
        grown as f64 / 1e6,
        ctx.describe()
    );
}
