//! One sub-Gaussian of a core at one time: its mean, log-scales and rotation from the core's
//! [`Frame`], its own offsets, log-scales and quaternion, and the time-rotation layer, with the
//! exact backward. Computed in f64.
//!
//! - mean `origin + alpha_0 n + alpha_1 a_dir + alpha_2 b_dir`;
//! - log-scales `[s_0 + ln 1e-8, s_1 + ln S_2, s_2 + ln S_3]`;
//! - rotation `normalize(W [q, PE(t)] + b) * q_core` (Hamilton product, not renormalized).

use crate::core_frame::{
    normalize_quat, normalize_quat_backward, quat_mul, quat_mul_backward, Frame, FrameGrads,
};
use crate::encoding::TIME_ENCODING;

/// Inputs of the time-rotation layer: a quaternion and the time encoding.
pub const TIME_NET_INPUT: usize = 4 + TIME_ENCODING;

/// Values of the time-rotation layer: weight `[4, 17]` (row-major) then bias `[4]`.
pub const TIME_NET_LEN: usize = 4 * TIME_NET_INPUT + 4;

/// `ln 1e-8`: the log-scale of the core's flat axis.
pub const LOG_FLAT: f64 = -18.420680743952367;

/// A sub-Gaussian's own parameters.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SubParams {
    /// Offsets along the normal and the two edge directions.
    pub alpha: [f64; 3],
    /// Log-scales relative to the core's.
    pub scale: [f64; 3],
    /// Quaternion before the time-rotation layer (w, x, y, z).
    pub rotation: [f64; 4],
}

/// What is rendered of a sub-Gaussian (besides its opacity and colour, which are its own).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SubGaussian {
    /// World position.
    pub mean: [f64; 3],
    /// Log-scales.
    pub log_scale: [f64; 3],
    /// Rotation (w, x, y, z), unit up to rounding.
    pub quat: [f64; 4],
}

/// The time-rotation layer's input: `[q, PE(t)]`.
fn layer_input(rotation: &[f64; 4], te: &[f32; TIME_ENCODING]) -> [f64; TIME_NET_INPUT] {
    let mut x = [0.0; TIME_NET_INPUT];
    x[..4].copy_from_slice(rotation);
    for k in 0..TIME_ENCODING {
        x[4 + k] = te[k] as f64;
    }
    x
}

/// `W x + b` of the time-rotation `layer` (f32 values, [`TIME_NET_LEN`] of them).
fn layer_apply(layer: &[f32], x: &[f64; TIME_NET_INPUT]) -> [f64; 4] {
    let bias = &layer[4 * TIME_NET_INPUT..];
    [0, 1, 2, 3].map(|r| {
        let row = &layer[r * TIME_NET_INPUT..(r + 1) * TIME_NET_INPUT];
        bias[r] as f64 + row.iter().zip(x).map(|(w, v)| *w as f64 * v).sum::<f64>()
    })
}

/// The sub-Gaussian of `own` in `frame` at the time encoding `te`.
pub fn sub_gaussian(
    frame: &Frame,
    own: &SubParams,
    layer: &[f32],
    te: &[f32; TIME_ENCODING],
) -> SubGaussian {
    let a = own.alpha;
    let mean = [0, 1, 2].map(|k| {
        frame.origin[k] + a[0] * frame.normal[k] + a[1] * frame.a_dir[k] + a[2] * frame.b_dir[k]
    });
    let log_scale = [
        own.scale[0] + LOG_FLAT,
        own.scale[1] + frame.log_scales[0],
        own.scale[2] + frame.log_scales[1],
    ];
    let (qt, _) = normalize_quat(layer_apply(layer, &layer_input(&own.rotation, te)));
    SubGaussian {
        mean,
        log_scale,
        quat: quat_mul(qt, frame.quat),
    }
}

