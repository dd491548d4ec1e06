//! The analytic backward of the rasterizer against f64 central finite differences, for every
//! parameter kind, on random scenes and on each degenerate case of docs/conventions.md.

mod common;

use common::{front_camera, oblique_camera, random_scene, weights};
use gs_core::gaussians::PARAM_NAMES;
use gs_core::raster::{backward, render, GradMask, Gradients, OutputGrads};
use gs_core::{Camera, GaussianSet};

/// The scalar loss `sum(w_rgb * rgb) + sum(w_a * alpha) + sum(w_d * depth)`.
struct Probe {
    rgb: Vec<f64>,
    alpha: Vec<f64>,
    depth: Vec<f64>,
    background: [f64; 3],
}

impl Probe {
    fn new(cam: &Camera, seed: u64) -> Self {
        let n = cam.pixel_count();
        Self {
            rgb: weights(seed, 3 * n),
            alpha: weights(seed + 1, n),
            depth: weights(seed + 2, n).iter().map(|v| 0.1 * v).collect(),
            background: [0.2, 0.5, 0.9],
        }
    }

    /// The analytic gradients of [`Probe::loss`] at `g`.
    fn gradients(&self, g: &GaussianSet<f64>, cam: &Camera) -> Gradients<f64> {
        backward(
            g,
            cam,
            &render(g, cam, self.background),
            &OutputGrads {
                rgb: &self.rgb,
                alpha: Some(&self.alpha),
                depth: Some(&self.depth),
            },
            GradMask::ALL,
        )
    }

    fn loss(&self, g: &GaussianSet<f64>, cam: &Camera, background: [f64; 3]) -> f64 {
        let r = render(g, cam, background);
        let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
        dot(&r.image.data, &self.rgb) + dot(&r.alpha, &self.alpha) + dot(&r.depth, &self.depth)
    }
}

/// Checks every parameter of `g` (except those `skip` names by array and index) and the
/// background against central differences.
fn check_gradients(
    g: &GaussianSet<f64>,
    cam: &Camera,
    seed: u64,
    skip: &dyn Fn(usize, usize) -> bool,
) {
    let probe = Probe::new(cam, seed);
    let grads = probe.gradients(g, cam);
    let h = 1e-6;
    let analytic = grads.gaussians.arrays().map(|a| a.to_vec());
    for (kind, name) in PARAM_NAMES.iter().enumerate() {
        let mut fd = Vec::new();
        let mut an = Vec::new();
        for idx in 0..analytic[kind].len() {
            if skip(kind, idx) {
                continue;
            }
            let mut plus = g.clone();
            plus.arrays_mut()[kind][idx] += h;
            let mut minus = g.clone();
            minus.arrays_mut()[kind][idx] -= h;
            let d = (probe.loss(&plus, cam, probe.background)
                - probe.loss(&minus, cam, probe.background))
                / (2.0 * h);
            fd.push(d);
            an.push(analytic[kind][idx]);
        }
        assert_close(name, &an, &fd);
    }
    let mut fd_bg = [0.0; 3];
    for (ch, v) in fd_bg.iter_mut().enumerate() {
        let mut p = probe.background;
        p[ch] += h;
        let mut m = probe.background;
        m[ch] -= h;
        *v = (probe.loss(g, cam, p) - probe.loss(g, cam, m)) / (2.0 * h);
    }
    assert_close("background", &grads.background, &fd_bg);
}

/// Relative error of the whole array below 1e-3 and of every entry below 1e-3 of the array's
/// largest magnitude.
fn assert_close(name: &str, analytic: &[f64], fd: &[f64]) {
    let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
    let diff: Vec<f64> = analytic.iter().zip(fd).map(|(a, b)| a - b).collect();
    let scale = norm(fd).max(1e-9);
    let rel = norm(&diff) / scale;
    let max_fd = fd.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-9);
    let worst = diff.iter().fold(0.0f64, |m, v| m.max(v.abs())) / max_fd;
    assert!(
        rel < 1e-3 && worst < 1e-3,
        "{name}: relative error {rel:.3e}, worst entry {worst:.3e}\nanalytic {analytic:?}\nfd {fd:?}"
    );
}

