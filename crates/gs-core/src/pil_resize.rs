//! Pillow's bicubic resize of 8-bit images, bit for bit: what `Image.resize(size,
//! Image.BICUBIC)` (and so torchvision's `Resize` on a PIL image, as in OpenAI CLIP's
//! preprocess, and INRIA 3DGS's loader with its default filter) does to an `L`, `RGB` or `RGBA`
//! image. An `RGBA` image is resized premultiplied, as Pillow does ([`pil_rgba_resize`]).
//!
//! Pillow (`libImaging/Resample.c`) resamples each axis with the antialiased bicubic filter
//! (Keys' cubic, `a = -0.5`, support 2 stretched by the downscale factor; the same taps as
//! the antialiased kernels of PyTorch's `interpolate`, [`antialias_taps`]). For 8-bit images the normalized weights are
//! rounded to fixed point with 22 fractional bits, and each output is the integer sum plus one
//! half, shifted back and clamped to `0..=255`. It resamples horizontally first, into an 8-bit
//! intermediate image, then vertically, and skips an axis whose size does not change.
//! Everything here is integer arithmetic after the weights, so it is exact, not approximate.

/// The bicubic filter of PIL and of PyTorch's antialiased bicubic: Keys' cubic with `a = -0.5`
/// (not PyTorch's plain bicubic `a = -0.75`), support 2, written as Pillow's `bicubic_filter`.
pub fn pil_bicubic_filter(x: f64) -> f64 {
    const A: f64 = -0.5;
    let x = x.abs();
    if x < 1.0 {
        ((A + 2.0) * x - (A + 3.0)) * x * x + 1.0
    } else if x < 2.0 {
        (((x - 5.0) * x + 8.0) * x - 4.0) * A
    } else {
        0.0
    }
}

/// The taps of one output sample of an antialiased resize: the weights of the consecutive
/// inputs `first..first + weights.len()`.
#[derive(Clone, Debug, PartialEq)]
pub struct AxisTaps {
    /// The first input sample.
    pub first: usize,
    /// The weight of each input sample from `first` on.
    pub weights: Vec<f64>,
}

/// Taps of output `i` of an antialiased resize of one axis (`scale = input / output`) with
/// `filter` of half-width `support` (in input pixels at scale 1): Pillow's `precompute_coeffs`
/// with the full box, which PyTorch's `antialias=True` kernels copy. The filter is stretched by
/// the downscale factor, centred at `scale (i + 0.5)`, cut to `[center - support + 0.5,
/// center + support + 0.5)` truncated toward zero (the C casts) and clamped to the image, and
/// normalized to sum 1 (left as is when the sum is 0).
pub fn antialias_taps_of(
    filter: fn(f64) -> f64,
    support: f64,
    input: usize,
    scale: f64,
    i: usize,
) -> AxisTaps {
    let filter_scale = scale.max(1.0);
    let support = support * filter_scale;
    let inv_scale = 1.0 / filter_scale;
    let center = scale * (i as f64 + 0.5);
    let lo = ((center - support + 0.5) as i64).max(0) as usize;
    let hi = ((center + support + 0.5) as i64).min(input as i64) as usize;
    let mut weights: Vec<f64> = (lo..hi.max(lo))
        .map(|j| filter((j as f64 - center + 0.5) * inv_scale))
        .collect();
    let total: f64 = weights.iter().sum();
    if total != 0.0 {
        weights.iter_mut().for_each(|w| *w /= total);
    }
    AxisTaps { first: lo, weights }
}

/// Taps of every output sample of an antialiased resize of one axis from `input` to `output`
/// samples (see [`antialias_taps_of`]).
pub fn antialias_taps(
    filter: fn(f64) -> f64,
    support: f64,
    input: usize,
    output: usize,
) -> Vec<AxisTaps> {
    let scale = input as f64 / output as f64;
    (0..output)
        .map(|i| antialias_taps_of(filter, support, input, scale, i))
        .collect()
}

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
) -> Result<Vec<u8>, ResizeError> {
    let (h, w) = input;
    let (oh, ow) = output;
    if h == 0 || w == 0 || oh == 0 || ow == 0 || planes.len() != channels * h * w {
        return Err(ResizeError(format!(
            "{} values for {channels} channels of {h}x{w} resized to {oh}x{ow}: expected \
             channels * h * w values and non-empty sizes",
            planes.len()
        )));
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

/// A resize that cannot be done: the sizes or the number of values do not fit.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("resize: {0}")]
pub struct ResizeError(pub String);

/// Pillow's `MULDIV255`: `round(a * b / 255)` in integers, as its `RGBA` to `RGBa` conversion
/// premultiplies.
fn muldiv255(a: u8, b: u8) -> u8 {
    let t = u32::from(a) * u32::from(b) + 128;
    (((t >> 8) + t) >> 8) as u8
}

/// Resizes interleaved 8-bit `RGBA` pixels `[h, w, 4]` to `[out_h, out_w, 4]` exactly as
/// Pillow's `Image.resize((out_w, out_h), Image.BICUBIC)` resizes an `RGBA` image: converted to
/// premultiplied `RGBa` (`MULDIV255`), resized ([`pil_bicubic_resize`], alpha as a fourth
/// channel), converted back (a colour times 255 divided by its alpha, truncated and clamped;
/// kept as it is where alpha is 0 or 255). A picture asked for at its own size is returned as it
/// is, as Pillow copies it without the round trip. Sizes are `(height, width)`.
pub fn pil_rgba_resize(
    rgba: &[u8],
    input: (usize, usize),
    output: (usize, usize),
) -> Result<Vec<u8>, ResizeError> {
    let (h, w) = input;
    if rgba.len() != 4 * h * w {
        return Err(ResizeError(format!(
            "{} values for {h}x{w} RGBA pixels",
            rgba.len()
        )));
    }
    if input == output {
        return Ok(rgba.to_vec());
    }
    let n = h * w;
    let mut planes = vec![0u8; 4 * n];
    for (p, px) in rgba.chunks_exact(4).enumerate() {
        for c in 0..3 {
            planes[c * n + p] = muldiv255(px[c], px[3]);
        }
        planes[3 * n + p] = px[3];
    }
    let resized = pil_bicubic_resize(&planes, 4, input, output)?;
    let m = output.0 * output.1;
    let mut out = Vec::with_capacity(4 * m);
    for p in 0..m {
        let alpha = resized[3 * m + p];
        for c in 0..3 {
            let v = resized[c * m + p];
            out.push(match alpha {
                0 | 255 => v,
                a => (255 * u32::from(v) / u32::from(a)).min(255) as u8,
            });
        }
        out.push(alpha);
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
