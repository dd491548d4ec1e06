//! The compact form of a page's Gaussians, for large scenes (about 62 bytes a Gaussian instead
//! of 236), quantised as PlayCanvas's SOG quantises them:
//! - positions: 16 bits an axis of `sign(x) ln(|x| + 1)` between the axis's extremes
//!   ([`LogPositions`]);
//! - rotations: the unit quaternion's smallest three components, a byte each, and `252 +` the
//!   index of the largest, made positive ([`smallest_three`]);
//! - log-scales, and the SH coefficients (degree 0 and the rest each their own): a byte
//!   indexing a 256-entry codebook of their values (splat-transform's `quantize1d`);
//! - opacity: the 8-bit level of its sigmoid.
//!
//! The page decodes them back to floats (`decodeCompact` in `viewer.html`).

use gs_core::splats::codebook::scalar_codebook;
use gs_core::splats::sog::{smallest_three, LogPositions};
use gs_core::GaussianSet;
use serde_json::json;

use super::base64;

/// The compact form of `set`, with `quats` (its quaternions, turned as the page blends them).
pub(super) fn compact_json(set: &GaussianSet, quats: &[f32]) -> serde_json::Value {
    let n = set.len();
    let ranges = &LogPositions::of(&set.means);
    let positions: Vec<u8> = set
        .means
        .chunks_exact(3)
        .flat_map(|p| (0..3).flat_map(move |k| ranges.level(p[k], k).to_le_bytes()))
        .collect();
    let rotations: Vec<u8> = quats.chunks_exact(4).flat_map(smallest_three).collect();
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
        "position_mins": ranges.mins,
        "position_maxs": ranges.maxs,
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
