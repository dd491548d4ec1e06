//! Pillow's bicubic resize of 8-bit images, bit for bit: what `Image.resize(size,
//! Image.BICUBIC)` (and so torchvision's `Resize` on a PIL image, as in OpenAI CLIP's
//! preprocess) does to an `L` or `RGB` image.
//!
//! Pillow (`libImaging/Resample.c`) resamples each axis with the antialiased bicubic filter
//! (Keys' cubic, `a = -0.5`, support 2 stretched by the downscale factor; the same taps as
//! [`crate::resize`]'s antialiased kernels). For 8-bit images the normalized weights are
//! rounded to fixed point with 22 fractional bits, and each output is the integer sum plus one
//! half, shifted back and clamped to `0..=255`. It resamples horizontally first, into an 8-bit
//! intermediate image, then vertically, and skips an axis whose size does not change.
//! Everything here is integer arithmetic after the weights, so it is exact, not approximate.

use crate::error::{Result, StyleLossError};
use crate::resize::{antialias_taps, pil_bicubic_filter};

/// Fractional bits of Pillow's 8-bit fixed-point weights (`PRECISION_BITS`).
const PRECISION_BITS: u32 = 32 - 8 - 2;

/// The fixed-point taps of one output sample: first input index and integer weights.
struct FixedTaps {
    first: usize,
    weights: Vec<i64>,
}

/// Pillow's `normalize_coeffs_8bpc`: each weight times `2^22`, rounded half away from zero by
/// adding `±0.5` and truncating.
fn fixed_taps(input: usize, output: usize) -> Vec<FixedTaps> {
    let unit = f64::from(1u32 << PRECISION_BITS);
    antialias_taps(pil_bicubic_filter, 2.0, input, output)
        .into_iter()
        .map(|taps| FixedTaps {
            first: taps.first,
            weights: taps
                .weights
                .iter()
                .map(|&w| {
                    let half = if w < 0.0 { -0.5 } else { 0.5 };
                    (half + w * unit) as i32 as i64
                })
                .collect(),
        })
        .collect()
}

/// Pillow's `clip8`: the accumulator back to 8 bits, clamped.
fn clip8(sum: i64) -> u8 {
    (sum >> PRECISION_BITS).clamp(0, 255) as u8
}

/// One output sample from inputs `value(first + k)` weighted by `taps`.
fn sample(taps: &FixedTaps, value: impl Fn(usize) -> u8) -> u8 {
    let start = 1i64 << (PRECISION_BITS - 1);
    let sum = taps.weights.iter().enumerate().fold(start, |acc, (k, &w)| {
        acc + i64::from(value(taps.first + k)) * w
    });
    clip8(sum)
}

/// Resizes planar 8-bit channels `[channels, h, w]` (row-major) to `[channels, out_h, out_w]`
/// exactly as Pillow's `Image.resize((out_w, out_h), Image.BICUBIC)` resizes an 8-bit `L` or
/// `RGB` image (channels are independent). Sizes are `(height, width)`; all must be positive
/// and `planes.len()` must be `channels * h * w`.
pub fn pil_bicubic_resize(
    planes: &[u8],
    channels: usize,
    input: (usize, usize),
    output: (usize, usize),
) -> Result<Vec<u8>> {
    let (h, w) = input;
    let (oh, ow) = output;
    if h == 0 || w == 0 || oh == 0 || ow == 0 || planes.len() != channels * h * w {
        return Err(StyleLossError::Input {
            name: "planes".into(),
            reason: format!(
                "{} values for {channels} channels of {h}x{w} resized to {oh}x{ow}: expected \
                 channels * h * w values and non-empty sizes",
                planes.len()
            ),
        });
    }
    // Horizontal pass into an 8-bit `[channels, h, ow]` image.
    let wide = if ow == w {
        planes.to_vec()
    } else {
        let taps = fixed_taps(w, ow);
        let mut out = Vec::with_capacity(channels * h * ow);
        for row in planes.chunks_exact(w) {
            out.extend(taps.iter().map(|t| sample(t, |x| row[x])));
        }
        out
    };
    // Vertical pass into `[channels, oh, ow]`.
    if oh == h {
        return Ok(wide);
    }
    let taps = fixed_taps(h, oh);
    let mut out = Vec::with_capacity(channels * oh * ow);
    for plane in wide.chunks_exact(h * ow) {
        for t in &taps {
            out.extend((0..ow).map(|x| sample(t, |y| plane[y * ow + x])));
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_sum_to_one_in_fixed_point() {
        // Downscale (stretched support), upscale and a non-integer factor.
        for (input, output) in [(800, 224), (13, 24), (83, 32), (5, 5)] {
            for taps in fixed_taps(input, output) {
                let sum: i64 = taps.weights.iter().sum();
                let unit = 1i64 << PRECISION_BITS;
                assert!((sum - unit).abs() <= taps.weights.len() as i64, "{sum}");
                assert!(taps.first + taps.weights.len() <= input);
            }
        }
        // An 800 -> 224 tap spans 2 * 2 * 800 / 224 = 14.3 inputs, not 4.
        let taps = fixed_taps(800, 224);
        assert!(taps[100].weights.len() >= 14, "{}", taps[100].weights.len());
    }

    #[test]
    fn flat_images_stay_flat_and_equal_sizes_are_the_identity() {
        let flat = vec![173u8; 2 * 37 * 51];
        let out = pil_bicubic_resize(&flat, 2, (37, 51), (11, 80)).unwrap();
        assert_eq!(out.len(), 2 * 11 * 80);
        assert!(out.iter().all(|&v| v == 173));
        let ramp: Vec<u8> = (0..3 * 4 * 6).map(|i| (i * 7 % 256) as u8).collect();
        assert_eq!(pil_bicubic_resize(&ramp, 3, (4, 6), (4, 6)).unwrap(), ramp);
    }

    #[test]
    fn overshoot_is_clamped() {
        // A step edge upsampled with a = -0.5 rings below 0 and above 255: clamped, not wrapped.
        let step: Vec<u8> = (0..8).map(|x| if x < 4 { 0 } else { 255 }).collect();
        let raw: Vec<i64> = fixed_taps(8, 32)
            .iter()
            .map(|t| {
                t.weights
                    .iter()
                    .enumerate()
                    .map(|(k, &w)| i64::from(step[t.first + k]) * w)
                    .sum()
            })
            .collect();
        assert!(raw.iter().any(|&s| s < 0));
        assert!(raw.iter().any(|&s| s >= 256 << PRECISION_BITS));
        let out = pil_bicubic_resize(&step, 1, (1, 8), (1, 32)).unwrap();
        assert_eq!(out[..8], [0; 8]);
        assert_eq!(out[24..], [255; 8]);
    }

    #[test]
    fn bad_sizes_are_errors() {
        assert!(pil_bicubic_resize(&[0; 6], 1, (2, 3), (0, 3)).is_err());
        assert!(pil_bicubic_resize(&[0; 5], 1, (2, 3), (2, 2)).is_err());
    }
}
