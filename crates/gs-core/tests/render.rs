//! Hand-built scenes with known answers, f32 against the f64 reference, and robustness to
//! degenerate and non-finite inputs.

mod common;

use common::{all_finite, oblique_camera, random_scene, weights};
use gs_core::raster::{backward, render, GradMask, OutputGrads};
use gs_core::sh::C0;
use gs_core::{Camera, GaussianSet};

const IDENTITY: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// 33x33 camera at z = -4 looking along +z; the origin lands on the centre of pixel (16, 16).
fn centred_camera() -> Camera {
    Camera::new(IDENTITY, [0.0, 0.0, 4.0], [40.0, 40.0, 16.5, 16.5], 33, 33).unwrap()
}

/// One Gaussian at `mean` of isotropic scale `scale`, opacity logit `logit` and colour `rgb`.
fn single(mean: [f32; 3], scale: f32, logit: f32, rgb: [f32; 3]) -> GaussianSet {
    let mut g = GaussianSet::zeros(1, 0);
    g.means.copy_from_slice(&mean);
    g.log_scales.fill(scale.ln());
    g.opacity_logits[0] = logit;
    for c in 0..3 {
        g.sh_dc[c] = (rgb[c] - 0.5) / C0 as f32;
    }
    g
}

fn concat(a: &GaussianSet, b: &GaussianSet) -> GaussianSet {
    let mut g = GaussianSet::zeros(a.len() + b.len(), a.sh_degree());
    for ((dst, x), y) in g.arrays_mut().into_iter().zip(a.arrays()).zip(b.arrays()) {
        *dst = x.iter().chain(y.iter()).copied().collect();
    }
    g
}

#[test]
fn isotropic_gaussian_peak_and_fall_off() {
    // Scale 0.1 at depth 4 with focal 40 is one pixel of standard deviation; eps2d adds 0.3.
    let g = single([0.0; 3], 0.1, 0.0, [0.8, 0.4, 0.2]);
    let r = render(&g, &centred_camera(), [0.0; 3]);
    let var = 1.0f64 + 0.3;
    for k in 0..=3u32 {
        let alpha = 0.5 * (-0.5 * (k * k) as f64 / var).exp();
        let px = r.image.pixel(16 + k, 16);
        for (c, want) in [0.8, 0.4, 0.2].iter().enumerate() {
            assert!(
                (px[c] as f64 - want * alpha).abs() < 1e-6,
                "k={k} c={c}: {px:?}"
            );
        }
        let a = r.alpha[16 * 33 + 16 + k as usize] as f64;
        assert!((a - alpha).abs() < 1e-6, "alpha at k={k}");
        let d = r.depth[16 * 33 + 16 + k as usize] as f64;
        assert!((d - 4.0 * alpha).abs() < 1e-5, "depth at k={k}");
    }
    // Diagonal neighbour: sigma = (1 + 1) / 2 / var.
    let diag = 0.5 * (-1.0 / var).exp() * 0.8;
    assert!((r.image.pixel(17, 17)[0] as f64 - diag).abs() < 1e-6);
    // Four pixels out, alpha is below 1/255: skipped, exactly background.
    assert_eq!(r.image.pixel(20, 16), [0.0; 3]);
    assert_eq!(r.image.pixel(0, 0), [0.0; 3]);
}

#[test]
fn nearer_gaussian_occludes_the_farther_one_whatever_the_order() {
    let logit = 9f32.ln(); // opacity 0.9
    let red = single([0.0, 0.0, -1.0], 0.5, logit, [1.0, 0.0, 0.0]);
    let blue = single([0.0, 0.0, 1.0], 0.5, logit, [0.0, 0.0, 1.0]);
    for g in [concat(&red, &blue), concat(&blue, &red)] {
        let r = render(&g, &centred_camera(), [0.0, 1.0, 0.0]);
        let px = r.image.pixel(16, 16);
        // Red takes 0.9, blue 0.9 of the remaining 0.1, the green background the last 0.01.
        assert!((px[0] - 0.9).abs() < 1e-5, "{px:?}");
        assert!((px[2] - 0.09).abs() < 1e-5, "{px:?}");
        assert!((px[1] - 0.01).abs() < 1e-5, "{px:?}");
    }
}

