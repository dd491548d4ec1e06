//! The embedded default scene: a small procedural object (a striped torus around a glossy
//! ball) as 3D Gaussians, and the ring of cameras that look at it.

use std::f64::consts::TAU;

use gs_core::model::View;
use gs_core::sh::C0;
use gs_core::{Camera, GaussianSet};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Radius of the ring the demo cameras sit on, world units.
const CAMERA_DISTANCE: f64 = 3.2;

fn set_colour(g: &mut GaussianSet, i: usize, rgb: [f32; 3]) {
    for c in 0..3 {
        g.sh_dc[3 * i + c] = (rgb[c] - 0.5) / C0 as f32;
    }
}

/// The default scene: 1,800 Gaussians of SH degree 1 (a torus of 1,200 in hue stripes and a
/// ball of 600 whose colour changes with the view direction).
pub fn default_scene() -> GaussianSet {
    let (torus, ball) = (1200usize, 600usize);
    let mut g = GaussianSet::zeros(torus + ball, 1);
    let mut rng = ChaCha8Rng::seed_from_u64(2025);
    for i in 0..torus {
        let u = rng.random_range(0.0..TAU);
        let v = rng.random_range(0.0..TAU);
        let (big, small) = (0.85, 0.22);
        let p = [
            (big + small * v.cos()) * u.cos(),
            small * v.sin(),
            (big + small * v.cos()) * u.sin(),
        ];
        g.means[3 * i..3 * i + 3].copy_from_slice(&p.map(|x| x as f32));
        g.log_scales[3 * i..3 * i + 3].fill((0.045f32).ln());
        g.opacity_logits[i] = 2.5;
        let stripe = ((u / TAU * 8.0).floor() as usize) % 4;
        let rgb = [
            [0.9, 0.25, 0.2],
            [0.95, 0.8, 0.2],
            [0.2, 0.6, 0.9],
            [0.3, 0.8, 0.35],
        ][stripe];
        set_colour(&mut g, i, rgb);
    }
    for j in 0..ball {
        let i = torus + j;
        let z: f64 = rng.random_range(-1.0..1.0);
        let phi = rng.random_range(0.0..TAU);
        let r = 0.45 * (1.0 - z * z).sqrt();
        let p = [r * phi.cos(), 0.45 * z, r * phi.sin()];
        g.means[3 * i..3 * i + 3].copy_from_slice(&p.map(|x| x as f32));
        g.log_scales[3 * i..3 * i + 3].fill((0.06f32).ln());
        g.opacity_logits[i] = 3.0;
        set_colour(&mut g, i, [0.85, 0.85, 0.9]);
        // A degree-1 term on the x basis function (-C1 x): warm seen from +x (viewing direction
        // -x there), bluish seen from -x.
        let rest = &mut g.sh_rest[9 * i..9 * i + 9];
        rest[6..9].copy_from_slice(&[0.5, 0.1, -0.4]);
    }
    g
}

/// `count` cameras on a ring around the scene, slightly above it, looking at its centre.
pub fn ring_views(count: usize, size: u32) -> anyhow::Result<Vec<View>> {
    (0..count)
        .map(|k| {
            let a = k as f64 / count as f64 * TAU;
            let eye = [CAMERA_DISTANCE * a.cos(), -0.9, CAMERA_DISTANCE * a.sin()];
            let cam = Camera::look_at(eye, [0.0; 3], [0.0, -1.0, 0.0], 0.8, size, size)?;
            Ok(View::still(cam))
        })
        .collect()
}

/// `count` Gaussians of SH degree 1 at random in the scene's bounding box, grey and
/// half-transparent, as 3DGS initialises without a point cloud.
pub fn random_init(count: usize, seed: u64) -> GaussianSet {
    let mut g = GaussianSet::zeros(count, 1);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    for i in 0..count {
        for a in 0..3 {
            let half = if a == 1 { 0.5 } else { 1.1 };
            g.means[3 * i + a] = rng.random_range(-half..half);
        }
        g.log_scales[3 * i..3 * i + 3].fill((0.07f32).ln());
        for q in &mut g.quats[4 * i..4 * i + 4] {
            *q = rng.random_range(-1.0..1.0);
        }
        g.opacity_logits[i] = -1.0;
        set_colour(&mut g, i, [0.5, 0.5, 0.5]);
    }
    g
}
