//! One frame of VeGaS's folded Gaussians: the 3D Gaussians rendered at time `t`, and the
//! backward of that construction (`gaussian_renderer/__init__.py` of the authors' code).
//!
//! For a Gaussian with plane position `(x, z)`, in-plane log-scales `(s_x, s_z)`, rotation
//! logit `r`, temporal centre logit `m`, log width `sigma` and polynomial `w` (`2 P` values;
//! `w[2i]`, `w[2i + 1]` move `x`, `z` with power `i + 1`), with `u = sigmoid(m) - t`:
//! - mean `(x + sum_i w[2i] u^(i+1), 0, z + sum_i w[2i+1] u^(i+1))` (the stored `y` is unused);
//! - `delta = exp(-u^2 / (2 e^(2 sigma)))`, and scales `delta * (e^s_x, 1e-8, e^s_z)` (all
//!   three axes, so the log-scales are `(s_x, ln 1e-8, s_z) + ln delta`);
//! - rotation `(cos a, 0, sin a, 0)` with `a = pi sigmoid(r)`: a turn of `2 pi sigmoid(r)`
//!   about the plane's normal `y`;
//! - opacity logit and colour as stored (SH degree 0).
//!
//! A Gaussian is drawn only when `delta > 0.01` and both in-plane scales exceed `1e-4`
//! (strictly, as the authors' mask); the others are left out of the frame and receive no
//! gradient from it.

use gs_core::gaussians::GaussianGrads;
use gs_core::{GaussianSet, Real};

/// Degree of the motion polynomial `P` (VeGaS's `--poly_degree`).
pub const POLY_DEGREE: usize = 7;

/// Values of the polynomial per Gaussian, `2 P`.
pub const POLY_LEN: usize = 2 * POLY_DEGREE;

/// The scale of the flat axis before the temporal factor, world units.
pub const FLAT_SCALE: f64 = 1e-8;

/// A Gaussian is drawn only when its temporal factor exceeds this.
pub const MIN_DELTA: f64 = 0.01;

/// A Gaussian is drawn only when both of its in-plane scales (after the temporal factor)
/// exceed this, world units.
pub const MIN_SCALE: f64 = 1e-4;

/// The parameters of folded Gaussians, one row per Gaussian (the layout of VeGaS's PLY).
#[derive(Clone, Debug, PartialEq)]
pub struct FoldedParams<T: Real = f32> {
    /// Positions `[N, 3]`; `x` and `z` are on the plane, `y` is stored but never rendered.
    pub xyz: Vec<T>,
    /// In-plane log-scales `[N, 2]`: `s_x`, `s_z`.
    pub log_scales: Vec<T>,
    /// Rotation logits `[N]`.
    pub rotation: Vec<T>,
    /// Temporal centre logits `[N]` (the centre in time is `sigmoid(m)`).
    pub m: Vec<T>,
    /// Log temporal widths `[N]`.
    pub sigma: Vec<T>,
    /// Motion polynomials `[N, 2 P]`.
    pub w: Vec<T>,
    /// Opacity logits `[N]`.
    pub opacity_logits: Vec<T>,
    /// Degree-0 SH coefficients `[N, 3]`.
    pub sh_dc: Vec<T>,
}

/// What the backward of a frame needs: which Gaussians were drawn, in the order of the
/// rendered set.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FrameTape {
    /// Index in the parameters of each rendered Gaussian.
    pub drawn: Vec<u32>,
}

impl<T: Real> FoldedParams<T> {
    /// `n` Gaussians with every parameter 0.
    pub fn zeros(n: usize) -> Self {
        let zero = T::from_f64(0.0);
        Self {
            xyz: vec![zero; 3 * n],
            log_scales: vec![zero; 2 * n],
            rotation: vec![zero; n],
            m: vec![zero; n],
            sigma: vec![zero; n],
            w: vec![zero; POLY_LEN * n],
            opacity_logits: vec![zero; n],
            sh_dc: vec![zero; 3 * n],
        }
    }

