//! Scenes and helpers shared by gs-core's integration tests.
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

/// The GPU context shared by a test binary: real GPU first, else a software device. Fails with
/// a message naming what to install when there is none: these tests never pass silently.
#[cfg(feature = "wgpu")]
pub fn gpu() -> &'static gs_core::wgpu::GpuContext {
    use gs_core::wgpu::{AdapterChoice, GpuContext};
    static CTX: std::sync::OnceLock<GpuContext> = std::sync::OnceLock::new();
    CTX.get_or_init(|| {
        let ctx = GpuContext::new(AdapterChoice::AllowSoftware)
            .unwrap_or_else(|e| panic!("the wgpu tests need a GPU adapter and found none: {e}"));
        eprintln!("wgpu tests on {}", ctx.describe());
        ctx
    })
}
