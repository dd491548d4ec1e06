//! The flat-Gaussian transform of MiraGe against f64 central differences: the gradient of a
//! weighted sum of the front-camera render with respect to every stored parameter kind,
//! including in-plane scales clamped at either bound and the held flat axis.

use base_mirage::flat::{add_scale_grads, renderable, FLAT_SCALE};
use base_mirage::mirror::{plane_camera, plane_half_size};
use gs_core::raster::{backward, render, GradMask, OutputGrads};
use gs_core::{Camera, GaussianSet};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const W: u32 = 40;
const H: u32 = 28;

/// Flat Gaussians on the framed plane, some slightly off it, with scales inside and outside
/// the clamp.
fn scene() -> GaussianSet<f64> {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let (hw, hh) = plane_half_size(W, H, 1.0);
    let n = 12;
    let mut g = GaussianSet::<f64>::zeros(n, 1);
    for i in 0..n {
        g.means[3 * i] = rng.random_range(-0.7 * hw..0.7 * hw);
        g.means[3 * i + 1] = rng.random_range(-0.05..0.05);
        g.means[3 * i + 2] = rng.random_range(-0.7 * hh..0.7 * hh);
        g.log_scales[3 * i] = rng.random_range(-3.0..0.0);
        g.log_scales[3 * i + 1] = rng.random_range(-3.5..-2.0);
        g.log_scales[3 * i + 2] = rng.random_range(-3.5..-2.0);
        for q in 0..4 {
            g.quats[4 * i + q] = 1.0 + rng.random_range(-0.3..0.3);
        }
        g.opacity_logits[i] = rng.random_range(-1.0..2.0);
        for v in g.sh_dc[3 * i..3 * i + 3].iter_mut() {
            *v = rng.random_range(-1.0..1.0);
        }
        for v in g.sh_rest[9 * i..9 * i + 9].iter_mut() {
            *v = rng.random_range(-0.3..0.3);
        }
    }
    // Clamped above (scale e^0.4 > 1) and below (e^-19 < 1e-8).
    g.log_scales[4] = 0.4;
    g.log_scales[8] = -19.0;
    g
}

fn weights() -> Vec<f64> {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    (0..(W * H * 3))
        .map(|_| rng.random_range(-1.0..1.0))
        .collect()
}

fn loss(params: &GaussianSet<f64>, camera: &Camera, w: &[f64]) -> f64 {
    let img = render(&renderable(params), camera, [0.1, 0.2, 0.3]).image;
    img.data.iter().zip(w).map(|(a, b)| a * b).sum()
}

#[test]
fn flat_gaussian_gradients_match_central_differences() {
    let camera = plane_camera(W, H, 1.0, false).unwrap();
    let params = scene();
    let w = weights();
    let shown = renderable(&params);
    let rendered = render(&shown, &camera, [0.1, 0.2, 0.3]);
    let grads = backward(
        &shown,
        &camera,
        &rendered,
        &OutputGrads {
            rgb: &w,
            alpha: None,
            depth: None,
        },
        GradMask::ALL,
    )
    .gaussians;
    let mut scale_grads = vec![0.0; params.log_scales.len()];
    add_scale_grads(&params.log_scales, &grads.log_scales, &mut scale_grads);
    let mut analytic = grads.clone();
    analytic.log_scales = scale_grads;

    let eps = 1e-6;
    let mut checked = 0;
    for group in 0..6 {
        let len = params.arrays()[group].len();
        for idx in 0..len {
            let mut plus = params.clone();
            plus.arrays_mut()[group][idx] += eps;
            let mut minus = params.clone();
            minus.arrays_mut()[group][idx] -= eps;
            let fd = (loss(&plus, &camera, &w) - loss(&minus, &camera, &w)) / (2.0 * eps);
            let an = analytic.arrays()[group][idx];
            assert!(
                (fd - an).abs() <= 1e-5 * (1.0 + fd.abs()),
                "group {group} index {idx}: finite difference {fd}, analytic {an}"
            );
            checked += 1;
        }
    }
    assert!(checked > 200);
    // The flat axis and the clamped scales get exactly nothing.
    assert!(analytic.log_scales.iter().step_by(3).all(|&g| g == 0.0));
    assert_eq!((analytic.log_scales[4], analytic.log_scales[8]), (0.0, 0.0));
    assert!(
        grads.log_scales[4] != 0.0 && grads.log_scales[8] != 0.0,
        "the clamped Gaussians are visible, so only the clamp zeroes their gradient"
    );
    assert!(renderable(&params)
        .log_scales
        .iter()
        .step_by(3)
        .all(|&s| s == FLAT_SCALE.ln()));
}