    /// No Gaussians, with room for `n` in every array.
    pub fn with_capacity(n: usize) -> Self {
        Self {
            xyz: Vec::with_capacity(3 * n),
            log_scales: Vec::with_capacity(2 * n),
            rotation: Vec::with_capacity(n),
            m: Vec::with_capacity(n),
            sigma: Vec::with_capacity(n),
            w: Vec::with_capacity(POLY_LEN * n),
            opacity_logits: Vec::with_capacity(n),
            sh_dc: Vec::with_capacity(3 * n),
        }
    }

    /// The number of Gaussians.
    pub fn len(&self) -> usize {
        self.m.len()
    }

    /// Whether there are no Gaussians.
    pub fn is_empty(&self) -> bool {
        self.m.is_empty()
    }
}

/// `u = sigmoid(m) - t`, `ln delta` and `e^(-2 sigma)` of Gaussian `i` at time `t`.
fn temporal<T: Real>(p: &FoldedParams<T>, i: usize, t: T) -> (T, T, T) {
    let u = p.m[i].sigmoid() - t;
    let width = p.sigma[i].exp();
    let ln_delta = u * u / (width * width) / T::from_f64(-2.0);
    (u, ln_delta, T::from_f64(1.0) / (width * width))
}

/// Whether Gaussian `i` is drawn at time `t`, decided with the authors' operations in their
/// order (`delta > 0.01`, `delta * e^s > 1e-4` for both in-plane scales).
fn is_drawn<T: Real>(p: &FoldedParams<T>, i: usize, t: T) -> bool {
    let (_, ln_delta, _) = temporal(p, i, t);
    let delta = ln_delta.exp();
    let min_scale = T::from_f64(MIN_SCALE);
    delta > T::from_f64(MIN_DELTA)
        && delta * p.log_scales[2 * i].exp() > min_scale
        && delta * p.log_scales[2 * i + 1].exp() > min_scale
}

/// `(cos a, sin a)` for `a = pi sigmoid(r)`.
fn half_angle<T: Real>(r: T) -> (T, T) {
    let a = std::f64::consts::PI * r.sigmoid().to_f64();
    (T::from_f64(a.cos()), T::from_f64(a.sin()))
}

/// The Gaussians drawn at time `t` and the tape of the frame.
pub fn build_frame<T: Real>(p: &FoldedParams<T>, t: T) -> (GaussianSet<T>, FrameTape) {
    let drawn: Vec<u32> = (0..p.len())
        .filter(|&i| is_drawn(p, i, t))
        .map(|i| i as u32)
        .collect();
    let mut set = GaussianSet::zeros(drawn.len(), 0);
    let flat = T::from_f64(FLAT_SCALE.ln());
    for (k, &i) in drawn.iter().enumerate() {
        let i = i as usize;
        let (u, ln_delta, _) = temporal(p, i, t);
        let (mut x, mut z) = (p.xyz[3 * i], p.xyz[3 * i + 2]);
        let mut power = u;
        for w in p.w[POLY_LEN * i..POLY_LEN * (i + 1)].chunks_exact(2) {
            x += w[0] * power;
            z += w[1] * power;
            power *= u;
        }
        set.means[3 * k..3 * k + 3].copy_from_slice(&[x, T::from_f64(0.0), z]);
        set.log_scales[3 * k..3 * k + 3].copy_from_slice(&[
            p.log_scales[2 * i] + ln_delta,
            flat + ln_delta,
            p.log_scales[2 * i + 1] + ln_delta,
        ]);
        let (c, s) = half_angle(p.rotation[i]);
        set.quats[4 * k..4 * k + 4].copy_from_slice(&[c, T::from_f64(0.0), s, T::from_f64(0.0)]);
        set.opacity_logits[k] = p.opacity_logits[i];
        set.sh_dc[3 * k..3 * k + 3].copy_from_slice(&p.sh_dc[3 * i..3 * i + 3]);
    }
    (set, FrameTape { drawn })
}