/// The gradient of a loss with respect to the sub-Gaussian's own parameters, given its gradient
/// `g` with respect to [`sub_gaussian`]`(frame, own, layer, te)`; adds those of the frame and of
/// the layer to `g_frame` and `g_layer`.
pub fn sub_gaussian_backward(
    frame: &Frame,
    own: &SubParams,
    layer: &[f32],
    te: &[f32; TIME_ENCODING],
    g: &SubGaussian,
    g_frame: &mut FrameGrads,
    g_layer: &mut [f64; TIME_NET_LEN],
) -> SubParams {
    let mut g_own = SubParams::default();
    let a = own.alpha;
    let dirs = [frame.normal, frame.a_dir, frame.b_dir];
    for k in 0..3 {
        g_frame.origin[k] += g.mean[k];
        g_frame.normal[k] += a[0] * g.mean[k];
        g_frame.a_dir[k] += a[1] * g.mean[k];
        g_frame.b_dir[k] += a[2] * g.mean[k];
    }
    for (j, dir) in dirs.iter().enumerate() {
        g_own.alpha[j] += (0..3).map(|k| dir[k] * g.mean[k]).sum::<f64>();
    }
    for k in 0..3 {
        g_own.scale[k] += g.log_scale[k];
    }
    g_frame.log_scales[0] += g.log_scale[1];
    g_frame.log_scales[1] += g.log_scale[2];
    let x = layer_input(&own.rotation, te);
    let (qt, n) = normalize_quat(layer_apply(layer, &x));
    let (g_qt, g_qc) = quat_mul_backward(qt, frame.quat, g.quat);
    for k in 0..4 {
        g_frame.quat[k] += g_qc[k];
    }
    let g_ql = normalize_quat_backward(qt, n, g_qt);
    for r in 0..4 {
        for j in 0..TIME_NET_INPUT {
            g_layer[r * TIME_NET_INPUT + j] += g_ql[r] * x[j];
        }
        g_layer[4 * TIME_NET_INPUT + r] += g_ql[r];
    }
    for j in 0..4 {
        g_own.rotation[j] += (0..4)
            .map(|r| g_ql[r] * layer[r * TIME_NET_INPUT + j] as f64)
            .sum::<f64>();
    }
    g_own
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core_frame::frame;
    use crate::encoding::time_encoding;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn a_sub_gaussian_has_the_gradient_of_finite_differences() {
        for seed in 0..5 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let mut r = |s: f64| rng.random_range(-s..s);
            let tri = [0, 1, 2].map(|_| [0, 1, 2].map(|_| r(1.0)));
            let f = frame(&tri);
            let own = SubParams {
                alpha: [r(0.2), r(0.2), r(0.2)],
                scale: [r(1.0), r(1.0), r(1.0)],
                rotation: [r(1.0), r(1.0), r(1.0), r(1.0)],
            };
            // Zero biases for one seed.
            let layer: Vec<f32> = (0..TIME_NET_LEN)
                .map(|i| {
                    if seed == 0 && i >= 4 * TIME_NET_INPUT {
                        0.0
                    } else {
                        r(0.5) as f32
                    }
                })
                .collect();
            let te = time_encoding(r(1.0).abs() as f32);
            let g = SubGaussian {
                mean: [r(1.0), r(1.0), r(1.0)],
                log_scale: [r(1.0), r(1.0), r(1.0)],
                quat: [r(1.0), r(1.0), r(1.0), r(1.0)],
            };
            let loss = |f: &Frame, own: &SubParams, layer: &[f32]| {
                let s = sub_gaussian(f, own, layer, &te);
                let d = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
                d(&s.mean, &g.mean) + d(&s.log_scale, &g.log_scale) + d(&s.quat, &g.quat)
            };
            let mut g_frame = FrameGrads::default();
            let mut g_layer = [0.0; TIME_NET_LEN];
            let g_own =
                sub_gaussian_backward(&f, &own, &layer, &te, &g, &mut g_frame, &mut g_layer);
            let h = 1e-6;
            let check = |analytic: f64, plus: f64, minus: f64, what: &str| {
                let numeric = (plus - minus) / (2.0 * h);
                assert!(
                    (analytic - numeric).abs() < 1e-6 * (1.0 + numeric.abs()),
                    "seed {seed}: {what}: {analytic} vs {numeric}"
                );
            };
            let analytic: Vec<f64> = g_own
                .alpha
                .iter()
                .chain(&g_own.scale)
                .chain(&g_own.rotation)
                .copied()
                .collect();
            for (n, a) in analytic.iter().enumerate() {
                let shifted = |s: f64| {
                    let mut o = own;
                    let mut fields: Vec<f64> = o
                        .alpha
                        .iter()
                        .chain(&o.scale)
                        .chain(&o.rotation)
                        .copied()
                        .collect();
                    fields[n] += s;
                    o.alpha.copy_from_slice(&fields[..3]);
                    o.scale.copy_from_slice(&fields[3..6]);
                    o.rotation.copy_from_slice(&fields[6..]);
                    loss(&f, &o, &layer)
                };
                check(*a, shifted(h), shifted(-h), &format!("own parameter {n}"));
            }
            let frame_fields = |fr: &Frame| -> Vec<f64> {
                fr.origin
                    .iter()
                    .chain(&fr.normal)
                    .chain(&fr.a_dir)
                    .chain(&fr.b_dir)
                    .chain(&fr.log_scales)
                    .chain(&fr.quat)
                    .copied()
                    .collect()
            };
            let rebuild = |v: &[f64]| Frame {
                origin: [v[0], v[1], v[2]],
                normal: [v[3], v[4], v[5]],
                a_dir: [v[6], v[7], v[8]],
                b_dir: [v[9], v[10], v[11]],
                log_scales: [v[12], v[13]],
                quat: [v[14], v[15], v[16], v[17]],
            };
            for (n, a) in frame_fields(&g_frame).iter().enumerate() {
                let shifted = |s: f64| {
                    let mut v = frame_fields(&f);
                    v[n] += s;
                    loss(&rebuild(&v), &own, &layer)
                };
                check(*a, shifted(h), shifted(-h), &format!("frame value {n}"));
            }
            // The layer is f32: a step of 1e-3 in f32 and a looser bound.
            for n in 0..TIME_NET_LEN {
                let shifted = |s: f32| {
                    let mut l = layer.clone();
                    l[n] += s;
                    loss(&f, &own, &l)
                };
                let step = 1e-3f32;
                let numeric =
                    (shifted(step) - shifted(-step)) / (2.0 * (layer[n] + step - layer[n]) as f64);
                assert!(
                    (g_layer[n] - numeric).abs() < 2e-3 * (1.0 + numeric.abs()),
                    "seed {seed}: layer value {n}: {} vs {numeric}",
                    g_layer[n]
                );
            }
        }
    }
}
