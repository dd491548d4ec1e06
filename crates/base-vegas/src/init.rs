//! VeGaS's initialisation of a video's folded Gaussians (`create_from_pcd` of its code):
//! `count` points drawn uniformly on the rectangle of the plane `y = 0` that the front camera
//! frames, with
//! - colours near black as VeGaS draws them: SH DC `u / 255`, `u` uniform in `[0, 1)`;
//! - opacity 0.1;
//! - in-plane scales `sqrt(mean squared distance to the 3 nearest other points)` (the squared
//!   distance clamped below at 1e-7, as `distCUDA2`);
//! - rotation and temporal centre `logit(u)`, log width `ln(0.99 u + 0.01)`, motion polynomial
//!   uniform in `[-1, 1]`;
//! - equal time logits (ones): uniform frame times.

use gs_core::plane_neighbours::random_points_with_log_scales;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::folded::FoldedGaussians;
use crate::frame::{FoldedParams, POLY_LEN};

/// Initial opacity of every Gaussian.
pub const INITIAL_OPACITY: f64 = 0.1;

/// `logit(u)` for `u` uniform in `(0, 1)`, kept a millionth away from both ends so that it is
/// finite.
fn random_logit(rng: &mut ChaCha8Rng) -> f32 {
    let u: f64 = rng.random_range(1e-6..1.0 - 1e-6);
    (u / (1.0 - u)).ln() as f32
}

/// `count` folded Gaussians on the rectangle `[-half_width, half_width] x [-half_height,
/// half_height]` of the plane `y = 0` (x across, z up) for a video of `frames` frames, drawn
/// from `seed`.
pub fn initial_model(
    count: usize,
    frames: usize,
    half_width: f64,
    half_height: f64,
    seed: u64,
) -> FoldedGaussians {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let points = random_points_with_log_scales(count, half_width, half_height, &mut rng);
    let opacity = (INITIAL_OPACITY / (1.0 - INITIAL_OPACITY)).ln() as f32;
    let mut p = FoldedParams::with_capacity(count);
    for (point, log_scale) in points {
        p.xyz.extend([point[0] as f32, 0.0, point[1] as f32]);
        p.log_scales.extend([log_scale as f32; 2]);
        p.opacity_logits.push(opacity);
        p.rotation.push(random_logit(&mut rng));
        p.m.push(random_logit(&mut rng));
        p.sigma
            .push((0.99 * rng.random_range(0.0..1.0f64) + 0.01).ln() as f32);
        p.w.extend((0..POLY_LEN).map(|_| rng.random_range(-1.0..=1.0f32)));
        p.sh_dc
            .extend((0..3).map(|_| rng.random_range(0.0..1.0f32) / 255.0));
    }
    FoldedGaussians::new(p, vec![1.0; frames.saturating_sub(1)])
        .expect("the arrays are built to the Gaussian count")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn initial_gaussians_are_drawn_as_vegas_draws_them() {
        let model = initial_model(1500, 6, 0.4, 0.25, 3);
        let p = model.params();
        assert_eq!((p.len(), model.frames()), (1500, 6));
        assert_eq!(model.time_logits(), &[1.0; 5]);
        for i in 0..p.len() {
            assert!(p.xyz[3 * i].abs() <= 0.4 && p.xyz[3 * i + 1] == 0.0);
            assert!(p.xyz[3 * i + 2].abs() <= 0.25);
            assert_eq!(p.log_scales[2 * i], p.log_scales[2 * i + 1]);
            assert!(p.rotation[i].is_finite() && p.m[i].is_finite());
            let width = p.sigma[i].exp();
            assert!((0.01..=1.0).contains(&width), "width {width}");
            assert!(p.w[POLY_LEN * i..POLY_LEN * (i + 1)]
                .iter()
                .all(|w| w.abs() <= 1.0));
            let opacity = 1.0 / (1.0 + (-p.opacity_logits[i]).exp());
            assert!((opacity - 0.1).abs() < 1e-6);
        }
        assert_eq!(initial_model(1500, 6, 0.4, 0.25, 3), model, "seeded");
        assert_ne!(initial_model(1500, 6, 0.4, 0.25, 4), model);
    }
}
