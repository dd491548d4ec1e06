//! The compact form of a page's Gaussians, for large scenes (about 62 bytes a Gaussian instead
//! of 236), quantised as PlayCanvas's SOG quantises them:
//! - positions: 16 bits an axis of `sign(x) ln(|x| + 1)` between the axis's extremes;
//! - rotations: the unit quaternion's smallest three components, a byte each
//!   (`(v sqrt 2 + 1) / 2`), and `252 +` the index of the largest (made positive);
//! - log-scales, and the SH coefficients (degree 0 and the rest each their own): a byte
//!   indexing a 256-entry codebook of their values (splat-transform's `quantize1d`);
//! - opacity: the 8-bit level of its sigmoid.
//!
//! The page decodes them back to floats (`decodeCompact` in `viewer.html`).

use gs_core::splats::codebook::scalar_codebook;
use gs_core::GaussianSet;
use serde_json::json;

use super::base64;

/// `sign(x) ln(|x| + 1)`.
fn to_log(x: f64) -> f64 {
    x.signum() * (x.abs() + 1.0).ln()
}

/// The compact form of `set`, with `quats` (its quaternions, turned as the page blends them).
pub(super) fn compact_json(set: &GaussianSet, quats: &[f32]) -> serde_json::Value {
    let n = set.len();
    let mut mins = [f64::INFINITY; 3];
    let mut maxs = [f64::NEG_INFINITY; 3];
    for p in set.means.chunks_exact(3) {
        for k in 0..3 {
            let v = to_log(f64::from(p[k]));
            mins[k] = mins[k].min(v);
            maxs[k] = maxs[k].max(v);
        }
    }
    let mut positions = Vec::with_capacity(6 * n);
    for p in set.means.chunks_exact(3) {
        for k in 0..3 {
            let span = maxs[k] - mins[k];
            let level = if span > 0.0 {
                (65535.0 * (to_log(f64::from(p[k])) - mins[k]) / span).round() as u16
            } else {
                0
            };
            positions.extend(level.to_le_bytes());
        }
    }
    const INDEX: [[usize; 3]; 4] = [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]];
    let mut rotations = Vec::with_capacity(4 * n);
    for q in quats.chunks_exact(4) {
        let norm = q.iter().map(|&v| f64::from(v).powi(2)).sum::<f64>().sqrt();
        if !(norm > 0.0) {
            // No direction: decoded as the zero quaternion the page culls, as gs-core culls it.
            rotations.extend([0, 0, 0, 0]);
            continue;
        }
        let q = [0, 1, 2, 3].map(|k| f64::from(q[k]) / norm);
        let largest = (1..4).fold(0, |m, k| if q[k].abs() > q[m].abs() { k } else { m });
        let s = q[largest].signum() * std::f64::consts::SQRT_2;
        for &k in &INDEX[largest] {
            rotations.push((255.0 * (q[k] * s * 0.5 + 0.5)).round().clamp(0.0, 255.0) as u8);
        }
        rotations.push(252 + largest as u8);
    }
    let opacity: Vec<u8> = set
        .opacity_logits
        .iter()
        .map(|&l| (255.0 / (1.0 + (-f64::from(l)).exp())).round() as u8)
        .collect();
    let scales = scalar_codebook(&set.log_scales);
    let sh = set.sh();
    let per = sh.len() / n.max(1);
    let (dc, rest): (Vec<f32>, Vec<f32>) = {
        let mut dc = Vec::with_capacity(3 * n);
        let mut rest = Vec::with_capacity(sh.len() - 3 * n);
        for g in sh.chunks_exact(per.max(1)) {
            dc.extend(&g[..3]);
            rest.extend(&g[3..]);
        }
        (dc, rest)
    };
    let (dc, rest) = (scalar_codebook(&dc), scalar_codebook(&rest));
    json!({
        "compact": true,
        "positions": base64(&positions),
        "position_mins": mins,
        "position_maxs": maxs,
        "rotations": base64(&rotations),
        "opacity_levels": base64(&opacity),
        "scales": base64(&scales.labels),
        "scale_codebook": scales.values,
        "dc": base64(&dc.labels),
        "dc_codebook": dc.values,
        "rest": base64(&rest.labels),
        "rest_codebook": rest.values,
    })
}
