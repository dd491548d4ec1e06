//! The wgpu backend's Adam against gs-core's cpu Adam, step for step, with a frozen group and
//! both schedules. Needs a GPU adapter (lavapipe in CI).

/// The scenes and GPU contexts of gs-core's rasterizer tests, shared with them.
#[path = "../../gs-core/tests/common/mod.rs"]
mod common;

use common::{gpu, gpu_per_parameter_binding, gpu_with, weights};
use gs_core::adam::{Adam, AdamHyper, GroupConfig, LrSchedule};
use gs_wgpu::{GpuAdam, GpuContext, GpuOptions};

fn f32s(v: Vec<f64>) -> Vec<f32> {
    v.into_iter().map(|x| x as f32).collect()
}

#[test]
fn matches_the_cpu_adam_step_for_step() {
    let Some(ctx) = gpu() else { return };
    check_steps(ctx);
}

#[test]
fn matches_the_cpu_adam_in_chunks_past_the_binding_limit() {
    // 1 KiB bindings hold 256 values: the 1000-value group runs in four chunks.
    let Some(ctx) = gpu_with(GpuOptions {
        max_binding_bytes: Some(1024),
        ..GpuOptions::default()
    }) else {
        return;
    };
    check_steps(&ctx);
}

#[test]
fn matches_the_cpu_adam_with_parameter_blocks_bound_either_way() {
    // Uniforms (hardware adapters) and read-only storage (software ones), in chunks.
    for ctx in gpu_per_parameter_binding(GpuOptions {
        max_binding_bytes: Some(1024),
        ..GpuOptions::default()
    }) {
        check_steps(&ctx);
    }
}

/// Ten Adam steps on both devices with a frozen group, both schedules and zero gradients.
fn check_steps(ctx: &GpuContext) {
    let groups = vec![
        GroupConfig::new(
            "means",
            LrSchedule::Exponential {
                start: 1.6e-4,
                end: 1.6e-6,
                steps: 7,
            },
        ),
        GroupConfig::frozen("scales"),
        GroupConfig::new("colours", LrSchedule::Constant(0.0025)),
    ];
    // More than one workgroup of 256 in the first group.
    let lens = [1000usize, 30, 77];
    let hyper = AdamHyper::default();
    let mut cpu = Adam::new(groups.clone(), &lens, hyper);
    let mut gpu_adam = GpuAdam::new(ctx, groups, &lens, hyper).expect("moments");
    let mut params: Vec<Vec<f32>> = lens
        .iter()
        .enumerate()
        .map(|(i, &n)| f32s(weights(100 + i as u64, n)))
        .collect();
    let buffers: Vec<gs_wgpu::Buffer> = params
        .iter()
        .map(|p| gs_wgpu::upload_f32(ctx, p).expect("upload"))
        .collect();
    for step in 0..10u64 {
        let grads: Vec<Vec<f32>> = lens
            .iter()
            .enumerate()
            .map(|(i, &n)| {
                // Zero gradients at some steps and entries, as frozen pixels give.
                let scale = if step == 3 { 0.0 } else { 1.0 + step as f64 };
                f32s(
                    weights(1000 * step + i as u64, n)
                        .iter()
                        .map(|v| v * scale)
                        .collect(),
                )
            })
            .collect();
        let grad_buffers: Vec<gs_wgpu::Buffer> = grads
            .iter()
            .map(|g| gs_wgpu::upload_f32(ctx, g).expect("upload"))
            .collect();
        {
            let mut slices: Vec<&mut [f32]> = params.iter_mut().map(|p| &mut p[..]).collect();
            let grad_slices: Vec<&[f32]> = grads.iter().map(|g| &g[..]).collect();
            cpu.step(&mut slices, &grad_slices);
        }
        let param_refs: Vec<&gs_wgpu::Buffer> = buffers.iter().collect();
        let grad_refs = [Some(&grad_buffers[0]), None, Some(&grad_buffers[2])];
        gpu_adam.step(ctx, &param_refs, &grad_refs).unwrap();
        for (i, (want, buffer)) in params.iter().zip(&buffers).enumerate() {
            let got = gs_wgpu::read_f32(ctx, buffer, want.len());
            for (k, (a, b)) in want.iter().zip(&got).enumerate() {
                assert!(
                    (a - b).abs() <= 1e-7 * a.abs().max(1e-3),
                    "step {step}, group {i}, entry {k}: cpu {a} gpu {b}"
                );
            }
        }
    }
    assert_eq!(gpu_adam.step_count(), cpu.step_count());
    assert!(
        gpu_adam.moments(ctx, 1).is_none(),
        "a frozen group has no moments"
    );
}

#[test]
fn state_saved_on_either_device_restores_on_the_other() {
    let Some(ctx) = gpu() else { return };
    let groups = vec![
        GroupConfig::new("means", LrSchedule::Constant(0.01)),
        GroupConfig::frozen("scales"),
        GroupConfig::new("colours", LrSchedule::Constant(0.0025)),
        GroupConfig::new("empty", LrSchedule::Constant(0.1)),
    ];
    let lens = [300usize, 5, 40, 0];
    let hyper = AdamHyper::default();
    let mut cpu = Adam::new(groups.clone(), &lens, hyper);
    let mut params: Vec<Vec<f32>> = lens.iter().map(|&n| vec![0.5; n]).collect();
    for step in 0..3u64 {
        let grads: Vec<Vec<f32>> = lens
            .iter()
            .enumerate()
            .map(|(i, &n)| f32s(weights(10 * step + i as u64, n)))
            .collect();
        let mut slices: Vec<&mut [f32]> = params.iter_mut().map(|p| &mut p[..]).collect();
        let grad_slices: Vec<&[f32]> = grads.iter().map(|g| &g[..]).collect();
        cpu.step(&mut slices, &grad_slices);
    }
    let cpu_bytes = cpu.save_state();

    let mut on_gpu = GpuAdam::new(ctx, groups.clone(), &lens, hyper).expect("moments");
    on_gpu.restore_state(ctx, &cpu_bytes).unwrap();
    assert_eq!(on_gpu.step_count(), 3);
    assert_eq!(on_gpu.save_state(ctx), cpu_bytes, "cpu -> gpu -> bytes");
    let mut back = Adam::new(groups.clone(), &lens, hyper);
    back.restore_state(&on_gpu.save_state(ctx)).unwrap();
    assert_eq!(back, cpu, "gpu -> cpu");

    let mut other = GpuAdam::new(ctx, groups, &[301, 5, 40, 0], hyper).expect("moments");
    let e = other
        .restore_state(ctx, &cpu_bytes)
        .unwrap_err()
        .to_string();
    assert!(e.contains("means") && e.contains("301"), "{e}");
    assert_eq!(other.step_count(), 0, "a refused state changes nothing");
}