#[test]
fn gaussian_behind_the_camera_draws_nothing() {
    let g = single([0.0, 0.0, -6.0], 0.5, 5.0, [1.0, 1.0, 1.0]);
    let r = render(&g, &centred_camera(), [0.25, 0.5, 0.75]);
    assert_eq!(r.visible_count(), 0);
    assert!(r.image.data.chunks(3).all(|p| p == [0.25, 0.5, 0.75]));
    assert!(r.alpha.iter().all(|a| *a == 0.0));
}

#[test]
fn empty_set_renders_the_exact_background() {
    let g = GaussianSet::zeros(0, 3);
    let cam = centred_camera();
    let r = render(&g, &cam, [0.1, 0.2, 0.3]);
    assert!(r.image.data.chunks(3).all(|p| p == [0.1, 0.2, 0.3]));
    let grad = vec![1.0f32; 3 * cam.pixel_count()];
    let gr = backward(
        &g,
        &cam,
        &r,
        &OutputGrads {
            rgb: &grad,
            alpha: None,
            depth: None,
        },
        GradMask::ALL,
    );
    // Every pixel shows the background fully: dL/dbg = number of pixels per channel.
    assert_eq!(gr.background, [cam.pixel_count() as f32; 3]);
}

#[test]
fn f32_render_and_gradients_match_the_f64_reference() {
    let g64 = random_scene::<f64>(77, 40, 3);
    let g32: GaussianSet = g64.cast();
    let cam = oblique_camera(64, 48);
    let r64 = render(&g64, &cam, [0.3, 0.3, 0.3]);
    let r32 = render(&g32, &cam, [0.3, 0.3, 0.3]);
    let max_err = r64
        .image
        .data
        .iter()
        .zip(&r32.image.data)
        .fold(0.0f64, |m, (a, b)| m.max((a - *b as f64).abs()));
    assert!(max_err < 1e-4, "image error {max_err}");
    let w = weights(5, 3 * cam.pixel_count());
    let w32: Vec<f32> = w.iter().map(|v| *v as f32).collect();
    let out64 = OutputGrads {
        rgb: &w,
        alpha: None,
        depth: None,
    };
    let out32 = OutputGrads {
        rgb: &w32,
        alpha: None,
        depth: None,
    };
    let g64b = backward(&g64, &cam, &r64, &out64, GradMask::ALL);
    let g32b = backward(&g32, &cam, &r32, &out32, GradMask::ALL);
    for (name, (a, b)) in gs_core::gaussians::PARAM_NAMES
        .iter()
        .zip(g64b.gaussians.arrays().iter().zip(g32b.gaussians.arrays()))
    {
        let norm = a.iter().map(|v| v * v).sum::<f64>().sqrt();
        let diff = a
            .iter()
            .zip(b.iter())
            .map(|(x, y)| (x - *y as f64).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(norm > 0.0 && diff / norm < 1e-3, "{name}: {diff} / {norm}");
    }
}

#[test]
fn the_rgb_only_backward_is_the_backward_with_zero_alpha_and_depth_gradients_bit_for_bit() {
    // The compositing backward leaves the alpha and depth terms out when neither gradient is
    // given (training); with zeros given it runs them. Both must give the same sums.
    for (seed, n, (w, h)) in [(31, 25, (40, 30)), (32, 60, (47, 33)), (33, 8, (17, 64))] {
        let g = random_scene::<f32>(seed, n, 2);
        let cam = oblique_camera(w, h);
        let r = render(&g, &cam, [0.2, 0.4, 0.6]);
        assert!(
            r.visible_count() > n / 2,
            "seed {seed}: {} visible",
            r.visible_count()
        );
        let rgb: Vec<f32> = weights(seed + 100, 3 * cam.pixel_count())
            .iter()
            .map(|v| *v as f32)
            .collect();
        let zeros = vec![0f32; cam.pixel_count()];
        let rgb_only = OutputGrads {
            rgb: &rgb,
            alpha: None,
            depth: None,
        };
        let with_zeros = OutputGrads {
            rgb: &rgb,
            alpha: Some(&zeros),
            depth: Some(&zeros),
        };
        let a = backward(&g, &cam, &r, &rgb_only, GradMask::ALL);
        let b = backward(&g, &cam, &r, &with_zeros, GradMask::ALL);
        for (name, (x, y)) in gs_core::gaussians::PARAM_NAMES
            .iter()
            .zip(a.gaussians.arrays().iter().zip(b.gaussians.arrays()))
        {
            assert!(
                x.iter().any(|v| *v != 0.0),
                "seed {seed}: no {name} gradient"
            );
            for (i, (u, v)) in x.iter().zip(y.iter()).enumerate() {
                assert_eq!(
                    u.to_bits(),
                    v.to_bits(),
                    "seed {seed}, {name}[{i}]: {u} vs {v}"
                );
            }
        }
        assert_eq!(a.background, b.background, "seed {seed}");
    }
}

#[test]
fn frozen_groups_get_zero_gradient_and_the_rest_is_unchanged() {
    let g = random_scene::<f32>(8, 20, 2);
    let cam = oblique_camera(40, 30);
    let r = render(&g, &cam, [0.0; 3]);
    let w: Vec<f32> = weights(9, 3 * cam.pixel_count())
        .iter()
        .map(|v| *v as f32)
        .collect();
    let out = OutputGrads {
        rgb: &w,
        alpha: None,
        depth: None,
    };
    let all = backward(&g, &cam, &r, &out, GradMask::ALL);
    let colours = backward(&g, &cam, &r, &out, GradMask::COLORS);
    assert!(colours.gaussians.means.iter().all(|v| *v == 0.0));
    assert!(colours.gaussians.log_scales.iter().all(|v| *v == 0.0));
    assert!(colours.gaussians.quats.iter().all(|v| *v == 0.0));
    assert!(colours.gaussians.opacity_logits.iter().all(|v| *v == 0.0));
    assert_eq!(colours.gaussians.sh_dc, all.gaussians.sh_dc);
    assert_eq!(colours.gaussians.sh_rest, all.gaussians.sh_rest);
    assert!(all.gaussians.means.iter().any(|v| *v != 0.0));
}

#[test]
fn non_finite_and_extreme_parameters_are_culled_without_nan() {
    let mut g = random_scene::<f32>(21, 12, 3);
    g.means[0] = f32::NAN; // 0: NaN mean
    g.log_scales[3] = f32::INFINITY; // 1: infinite scale
    g.quats[8..12].fill(0.0); // 2: zero quaternion
    g.opacity_logits[3] = f32::NEG_INFINITY; // 3: infinite logit
    g.sh_rest[4 * 45] = f32::NAN; // 4: NaN colour
    g.means[15..18].copy_from_slice(&[1e30, -1e30, 1e30]); // 5: far away
    g.log_scales[18..21].fill(100.0); // 6: exp overflows f32
    g.log_scales[21..24].fill(-100.0); // 7: scale underflows to 0
    g.opacity_logits[8] = 1e30; // 8: opacity exactly 1
    g.opacity_logits[9] = -1e30; // 9: opacity exactly 0
    let cam = oblique_camera(48, 40);
    let r = render(&g, &cam, [0.5; 3]);
    assert!(all_finite(&r.image.data) && all_finite(&r.alpha) && all_finite(&r.depth));
    // Gaussians 0-6 are culled; at most the other five are drawn.
    assert!(r.visible_count() <= 5, "{} visible", r.visible_count());
    let w: Vec<f32> = weights(3, 3 * cam.pixel_count())
        .iter()
        .map(|v| *v as f32)
        .collect();
    let a: Vec<f32> = weights(4, cam.pixel_count())
        .iter()
        .map(|v| *v as f32)
        .collect();
    let grads = backward(
        &g,
        &cam,
        &r,
        &OutputGrads {
            rgb: &w,
            alpha: Some(&a),
            depth: Some(&a),
        },
        GradMask::ALL,
    );
    for arr in grads.gaussians.arrays() {
        assert!(all_finite(arr));
    }
    assert!(grads.background.iter().all(|v| v.is_finite()));
    for i in 0..5 {
        assert_eq!(
            grads.gaussians.means[3 * i..3 * i + 3],
            [0.0; 3],
            "gaussian {i}"
        );
        assert_eq!(grads.gaussians.opacity_logits[i], 0.0, "gaussian {i}");
    }
}
