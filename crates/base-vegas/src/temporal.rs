//! Temporal consistency of a video as the paper reports it (after StyleRF): RMSE between frame
//! `i` and frame `i + 1` (short range) and frame `i + 7` (long range), averaged over `i`, on
//! values in `[0, 1]`.
//!
//! The paper first warps one frame onto the other along the optical flow (softmax splatting)
//! and masks the RMSE; its flow model and mask are not published, and no maintained optical-flow
//! implementation fits this workspace (RAFT needs its network weights, OpenCV's Farneback a
//! system library), so these are the *unwarped* frame differences. They measure flicker
//! directly, and compared with the same numbers of the original video
//! ([`TemporalConsistency`] holds both) they say how much a stylization adds.

use gs_core::Image;
use serde::Serialize;

/// The frame gap of short-range consistency.
pub const SHORT_RANGE_GAP: usize = 1;
/// The frame gap of long-range consistency.
pub const LONG_RANGE_GAP: usize = 7;

/// Short- and long-range RMSE of a stylized video and of its original.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TemporalConsistency {
    /// Mean RMSE between consecutive stylized frames.
    pub short_range_rmse: Option<f64>,
    /// Mean RMSE between stylized frames 7 apart (`None` for fewer than 8 frames).
    pub long_range_rmse: Option<f64>,
    /// The same short-range RMSE of the original video.
    pub original_short_range_rmse: Option<f64>,
    /// The same long-range RMSE of the original video.
    pub original_long_range_rmse: Option<f64>,
}

/// Both ranges for `stylized` and `original` (frames of one size each).
pub fn temporal_consistency(stylized: &[Image], original: &[Image]) -> TemporalConsistency {
    TemporalConsistency {
        short_range_rmse: frame_gap_rmse(stylized, SHORT_RANGE_GAP),
        long_range_rmse: frame_gap_rmse(stylized, LONG_RANGE_GAP),
        original_short_range_rmse: frame_gap_rmse(original, SHORT_RANGE_GAP),
        original_long_range_rmse: frame_gap_rmse(original, LONG_RANGE_GAP),
    }
}

/// The mean over `i` of the RMSE between `frames[i]` and `frames[i + gap]`; `None` when no
/// pair is `gap` apart (or `gap` is 0).
pub fn frame_gap_rmse(frames: &[Image], gap: usize) -> Option<f64> {
    if gap == 0 || frames.len() <= gap {
        return None;
    }
    let pairs = frames.len() - gap;
    let sum: f64 = (0..pairs)
        .map(|i| rmse(&frames[i].data, &frames[i + gap].data))
        .sum();
    Some(sum / pairs as f64)
}

/// `sqrt(mean((a - b)^2))` over all values (in f64).
fn rmse(a: &[f32], b: &[f32]) -> f64 {
    let sum: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| {
            let d = f64::from(*x) - f64::from(*y);
            d * d
        })
        .sum();
    (sum / a.len().max(1) as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(v: f32) -> Image {
        Image::filled(4, 3, [v, v, v])
    }

    #[test]
    fn gaps_average_the_rmse_of_their_pairs() {
        // Values 0, 0.1, 0.2, ...: consecutive frames differ by 0.1 everywhere.
        let frames: Vec<Image> = (0..9).map(|k| flat(0.1 * k as f32)).collect();
        let short = frame_gap_rmse(&frames, 1).unwrap();
        let long = frame_gap_rmse(&frames, 7).unwrap();
        assert!(
            (short - 0.1).abs() < 1e-6 && (long - 0.7).abs() < 1e-6,
            "{short} {long}"
        );
        assert_eq!(frame_gap_rmse(&frames[..7], 7), None);
        assert_eq!(frame_gap_rmse(&frames, 0), None);
        let still: Vec<Image> = (0..9).map(|_| flat(0.4)).collect();
        let both = temporal_consistency(&still, &frames);
        assert_eq!(both.short_range_rmse, Some(0.0));
        assert!((both.original_long_range_rmse.unwrap() - 0.7).abs() < 1e-6);
    }
}
