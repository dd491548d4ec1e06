//! Scenes and helpers shared by gs-core's integration tests and gs-wgpu's (which include this
//! file by path).
#![allow(dead_code)]

use gs_core::{Camera, GaussianSet, Real};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A camera at distance 4 on the -z side of the origin, looking at it, x right, y down.
pub fn front_camera(width: u32, height: u32) -> Camera {
    Camera::look_at(
        [0.0, 0.0, -4.0],
        [0.0; 3],
        [0.0, -1.0, 0.0],
        0.8,
        width,
        height,
    )
    .unwrap()
}

/// An oblique camera, so no world axis lines up with an image axis.
pub fn oblique_camera(width: u32, height: u32) -> Camera {
    Camera::look_at(
        [2.5, -1.5, -3.0],
        [0.1, 0.0, 0.2],
        [0.0, -1.0, 0.2],
        0.9,
        width,
        height,
    )
    .unwrap()
}

/// `count` square views of `size` pixels on a ring of radius 3.5 around the origin, a little
/// above it, looking at it (the fitting tests' cameras).
pub fn ring_views(count: usize, size: u32) -> Vec<gs_core::model::View> {
    (0..count)
        .map(|i| {
            let a = i as f64 / count as f64 * std::f64::consts::TAU;
            let eye = [3.5 * a.cos(), -0.8, 3.5 * a.sin()];
            let camera = Camera::look_at(eye, [0.0; 3], [0.0, -1.0, 0.0], 0.9, size, size);
            gs_core::model::View::still(camera.unwrap())
        })
        .collect()
}

/// `n` random Gaussians of SH degree `degree` around the origin, sized to cover a few tiles of
/// a small image.
pub fn random_scene<T: Real>(seed: u64, n: usize, degree: usize) -> GaussianSet<T> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut g = GaussianSet::<f64>::zeros(n, degree);
    for v in &mut g.means {
        *v = rng.random_range(-0.8..0.8);
    }
    for v in &mut g.log_scales {
        *v = rng.random_range(-2.6..-1.2);
    }
    for v in &mut g.quats {
        *v = rng.random_range(-1.0..1.0);
    }
    for v in &mut g.opacity_logits {
        *v = rng.random_range(-1.5..2.0);
    }
    for v in &mut g.sh_dc {
        *v = rng.random_range(-1.2..1.2);
    }
    for v in &mut g.sh_rest {
        *v = rng.random_range(-0.4..0.4);
    }
    g.cast()
}

/// Fixed random weights in [-1, 1].
pub fn weights(seed: u64, n: usize) -> Vec<f64> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n).map(|_| rng.random_range(-1.0..1.0)).collect()
}

/// True when every value is finite.
pub fn all_finite<T: Real>(v: &[T]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// The GPU context shared by a test binary: real GPU first, else a software device. `None`
/// (the test says it was skipped, and passes) where there is no adapter, unless
/// `CLIPGAUSSIAN_REQUIRE_GPU_TESTS=1` (`.ci/run`), where it fails naming what to install.
pub fn gpu() -> Option<&'static gs_wgpu::GpuContext> {
    use gs_wgpu::{test_context, GpuContext, GpuOptions};
    static CTX: std::sync::OnceLock<GpuContext> = std::sync::OnceLock::new();
    if let Some(ctx) = CTX.get() {
        return Some(ctx);
    }
    let ctx = test_context(GpuOptions::default())?;
    eprintln!("wgpu tests on {}", ctx.describe());
    Some(CTX.get_or_init(|| ctx))
}

/// A GPU context of its own with `options` (real GPU first, else a software device), for the
/// tests of the fallbacks; `None` as [`gpu`] where there is no adapter.
pub fn gpu_with(options: gs_wgpu::GpuOptions) -> Option<gs_wgpu::GpuContext> {
    gs_wgpu::test_context(options)
}

/// A GPU context of its own for each way of binding parameter blocks (uniforms, as hardware
/// adapters do; read-only storage, as software ones do), with `options` otherwise; none where
/// there is no adapter (as [`gpu`]).
pub fn gpu_per_parameter_binding(options: gs_wgpu::GpuOptions) -> Vec<gs_wgpu::GpuContext> {
    use gs_wgpu::ParameterBinding;
    [ParameterBinding::Uniform, ParameterBinding::Storage]
        .into_iter()
        .map_while(|binding| {
            let ctx = gpu_with(gs_wgpu::GpuOptions {
                parameter_binding: Some(binding),
                ..options
            })?;
            assert_eq!(ctx.parameter_binding(), binding);
            Some(ctx)
        })
        .collect()
}

/// The learning rates of the fitting tests.
pub fn fit_lrs() -> gs_core::model::GaussianLrs {
    gs_core::model::GaussianLrs {
        means: gs_core::adam::LrSchedule::Constant(0.004),
        scales: 0.01,
        rotations: 0.01,
        opacities: 0.05,
        feature: 0.05,
    }
}

/// The binding limit, bytes, under which the split-array tests run: sixteen times smaller
/// than a 1 MiB binding, so that a few thousand Gaussians of degree 3 run in 256-Gaussian
/// chunks and their splats in parts of 1024.
pub const SMALL_BINDING: u64 = 64 * 1024;

