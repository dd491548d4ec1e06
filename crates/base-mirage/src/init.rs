//! MiraGe's initialisation of a picture's Gaussians: `count` points drawn uniformly on the
//! rectangle of the plane `y = 0` that the front camera frames, with
//! - colours near mid-grey: SH DC `u / 255`, `u` uniform in `[0, 1)` per channel, higher SH
//!   degrees zero;
//! - opacity 0.1;
//! - in-plane scales `sqrt(mean squared distance to the 3 nearest other points)` (the
//!   squared distance clamped below at 1e-7, as 3DGS's `distCUDA2` is), the flat axis at 1e-8;
//! - the quaternion `(1, 1, 1, 1)` (normalized when used: a 120° turn about `(1, 1, 1)` that
//!   lays the flat axis along `y`, so the discs face both cameras).

use gs_core::plane_neighbours::random_points_with_log_scales;
use gs_core::GaussianSet;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::flat::{FlatGaussians, FLAT_SCALE};

/// Initial opacity of every Gaussian.
pub const INITIAL_OPACITY: f64 = 0.1;

/// `count` Gaussians of SH degree `sh_degree` on the rectangle `[-half_width, half_width] x
/// [-half_height, half_height]` of the plane `y = 0` (x across, z up), drawn from `seed`.
pub fn initial_gaussians(
    count: usize,
    sh_degree: usize,
    half_width: f64,
    half_height: f64,
    seed: u64,
) -> FlatGaussians {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let points = random_points_with_log_scales(count, half_width, half_height, &mut rng);
    let mut set = GaussianSet::zeros(count, sh_degree);
    let logit = (INITIAL_OPACITY / (1.0 - INITIAL_OPACITY)).ln() as f32;
    for (i, (p, log_scale)) in points.iter().enumerate() {
        set.means[3 * i..3 * i + 3].copy_from_slice(&[p[0] as f32, 0.0, p[1] as f32]);
        let log_scale = *log_scale as f32;
        set.log_scales[3 * i..3 * i + 3].copy_from_slice(&[
            FLAT_SCALE.ln() as f32,
            log_scale,
            log_scale,
        ]);
        set.quats[4 * i..4 * i + 4].fill(1.0);
        set.opacity_logits[i] = logit;
        for c in 0..3 {
            set.sh_dc[3 * i + c] = rng.random_range(0.0..1.0f32) / 255.0;
        }
    }
    FlatGaussians::new(set)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn initial_gaussians_lie_on_the_framed_rectangle_as_mirage_sets_them() {
        let model = initial_gaussians(2000, 3, 0.4, 0.25, 1);
        let set = model.params();
        assert_eq!((set.len(), set.sh_degree()), (2000, 3));
        for i in 0..set.len() {
            let m = &set.means[3 * i..3 * i + 3];
            assert!(m[0].abs() <= 0.4 && m[1] == 0.0 && m[2].abs() <= 0.25);
            let s = &set.log_scales[3 * i..3 * i + 3];
            assert_eq!(s[0], FLAT_SCALE.ln() as f32);
            assert_eq!(s[1], s[2]);
            assert!(s[1] < (0.05f32).ln(), "2000 points on 0.8 x 0.5 are close");
            assert_eq!(&set.quats[4 * i..4 * i + 4], &[1.0; 4]);
            let opacity = 1.0 / (1.0 + (-set.opacity_logits[i]).exp());
            assert!((opacity - 0.1).abs() < 1e-6);
            assert!(set.sh_dc[3 * i..3 * i + 3]
                .iter()
                .all(|&c| (0.0..1.0 / 255.0).contains(&c)));
        }
        assert!(set.sh_rest.iter().all(|&c| c == 0.0));
        assert_eq!(initial_gaussians(2000, 3, 0.4, 0.25, 1), model, "seeded");
    }
}
