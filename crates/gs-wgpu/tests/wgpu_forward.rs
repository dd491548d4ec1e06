//! The wgpu backend's forward pass against the cpu backend, on random scenes of every SH degree
//! and on each degenerate case of docs/conventions.md. Needs a GPU adapter (lavapipe in CI):
//! without one these tests fail, naming what to install.

/// The scenes and GPU contexts of gs-core's rasterizer tests, shared with them.
#[path = "../../gs-core/tests/common/mod.rs"]
mod common;

use common::{
    degenerate_cases, edge_on_flat, front_camera, gpu, gpu_per_parameter_binding, gpu_with,
    oblique_camera, poisoned_scene, random_scene, stacked_scene, SMALL_BINDING,
};
use gs_core::raster::render;
use gs_core::{Camera, GaussianSet};
use gs_wgpu::{self as gpu_backend, GpuContext, GpuError, GpuGaussians, GpuOptions};

/// Renders `case` on both backends and checks that the image, alpha and depth agree.
fn check(case: &str, g: &GaussianSet, cam: &Camera, background: [f32; 3], ctx: &GpuContext) {
    let cpu = render(g, cam, background);
    let gg = GpuGaussians::upload(ctx, g).expect("upload");
    let r = gpu_backend::render(ctx, &gg, cam, background).expect("render");
    assert!(
        r.intersection_count() >= cpu.intersection_count(),
        "the GPU lists {} tile pairs, fewer than the cpu backend's {}",
        r.intersection_count(),
        cpu.intersection_count()
    );
    let pairs = [
        ("image", cpu.image.data.clone(), r.image(ctx).data),
        ("alpha", cpu.alpha.clone(), r.alpha(ctx)),
        ("depth", cpu.depth.clone(), r.depth(ctx)),
    ];
    for (name, want, got) in pairs {
        assert_eq!(want.len(), got.len(), "{name} size");
        let (mut worst, mut at) = (0.0f32, 0);
        for (i, (a, b)) in want.iter().zip(&got).enumerate() {
            let scale = if name == "depth" { 1.0 + a.abs() } else { 1.0 };
            let d = (a - b).abs() / scale;
            if !(d <= worst) {
                worst = d;
                at = i;
            }
        }
        assert!(
            worst < 1e-5,
            "{case}, {name}: worst difference {worst:e} at {at}: cpu {} gpu {}",
            want[at],
            got[at]
        );
    }
}

#[test]
fn random_scenes_every_degree() {
    let Some(ctx) = gpu() else { return };
    for degree in 0..=3 {
        let g = random_scene::<f32>(70 + degree as u64, 60, degree);
        let case = format!("degree {degree}");
        check(&case, &g, &oblique_camera(64, 48), [0.3, 0.6, 0.9], ctx);
        check(&case, &g, &front_camera(50, 37), [0.0; 3], ctx);
    }
}

#[test]
fn many_gaussians_span_several_sort_and_prefix_sum_blocks() {
    // 3000 Gaussians and their tile pairs exceed one 1024-item block of every GPU pass.
    let Some(ctx) = gpu() else { return };
    let mut g = random_scene::<f32>(5, 3000, 1);
    for v in &mut g.log_scales {
        *v -= 1.0;
    }
    check(
        "3000 Gaussians",
        &g,
        &oblique_camera(160, 120),
        [1.0; 3],
        ctx,
    );
}

#[test]
fn dispatches_split_past_the_workgroup_limit() {
    // With at most 3 workgroups per dimension, every per-item dispatch is split over y.
    let Some(ctx) = gpu_with(GpuOptions {
        max_workgroups_per_dimension: Some(3),
        ..GpuOptions::default()
    }) else {
        return;
    };
    let g = random_scene::<f32>(6, 2500, 2);
    check(
        "split dispatches",
        &g,
        &oblique_camera(40, 40),
        [0.2; 3],
        &ctx,
    );
}