/// One degenerate Gaussian (index 0, after `edit`) in front of a normal one, the scenes of the
/// degenerate-case tests.
pub fn degenerate_scene(edit: impl Fn(&mut GaussianSet<f64>)) -> GaussianSet<f64> {
    let mut g = random_scene::<f64>(42, 2, 2);
    g.means[3..6].copy_from_slice(&[0.1, -0.1, 0.6]);
    g.log_scales[3..6].copy_from_slice(&[-1.0, -1.2, -1.1]);
    g.opacity_logits[1] = 0.5;
    g.means[0..3].copy_from_slice(&[-0.05, 0.05, 0.0]);
    edit(&mut g);
    g
}

/// The degenerate cases a rasterizer must survive, seen by [`front_camera`], named: near-zero
/// and huge scales, behind the camera, straddling the near plane, opacity near 0 and near 1,
/// equal depths, a centre past the Jacobian clamp.
pub fn degenerate_cases() -> Vec<(&'static str, GaussianSet<f64>)> {
    vec![
        (
            "near-zero scales",
            degenerate_scene(|g| g.log_scales[0..3].copy_from_slice(&[-18.0, -19.0, -20.0])),
        ),
        (
            "huge scales",
            degenerate_scene(|g| g.log_scales[0..3].copy_from_slice(&[2.5, 2.0, 3.0])),
        ),
        (
            "behind the camera",
            degenerate_scene(|g| g.means[0..3].copy_from_slice(&[0.0, 0.0, -6.0])),
        ),
        (
            "straddling the near plane",
            degenerate_scene(|g| {
                g.means[0..3].copy_from_slice(&[0.01, 0.02, -3.75]);
                g.log_scales[0..3].copy_from_slice(&[-1.2, -1.5, -1.2]);
            }),
        ),
        (
            "opacity near zero",
            degenerate_scene(|g| g.opacity_logits[0] = -5.3),
        ),
        (
            "opacity near one",
            degenerate_scene(|g| g.opacity_logits[0] = 9.0),
        ),
        (
            "overlapping at equal depth",
            degenerate_scene(|g| {
                g.means[0..3].copy_from_slice(&[0.05, 0.0, 0.3]);
                g.means[3..6].copy_from_slice(&[-0.05, 0.02, 0.3]);
            }),
        ),
        (
            "centre outside the Jacobian clamp",
            degenerate_scene(|g| {
                g.means[0..3].copy_from_slice(&[2.8, 0.1, 0.0]);
                g.log_scales[0..3].copy_from_slice(&[0.4, 0.3, 0.2]);
            }),
        ),
    ]
}

/// A Gaussian flat along world x and the camera that sees it edge-on (along x): only eps2d
/// keeps its 2D covariance invertible.
pub fn edge_on_flat() -> (GaussianSet<f64>, Camera) {
    let flat = degenerate_scene(|g| {
        g.log_scales[0..3].copy_from_slice(&[-1.0, -1.0, -17.0]);
        g.quats[0..4].copy_from_slice(&[1.0, 0.0, 1.0, 0.0]);
    });
    let side = Camera::look_at([-4.0, 0.0, 0.3], [0.0; 3], [0.0, -1.0, 0.0], 0.8, 24, 24)
        .expect("a valid camera");
    (flat, side)
}

/// Five opaque Gaussians stacked in depth, so pixels behind the first few stop early.
pub fn stacked_scene() -> GaussianSet {
    let mut g = random_scene::<f32>(5, 5, 1);
    for i in 0..5 {
        g.means[3 * i..3 * i + 3].copy_from_slice(&[
            0.02 * i as f32,
            -0.01 * i as f32,
            0.2 * i as f32,
        ]);
        g.log_scales[3 * i..3 * i + 3].copy_from_slice(&[-1.1, -1.2, -1.0]);
        g.opacity_logits[i] = 3.0;
    }
    g
}

/// 21 Gaussians of SH degree 3, some with NaN, infinite, zero-quaternion or overflowing
/// parameters, which must be culled and get zero gradient.
pub fn poisoned_scene() -> GaussianSet {
    let mut g = random_scene::<f32>(21, 12, 3);
    g.means[0] = f32::NAN;
    g.log_scales[3] = f32::INFINITY;
    g.quats[8..12].fill(0.0);
    g.opacity_logits[3] = f32::NEG_INFINITY;
    g.sh_rest[4 * 45] = f32::NAN;
    g.means[15..18].copy_from_slice(&[1e30, -1e30, 1e30]);
    g.log_scales[18..21].fill(100.0);
    g.log_scales[21..24].fill(-100.0);
    g.opacity_logits[8] = 1e30;
    g.opacity_logits[9] = -1e30;
    g
}

/// Writes the `transforms_train.json` of a NeRF-synthetic scene of one frame, `./r_0` (its
/// picture, `r_0.png`, is the caller's), seen from 4 units along +z with a horizontal field of
/// view of 0.7 rad.
pub fn write_one_frame_transforms(root: &std::path::Path) {
    let json = serde_json::json!({
        "camera_angle_x": 0.7,
        "frames": [{"file_path": "./r_0",
                    "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]}]
    });
    std::fs::write(root.join("transforms_train.json"), json.to_string()).unwrap();
}
