//! 3x3 convolution, stride 1, zero padding 1, of channels-last f32 images with bf16 products
//! (gemmkit's bf16 kernel: f32 sums, each output rounded once to bf16).
//!
//! Each band of output rows is written once in bf16 as rows of `3 * cin` values, one per padded
//! pixel, holding the pixel and the two below it (kernel rows `dy` = 0, 1, 2). The `9 * cin`
//! values an output pixel reads are then the rows of three consecutive pixels, contiguous, and
//! consecutive output pixels start `3 * cin` values apart: the whole band is one product of a
//! `[rows * (w + 2), 9 * cin]` view with the `[9 * cin, cout]` kernel. The two padding columns
//! of each output row are dropped when the outputs are widened to f32, with the bias and ReLU
//! applied in f32 on the rounded sums.

use gemmkit::{gemm, MatMut, MatRef, Parallelism};
use half::bf16;
use rayon::prelude::*;

use crate::bf16_product::round_to_bf16;
use crate::conv3x3::{band_rows, ImageShape, PackedKernel};

/// A kernel for [`conv3x3_bf16`]: `[3 (dx)][3 (dy)][cin][cout]`, row-major, bf16.
#[derive(Clone, Debug)]
pub(crate) struct StackedKernel {
    data: Vec<bf16>,
    cin: usize,
    cout: usize,
}

impl StackedKernel {
    /// `kernel`'s taps, rounded to bf16, in the order of the stacked rows.
    pub(crate) fn new(kernel: &PackedKernel) -> Self {
        let (cin, cout) = (kernel.cin(), kernel.cout());
        let block = cin * cout;
        let taps = kernel.taps();
        let mut data = Vec::with_capacity(9 * block);
        for dx in 0..3 {
            for dy in 0..3 {
                let start = (dy * 3 + dx) * block;
                data.extend(
                    taps[start..start + block]
                        .iter()
                        .map(|&v| bf16::from_f32(v)),
                );
            }
        }
        Self { data, cin, cout }
    }

    /// Input channels.
    pub(crate) fn cin(&self) -> usize {
        self.cin
    }

    /// Output channels.
    pub(crate) fn cout(&self) -> usize {
        self.cout
    }
}

/// Convolves `input` (`[images, h, w, kernel.cin()]`) with `kernel`, then adds `bias` and
/// applies PyTorch's ReLU (NaN kept) when there is one; returns `[images, h, w, kernel.cout()]`.
/// With `input_gate`, an input value counts only where the gate is above 0 (NaN passes), as in
/// `conv3x3`.
pub(crate) fn conv3x3_bf16(
    input: &[f32],
    shape: ImageShape,
    kernel: &StackedKernel,
    input_gate: Option<&[f32]>,
    bias: Option<&[f32]>,
) -> Vec<f32> {
    let band = band_rows(shape.w, kernel.cin.max(kernel.cout));
    conv3x3_bf16_in_bands(input, shape, kernel, input_gate, bias, band)
}