fn no_skip(_: usize, _: usize) -> bool {
    false
}

#[test]
fn random_scenes_every_degree() {
    for degree in 0..=3 {
        let g = random_scene::<f64>(10 + degree as u64, 7, degree);
        check_gradients(&g, &oblique_camera(29, 21), 100 + degree as u64, &no_skip);
    }
}

#[test]
fn random_scene_front_view_with_gradients_nonzero() {
    let g = random_scene::<f64>(3, 9, 1);
    let cam = front_camera(33, 18);
    check_gradients(&g, &cam, 7, &no_skip);
    // The probe must actually exercise the Gaussians: most should get a gradient.
    let r = render(&g, &cam, [0.0; 3]);
    assert!(r.visible_count() >= 7, "only {} visible", r.visible_count());
    let w = weights(7, 3 * cam.pixel_count());
    let grads = backward(
        &g,
        &cam,
        &r,
        &OutputGrads {
            rgb: &w,
            alpha: None,
            depth: None,
        },
        GradMask::ALL,
    );
    let moved = (0..g.len())
        .filter(|i| {
            grads.gaussians.means[3 * i..3 * i + 3]
                .iter()
                .any(|v| *v != 0.0)
        })
        .count();
    assert!(moved >= 7, "only {moved} Gaussians got a mean gradient");
}

/// One Gaussian per degenerate case, each in a scene of its own with a normal Gaussian behind.
fn degenerate_scene(edit: impl Fn(&mut GaussianSet<f64>)) -> GaussianSet<f64> {
    let mut g = random_scene::<f64>(42, 2, 2);
    g.means[3..6].copy_from_slice(&[0.1, -0.1, 0.6]);
    g.log_scales[3..6].copy_from_slice(&[-1.0, -1.2, -1.1]);
    g.opacity_logits[1] = 0.5;
    g.means[0..3].copy_from_slice(&[-0.05, 0.05, 0.0]);
    edit(&mut g);
    g
}

#[test]
fn near_zero_scales() {
    let g = degenerate_scene(|g| g.log_scales[0..3].copy_from_slice(&[-18.0, -19.0, -20.0]));
    check_gradients(&g, &front_camera(24, 24), 1, &no_skip);
}

#[test]
fn huge_scales() {
    let g = degenerate_scene(|g| g.log_scales[0..3].copy_from_slice(&[2.5, 2.0, 3.0]));
    check_gradients(&g, &front_camera(24, 24), 2, &no_skip);
}

#[test]
fn flat_gaussian_seen_edge_on_has_near_zero_determinant() {
    // Flat along world x and seen along x: only eps2d keeps its 2D covariance invertible.
    let g = degenerate_scene(|g| {
        g.log_scales[0..3].copy_from_slice(&[-1.0, -1.0, -17.0]);
        g.quats[0..4].copy_from_slice(&[1.0, 0.0, 1.0, 0.0]); // z axis turned onto x
    });
    let cam = Camera::look_at([-4.0, 0.0, 0.3], [0.0; 3], [0.0, -1.0, 0.0], 0.8, 24, 24).unwrap();
    check_gradients(&g, &cam, 3, &no_skip);
}

#[test]
fn behind_the_camera_draws_nothing_and_gets_zero_gradient() {
    let g = degenerate_scene(|g| g.means[0..3].copy_from_slice(&[0.0, 0.0, -6.0]));
    let cam = front_camera(24, 24);
    check_gradients(&g, &cam, 4, &no_skip);
    let r = render(&g, &cam, [0.0; 3]);
    assert_eq!(r.visible_count(), 1);
}

