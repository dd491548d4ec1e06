//! antimatter15's `.splat`: no header, 32 bytes a Gaussian, little-endian:
//! - position `f32 x 3`;
//! - scale `f32 x 3`, linear (`exp` of the log-scale);
//! - colour `u8 x 4`: RGB `0.5 + C0 f_dc` and alpha `sigmoid(opacity)`, each `x 255`, clamped
//!   and truncated;
//! - rotation `u8 x 4`, `(w, x, y, z)` of the unit quaternion, `x 128 + 128`, clamped and
//!   truncated (antimatter15's `convert.py` normalises first; splat-transform 3.7 does not, and
//!   saturates quaternions of other norms).
//!
//! Degree-0 colour only: the higher SH coefficients are dropped. Reading inverts each
//! quantisation as splat-transform does: a rotation byte `b` is `b / 127.5 - 1`, the quaternion
//! normalised; an alpha level `a` becomes the opacity logit `logit(a / 255)`, kept finite at 0
//! and 255.

use super::DecodeError;
use super::{check_finite, check_linear_scales, check_rotations, opacity_of_level, sigmoid};
use crate::sh::C0;
use crate::GaussianSet;

/// Bytes a Gaussian takes.
pub const RECORD: usize = 32;

/// A `u8` level of `v` in `[0, 1]` (`x 255`, clamped, truncated).
fn level(v: f64) -> u8 {
    (v * 255.0).clamp(0.0, 255.0) as u8
}

/// The `.splat` bytes of `set` (its order kept); an error names a value that cannot be written.
pub fn encode(set: &GaussianSet) -> Result<Vec<u8>, String> {
    check_finite(set)?;
    check_rotations(set)?;
    check_linear_scales(set)?;
    let mut out = Vec::with_capacity(RECORD * set.len());
    for i in 0..set.len() {
        for k in 0..3 {
            out.extend(set.means[3 * i + k].to_le_bytes());
        }
        for k in 0..3 {
            out.extend((set.log_scales[3 * i + k].exp()).to_le_bytes());
        }
        for k in 0..3 {
            out.push(level(0.5 + C0 * f64::from(set.sh_dc[3 * i + k])));
        }
        out.push(level(sigmoid(f64::from(set.opacity_logits[i]))));
        let q = &set.quats[4 * i..4 * i + 4];
        let norm = q.iter().map(|&v| f64::from(v).powi(2)).sum::<f64>().sqrt();
        for &v in q {
            out.push((f64::from(v) / norm * 128.0 + 128.0).clamp(0.0, 255.0) as u8);
        }
    }
    Ok(out)
}

/// The Gaussians of `.splat` bytes (SH degree 0); an error when the length is not a whole
/// number of records.
pub fn decode(bytes: &[u8]) -> Result<GaussianSet, DecodeError> {
    if !bytes.len().is_multiple_of(RECORD) {
        return Err(format!(
            "{} bytes is not a whole number of {RECORD}-byte Gaussians",
            bytes.len()
        )
        .into());
    }
    let n = bytes.len() / RECORD;
    let mut set = GaussianSet::try_zeros(n, 0)?;
    let f32_at = |r: &[u8], k: usize| f32::from_le_bytes(r[4 * k..4 * k + 4].try_into().unwrap());
    for (i, r) in bytes.chunks_exact(RECORD).enumerate() {
        for k in 0..3 {
            set.means[3 * i + k] = f32_at(r, k);
            let scale = f32_at(r, 3 + k);
            if !(scale > 0.0 && scale.is_finite()) {
                return Err(
                    format!("Gaussian {i}: scale {k} is {scale}, not a positive size").into(),
                );
            }
            set.log_scales[3 * i + k] = scale.ln();
            set.sh_dc[3 * i + k] = ((f64::from(r[24 + k]) / 255.0 - 0.5) / C0) as f32;
        }
        if let Some(k) = (0..3).find(|&k| !set.means[3 * i + k].is_finite()) {
            return Err(format!("Gaussian {i}: position {k} is not finite").into());
        }
        set.opacity_logits[i] = opacity_of_level(u32::from(r[27])) as f32;
        let q = [0, 1, 2, 3].map(|k| f64::from(r[28 + k]) / 127.5 - 1.0);
        let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        for k in 0..4 {
            set.quats[4 * i + k] = (q[k] / norm) as f32;
        }
    }
    Ok(set)
}