/// [`conv3x3_bf16`], `band` output rows at a time.
fn conv3x3_bf16_in_bands(
    input: &[f32],
    shape: ImageShape,
    kernel: &StackedKernel,
    input_gate: Option<&[f32]>,
    bias: Option<&[f32]>,
    band: usize,
) -> Vec<f32> {
    let ImageShape { images, h, w } = shape;
    let (cin, cout) = (kernel.cin, kernel.cout);
    let (in_len, out_len) = (h * w * cin, h * w * cout);
    assert_eq!(input.len(), images * in_len, "conv3x3_bf16: input size");
    assert!(input_gate.is_none_or(|g| g.len() == input.len()));
    assert!(bias.is_none_or(|b| b.len() == cout));
    let padded_w = w + 2;
    let band = band.clamp(1, h.max(1));
    let mut out = vec![0f32; images * out_len];
    let mut stacked: Vec<bf16> = Vec::new();
    let mut sums: Vec<bf16> = Vec::new();
    for image in 0..images {
        let src = &input[image * in_len..(image + 1) * in_len];
        let gate = input_gate.map(|g| &g[image * in_len..(image + 1) * in_len]);
        for y0 in (0..h).step_by(band) {
            let rows_here = band.min(h - y0);
            let m = rows_here * padded_w;
            // Two spare pixels: the last row's dropped outputs read up to two past its end.
            stacked.clear();
            stacked.resize((m + 2) * 3 * cin, bf16::ZERO);
            stacked[..m * 3 * cin]
                .par_chunks_mut(padded_w * 3 * cin)
                .enumerate()
                .for_each(|(r, row)| {
                    for (x, pixel) in row.chunks_exact_mut(3 * cin).enumerate() {
                        for (dy, values) in pixel.chunks_exact_mut(cin).enumerate() {
                            // Padded row y0 + r + dy is image row y0 + r + dy - 1.
                            let y = (y0 + r + dy).checked_sub(1).filter(|&y| y < h);
                            let x = x.checked_sub(1).filter(|&x| x < w);
                            let (Some(y), Some(x)) = (y, x) else { continue };
                            let at = (y * w + x) * cin;
                            let from = &src[at..at + cin];
                            match gate {
                                None => {
                                    for (d, &v) in values.iter_mut().zip(from) {
                                        *d = round_to_bf16(v);
                                    }
                                }
                                Some(gate) => {
                                    let gate = &gate[at..at + cin];
                                    for ((d, &v), &g) in values.iter_mut().zip(from).zip(gate) {
                                        // PyTorch's threshold_backward: zero where the output
                                        // is <= 0.
                                        *d = round_to_bf16(if g <= 0.0 { 0.0 } else { v });
                                    }
                                }
                            }
                        }
                    }
                });
            sums.clear();
            sums.resize(m * cout, bf16::ZERO);
            gemm(
                bf16::ONE,
                MatRef::new(&stacked, m, 9 * cin, (3 * cin) as isize, 1),
                MatRef::from_row_major(&kernel.data, 9 * cin, cout),
                bf16::ZERO,
                MatMut::from_row_major(&mut sums, m, cout),
                Parallelism::Rayon(0),
            );
            let first = image * out_len + y0 * w * cout;
            out[first..first + rows_here * w * cout]
                .par_chunks_mut(w * cout)
                .zip(sums.par_chunks(padded_w * cout))
                .for_each(|(row, sums)| {
                    for (pixel, sums) in row.chunks_exact_mut(cout).zip(sums.chunks_exact(cout)) {
                        for (o, (v, &sum)) in pixel.iter_mut().zip(sums).enumerate() {
                            *v = match bias {
                                // PyTorch's relu: NaN kept.
                                Some(bias) => {
                                    let x = sum.to_f32() + bias[o];
                                    if x < 0.0 {
                                        0.0
                                    } else {
                                        x
                                    }
                                }
                                None => sum.to_f32(),
                            };
                        }
                    }
                });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn values(len: usize, seed: usize) -> Vec<f32> {
        (0..len)
            .map(|i| ((i * 7919 + seed * 104_729) % 1999) as f32 / 999.5 - 1.0)
            .collect()
    }

    fn round(v: f32) -> f64 {
        bf16::from_f32(v).to_f64()
    }

    /// The direct convolution of the bf16-rounded input (gated) and kernel in f64, and the sum
    /// of the magnitudes of its terms, per output `[images, h, w, cout]`.
    #[allow(clippy::too_many_arguments)]
    fn direct(
        input: &[f32],
        gate: Option<&[f32]>,
        weight: &[f32],
        shape: ImageShape,
        cin: usize,
        cout: usize,
    ) -> Vec<(f64, f64)> {
        let ImageShape { images, h, w } = shape;
        let mut out = Vec::with_capacity(images * h * w * cout);
        for n in 0..images {
            for y in 0..h {
                for x in 0..w {
                    for o in 0..cout {
                        let (mut sum, mut magnitude) = (0f64, 0f64);
                        for dy in 0..3 {
                            for dx in 0..3 {
                                let (Some(yy), Some(xx)) = (
                                    (y + dy).checked_sub(1).filter(|&v| v < h),
                                    (x + dx).checked_sub(1).filter(|&v| v < w),
                                ) else {
                                    continue;
                                };
                                for i in 0..cin {
                                    let at = ((n * h + yy) * w + xx) * cin + i;
                                    if gate.is_some_and(|g| g[at] <= 0.0) {
                                        continue;
                                    }
                                    let t = round(input[at])
                                        * round(weight[((o * cin + i) * 3 + dy) * 3 + dx]);
                                    sum += t;
                                    magnitude += t.abs();
                                }
                            }
                        }
                        out.push((sum, magnitude));
                    }
                }
            }
        }
        out
    }

    #[test]
    fn matches_the_rounded_direct_convolution_in_any_band_with_and_without_gate() {
        for (images, h, w, cin, cout) in [(2, 5, 7, 3, 5), (1, 1, 1, 2, 3), (1, 6, 4, 17, 9)] {
            let shape = ImageShape { images, h, w };
            let input = values(images * h * w * cin, 1);
            let weight = values(cout * cin * 9, 2);
            let bias = values(cout, 3);
            let gate = values(input.len(), 4);
            let kernel = StackedKernel::new(&PackedKernel::forward(&weight, cout, cin));
            for band in [1, 2, h] {
                for gated in [false, true] {
                    let g = gated.then_some(gate.as_slice());
                    let want = direct(&input, g, &weight, shape, cin, cout);
                    let plain = conv3x3_bf16_in_bands(&input, shape, &kernel, g, None, band);
                    let relu = conv3x3_bf16_in_bands(&input, shape, &kernel, g, Some(&bias), band);
                    for (k, ((&got, &with_bias), &(exact, magnitude))) in
                        plain.iter().zip(&relu).zip(&want).enumerate()
                    {
                        // One bf16 rounding of the sum and the f32 summation's bound.
                        let bound = exact.abs() / 256.0 + 40.0 * cin as f64 * magnitude / 1.6e7;
                        let context = format!(
                            "{images}x{h}x{w}x{cin}->{cout} band {band} gate {gated} [{k}]"
                        );
                        assert!(
                            (got as f64 - exact).abs() <= bound,
                            "{context}: {got} against {exact}"
                        );
                        let b = bias[k % cout];
                        let expected = (got + b).max(0.0);
                        assert_eq!(with_bias, expected, "{context}: bias and ReLU on the sum");
                    }
                }
            }
        }
    }

    #[test]
    fn a_nan_input_reaches_its_outputs_and_a_nan_gate_passes() {
        let shape = ImageShape {
            images: 1,
            h: 3,
            w: 3,
        };
        let mut input = vec![1f32; 9];
        input[4] = f32::NAN;
        let kernel = StackedKernel::new(&PackedKernel::forward(&[1f32; 9], 1, 1));
        let out = conv3x3_bf16(&input, shape, &kernel, None, Some(&[0.5]));
        assert!(
            out.iter().all(|v| v.is_nan()),
            "every output reads the centre: {out:?}"
        );
        let mut gate = vec![1f32; 9];
        gate[4] = f32::NAN;
        gate[0] = 0.0;
        let gated = conv3x3_bf16(&input, shape, &kernel, Some(&gate), None);
        assert!(
            gated.iter().all(|v| v.is_nan()),
            "a NaN gate passes: {gated:?}"
        );
        input[4] = 1.0;
        let gated = conv3x3_bf16(&input, shape, &kernel, Some(&gate), None);
        // The corner (gate 0) counts as 0: the centre output sums 8 ones.
        assert_eq!(gated[4], 8.0);
        assert_eq!(gated[8], 4.0);
        assert_eq!(gated[0], 3.0);
    }
}