#[test]
fn straddling_the_near_plane() {
    // Centre 0.25 in front of the camera, 0.05 past the near plane (0.2), extent 0.3 on both
    // sides of it.
    let g = degenerate_scene(|g| {
        g.means[0..3].copy_from_slice(&[0.01, 0.02, -3.75]);
        g.log_scales[0..3].copy_from_slice(&[-1.2, -1.5, -1.2]);
    });
    check_gradients(&g, &front_camera(24, 24), 5, &no_skip);
}

#[test]
fn opacity_near_zero_and_near_one() {
    // -5.3: opacity 0.005, just above 1/255, so it is drawn near its centre only; 9: opacity
    // 0.9999, whose alpha peaks at 0.9898 on this view's pixel centres, just below the 0.99
    // cap. At the cap itself the gradient is INRIA's, not the finite difference's
    // (tests/alpha_cap_gradient.rs).
    for logit in [-5.3, 9.0] {
        let g = degenerate_scene(|g| g.opacity_logits[0] = logit);
        check_gradients(&g, &front_camera(24, 24), 6, &no_skip);
    }
}

#[test]
fn overlapping_at_equal_depth() {
    // Two Gaussians at exactly the same depth: the order is by index, and moving either along
    // the view axis changes it, so depth-changing coordinates (mean z, camera looks along z) are
    // left out.
    let g = degenerate_scene(|g| {
        g.means[0..3].copy_from_slice(&[0.05, 0.0, 0.3]);
        g.means[3..6].copy_from_slice(&[-0.05, 0.02, 0.3]);
    });
    check_gradients(&g, &front_camera(24, 24), 8, &|kind, idx| {
        kind == 0 && idx % 3 == 2
    });
}

#[test]
fn centre_outside_the_jacobian_clamp() {
    // x/z = 0.7 is past the clamp 1.3 tan(fov_x / 2) = 0.55 of this camera: the centre is off
    // screen, the large Gaussian still reaches in, and its Jacobian uses the clamped x/z.
    let g = degenerate_scene(|g| {
        g.means[0..3].copy_from_slice(&[2.8, 0.1, 0.0]);
        g.log_scales[0..3].copy_from_slice(&[0.4, 0.3, 0.2]);
    });
    let cam = front_camera(24, 24);
    let r = render(&g, &cam, [0.0; 3]);
    assert_eq!(r.visible_count(), 2, "the clamped Gaussian must be drawn");
    // Its depth's gradient is INRIA's, not the derivative: INRIA's backward differentiates the
    // Jacobian's `-fx t_x / z^2` as if the clamped `t_x = u z` did not depend on `z` (held to
    // INRIA's rasterizer by tests/inria_thresholds.rs). This camera's depth is world z.
    check_gradients(&g, &cam, 9, &|kind, idx| kind == 0 && idx == 2);
    let probe = Probe::new(&cam, 9);
    let grads = probe.gradients(&g, &cam);
    let h = 1e-6;
    let shifted = |d: f64| {
        let mut s = g.clone();
        s.means[2] += d;
        probe.loss(&s, &cam, probe.background)
    };
    let fd = (shifted(h) - shifted(-h)) / (2.0 * h);
    let analytic = grads.gaussians.means[2];
    assert!(
        (analytic - fd).abs() > 1e-3 * fd.abs(),
        "the depth gradient at the clamp is INRIA's ({analytic:e}), not the derivative ({fd:e})"
    );
}

#[test]
fn pixels_that_stop_early() {
    // Five stacked, nearly opaque Gaussians: transmittance falls below 1e-4 at the fourth or
    // fifth near the centre, so those pixels stop and the rest is not composited.
    let mut g = random_scene::<f64>(5, 5, 1);
    for i in 0..5 {
        g.means[3 * i..3 * i + 3].copy_from_slice(&[
            0.02 * i as f64,
            -0.01 * i as f64,
            0.2 * i as f64,
        ]);
        g.log_scales[3 * i..3 * i + 3].copy_from_slice(&[-1.1, -1.2, -1.0]);
        g.opacity_logits[i] = 3.0;
    }
    check_gradients(&g, &front_camera(24, 24), 10, &no_skip);
}