#[test]
fn arrays_past_the_binding_limit_are_bound_in_chunks_and_parts() {
    // Under a 64 KiB binding limit, 3000 Gaussians of degree 3 (180 bytes of sh_rest each)
    // project in 12 chunks of 256, and their splats (64 bytes each) are bound as 3 parts of
    // 1024: as 5M Gaussians are on an adapter whose bindings hold 128 MiB.
    let Some(ctx) = gpu_with(GpuOptions {
        max_binding_bytes: Some(SMALL_BINDING),
        ..GpuOptions::default()
    }) else {
        return;
    };
    let mut g = random_scene::<f32>(9, 3000, 3);
    for v in &mut g.log_scales {
        *v -= 1.0;
    }
    check("split arrays", &g, &oblique_camera(64, 48), [0.1; 3], &ctx);
}

#[test]
fn parameter_blocks_bound_either_way_render_as_the_cpu() {
    // Hardware adapters bind the view, pass and chunk blocks as uniforms, software ones
    // (lavapipe in CI) as read-only storage: both are checked on whichever adapter runs this,
    // in chunks and parts as in the test above.
    for ctx in gpu_per_parameter_binding(GpuOptions {
        max_binding_bytes: Some(SMALL_BINDING),
        ..GpuOptions::default()
    }) {
        let binding = ctx.parameter_binding();
        let mut g = random_scene::<f32>(19, 3000, 3);
        for v in &mut g.log_scales {
            *v -= 1.0;
        }
        check(
            &format!("{binding:?}"),
            &g,
            &oblique_camera(64, 48),
            [0.4; 3],
            &ctx,
        );
    }
}

#[test]
fn a_scene_past_every_part_is_refused_naming_its_splats() {
    // 16 KiB bindings hold 256 splats: four parts hold 1024, not 1100.
    let Some(ctx) = gpu_with(GpuOptions {
        max_binding_bytes: Some(16 * 1024),
        ..GpuOptions::default()
    }) else {
        return;
    };
    let g = random_scene::<f32>(10, 1100, 0);
    let gg = GpuGaussians::upload(&ctx, &g).expect("upload");
    match gpu_backend::render(&ctx, &gg, &oblique_camera(16, 16), [0.0; 3]) {
        Err(e @ GpuError::TooLarge { .. }) => {
            let message = e.to_string();
            assert!(
                message.contains("splats of 1100 Gaussians") && message.contains("70400"),
                "{message}"
            );
        }
        Err(e) => panic!("expected a too-large error, got {e}"),
        Ok(_) => panic!("1100 splats rendered through four bindings of 256"),
    }
}

#[test]
fn empty_scene_renders_the_exact_background() {
    let Some(ctx) = gpu() else { return };
    let g = GaussianSet::zeros(0, 3);
    check("empty", &g, &oblique_camera(33, 20), [0.1, 0.2, 0.3], ctx);
}

#[test]
fn degenerate_cases_match_the_cpu() {
    let Some(ctx) = gpu() else { return };
    let cam = front_camera(24, 24);
    for (name, g) in degenerate_cases() {
        let g = g.cast();
        check(name, &g, &cam, [0.2, 0.5, 0.9], ctx);
    }
    // Flat along world x and seen along x: only eps2d keeps its 2D covariance invertible.
    let (flat, side) = edge_on_flat();
    let flat = flat.cast();
    check("flat, seen edge-on", &flat, &side, [0.2, 0.5, 0.9], ctx);
}

#[test]
fn pixels_that_stop_early() {
    let Some(ctx) = gpu() else { return };
    let g = stacked_scene();
    check("stacked", &g, &front_camera(24, 24), [0.0; 3], ctx);
}

#[test]
fn non_finite_and_extreme_parameters_are_culled() {
    let Some(ctx) = gpu() else { return };
    let g = poisoned_scene();
    check("non-finite", &g, &oblique_camera(48, 40), [0.5; 3], ctx);
}