/// Adds to `out` the gradient with respect to the parameters of a loss whose gradient with
/// respect to the frame's Gaussians (built by [`build_frame`] at time `t` with `tape`) is
/// `grads`, and returns its gradient with respect to `t`.
pub fn add_frame_grads<T: Real>(
    p: &FoldedParams<T>,
    t: T,
    tape: &FrameTape,
    grads: &GaussianGrads<T>,
    out: &mut FoldedParams<T>,
) -> T {
    let zero = T::from_f64(0.0);
    let mut grad_t = zero;
    for (k, &i) in tape.drawn.iter().enumerate() {
        let i = i as usize;
        let (u, _, inv_width2) = temporal(p, i, t);
        let (gx, gz) = (grads.means[3 * k], grads.means[3 * k + 2]);
        out.xyz[3 * i] += gx;
        out.xyz[3 * i + 2] += gz;
        // d mean / d w and d mean / d u.
        let mut grad_u = zero;
        let mut power = T::from_f64(1.0); // u^j before the j-th term (power j + 1)
        for (j, w) in p.w[POLY_LEN * i..POLY_LEN * (i + 1)]
            .chunks_exact(2)
            .enumerate()
        {
            let next = power * u;
            out.w[POLY_LEN * i + 2 * j] += gx * next;
            out.w[POLY_LEN * i + 2 * j + 1] += gz * next;
            let order = T::from_f64((j + 1) as f64);
            grad_u += order * power * (w[0] * gx + w[1] * gz);
            power = next;
        }
        let g = &grads.log_scales[3 * k..3 * k + 3];
        out.log_scales[2 * i] += g[0];
        out.log_scales[2 * i + 1] += g[2];
        // ln delta = -u^2 e^(-2 sigma) / 2 enters all three log-scales.
        let grad_ln_delta = g[0] + g[1] + g[2];
        grad_u -= grad_ln_delta * u * inv_width2;
        out.sigma[i] += grad_ln_delta * u * u * inv_width2;
        let sig = p.m[i].sigmoid();
        out.m[i] += grad_u * sig * (T::from_f64(1.0) - sig);
        grad_t -= grad_u;
        // q = (cos a, 0, sin a, 0), a = pi sigmoid(r).
        let (c, s) = half_angle(p.rotation[i]);
        let q = &grads.quats[4 * k..4 * k + 4];
        let grad_a = c * q[2] - s * q[0];
        let sr = p.rotation[i].sigmoid();
        out.rotation[i] +=
            grad_a * T::from_f64(std::f64::consts::PI) * sr * (T::from_f64(1.0) - sr);
        out.opacity_logits[i] += grads.opacity_logits[k];
        for c in 0..3 {
            out.sh_dc[3 * i + c] += grads.sh_dc[3 * k + c];
        }
    }
    grad_t
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;

    /// `n` Gaussians with every parameter drawn from `rng`, all drawn near time 0.5.
    fn random_params(n: usize, rng: &mut ChaCha8Rng) -> FoldedParams<f64> {
        let mut v = |len: usize, lo: f64, hi: f64| -> Vec<f64> {
            (0..len).map(|_| rng.random_range(lo..hi)).collect()
        };
        FoldedParams {
            xyz: v(3 * n, -1.0, 1.0),
            log_scales: v(2 * n, -4.0, -1.0),
            rotation: v(n, -2.0, 2.0),
            m: v(n, -0.3, 0.3),
            sigma: v(n, -0.5, 0.5),
            w: v(POLY_LEN * n, -1.0, 1.0),
            opacity_logits: v(n, -2.0, 2.0),
            sh_dc: v(3 * n, -1.0, 1.0),
        }
    }

    /// Upstream gradients for `set`, drawn from `rng`.
    fn random_grads(set: &GaussianSet<f64>, rng: &mut ChaCha8Rng) -> GaussianGrads<f64> {
        let mut g = GaussianSet::zeros(set.len(), 0);
        for array in [
            &mut g.means,
            &mut g.log_scales,
            &mut g.quats,
            &mut g.opacity_logits,
            &mut g.sh_dc,
        ] {
            for v in array.iter_mut() {
                *v = rng.random_range(-1.0..1.0);
            }
        }
        g
    }

    /// `sum(grads * build_frame(p, t))`, the loss whose gradient the backward computes.
    fn loss(p: &FoldedParams<f64>, t: f64, grads: &GaussianGrads<f64>) -> f64 {
        let (set, _) = build_frame(p, t);
        assert_eq!(
            set.len(),
            grads.len(),
            "the drawn set changed under the perturbation"
        );
        [
            (&set.means, &grads.means),
            (&set.log_scales, &grads.log_scales),
            (&set.quats, &grads.quats),
            (&set.opacity_logits, &grads.opacity_logits),
            (&set.sh_dc, &grads.sh_dc),
        ]
        .iter()
        .map(|(a, b)| a.iter().zip(b.iter()).map(|(x, y)| x * y).sum::<f64>())
        .sum()
    }

    fn arrays_mut(p: &mut FoldedParams<f64>) -> [(&'static str, &mut Vec<f64>); 8] {
        [
            ("xyz", &mut p.xyz),
            ("log_scales", &mut p.log_scales),
            ("rotation", &mut p.rotation),
            ("m", &mut p.m),
            ("sigma", &mut p.sigma),
            ("w", &mut p.w),
            ("opacity_logits", &mut p.opacity_logits),
            ("sh_dc", &mut p.sh_dc),
        ]
    }

    /// The backward against central differences of [`loss`] for every parameter and `t`,
    /// with step `h` and tolerance `tol` relative to the gradient's scale.
    fn check_against_finite_differences(
        p: &FoldedParams<f64>,
        t: f64,
        seed: u64,
        h: f64,
        tol: f64,
    ) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (set, tape) = build_frame(p, t);
        assert!(!set.is_empty(), "nothing drawn");
        let grads = random_grads(&set, &mut rng);
        let mut zeros = p.clone();
        for (_, a) in arrays_mut(&mut zeros) {
            a.iter_mut().for_each(|v| *v = 0.0);
        }
        let mut analytic = zeros.clone();
        let grad_t = add_frame_grads(p, t, &tape, &grads, &mut analytic);
        let mut analytic_arrays = analytic.clone();
        let names_and_values: Vec<(&str, Vec<f64>)> = arrays_mut(&mut analytic_arrays)
            .into_iter()
            .map(|(n, a)| (n, a.clone()))
            .collect();
        for (name, values) in names_and_values {
            for j in 0..values.len() {
                let fd = {
                    let mut up = p.clone();
                    let mut down = p.clone();
                    arrays_mut(&mut up)
                        .into_iter()
                        .find(|(n, _)| *n == name)
                        .unwrap()
                        .1[j] += h;
                    arrays_mut(&mut down)
                        .into_iter()
                        .find(|(n, _)| *n == name)
                        .unwrap()
                        .1[j] -= h;
                    (loss(&up, t, &grads) - loss(&down, t, &grads)) / (2.0 * h)
                };
                let a = values[j];
                assert!(
                    (a - fd).abs() <= tol * (1.0 + fd.abs()),
                    "{name}[{j}]: analytic {a}, finite difference {fd}"
                );
            }
        }
        let fd_t = (loss(p, t + h, &grads) - loss(p, t - h, &grads)) / (2.0 * h);
        assert!(
            (grad_t - fd_t).abs() <= tol * (1.0 + fd_t.abs()),
            "t: {grad_t} vs {fd_t}"
        );
    }

    #[test]
    fn backward_matches_finite_differences_for_every_parameter() {
        for seed in [1, 2, 3] {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let p = random_params(6, &mut rng);
            for t in [0.3, 0.5, 0.62] {
                check_against_finite_differences(&p, t, seed + 10, 1e-6, 1e-6);
            }
        }
    }

    #[test]
    fn backward_matches_finite_differences_at_near_zero_widths() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let mut p = random_params(3, &mut rng);
        // Widths e^-6 = 2.5e-3: drawn only within about 7.6e-3 of the temporal centre.
        let t = 0.5;
        for i in 0..3 {
            p.sigma[i] = -6.0;
            p.m[i] = 0.004 * (i as f64 - 1.0); // centres at t + 0.001 (i - 1) (sigmoid'(0) = 1/4)
            p.log_scales[2 * i] = -1.0;
            p.log_scales[2 * i + 1] = -1.5;
        }
        // Derivatives of order 1 / width^2 = 1.6e5: a smaller step, a scale-relative tolerance.
        check_against_finite_differences(&p, t, 5, 1e-9, 1e-4);
    }

    #[test]
    fn a_gaussian_at_the_culling_threshold_is_left_out_and_gets_no_gradient() {
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let mut p = random_params(2, &mut rng);
        let t = 0.5;
        // Gaussian 1: centre at sigmoid(0) = 0.5, width 0.1; delta(u) = 0.01 at
        // u* = 0.1 sqrt(2 ln 100). Put the time just inside and just outside u*.
        p.m[1] = 0.0;
        p.sigma[1] = 0.1f64.ln();
        let u_star = 0.1 * (2.0 * 100f64.ln()).sqrt();
        let inside = build_frame(&p, t - (u_star - 1e-9)).1;
        let outside = build_frame(&p, t - (u_star + 1e-9)).1;
        assert!(inside.drawn.contains(&1) && !outside.drawn.contains(&1));
        // Left out: no gradient reaches any of its parameters, nor t through it.
        let t_out = t - (u_star + 1e-9);
        let (set, tape) = build_frame(&p, t_out);
        let grads = random_grads(&set, &mut rng);
        let mut out = p.clone();
        for (_, a) in arrays_mut(&mut out) {
            a.iter_mut().for_each(|v| *v = 0.0);
        }
        add_frame_grads(&p, t_out, &tape, &grads, &mut out);
        assert_eq!(
            (out.m[1], out.sigma[1], out.sh_dc[3], out.w[POLY_LEN]),
            (0.0, 0.0, 0.0, 0.0)
        );
        // A scale at its threshold: just under 1e-4 is left out, just over is drawn.
        let mut q = random_params(1, &mut rng);
        q.m[0] = 0.0;
        q.log_scales[0] = MIN_SCALE.ln() - 1e-9;
        assert!(build_frame(&q, 0.5).1.drawn.is_empty());
        q.log_scales[0] = MIN_SCALE.ln() + 1e-9;
        assert_eq!(build_frame(&q, 0.5).1.drawn, vec![0]);
        check_against_finite_differences(&q, 0.5, 7, 1e-11, 1e-4);
    }

    #[test]
    fn at_its_temporal_centre_a_gaussian_is_its_stored_self() {
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let p = random_params(1, &mut rng);
        let t = 1.0 / (1.0 + (-p.m[0]).exp());
        let (set, _) = build_frame(&p, t);
        assert_eq!(set.means[0], p.xyz[0]);
        assert_eq!((set.means[1], set.means[2]), (0.0, p.xyz[2]));
        assert_eq!(set.log_scales[0], p.log_scales[0]);
        assert_eq!(set.log_scales[2], p.log_scales[1]);
        let q = &set.quats;
        assert!((q[0] * q[0] + q[2] * q[2] - 1.0).abs() < 1e-15 && q[1] == 0.0 && q[3] == 0.0);
        let a = std::f64::consts::PI / (1.0 + (-p.rotation[0]).exp());
        assert!((q[0] - a.cos()).abs() < 1e-15);
    }
}
