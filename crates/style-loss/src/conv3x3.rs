//! 3x3 convolution, stride 1, zero padding 1, of channels-last f32 images on the CPU.
//!
//! With the image zero-padded to `(h + 2) x (w + 2)` pixels and stored channels-last, the
//! `3 * cin` values a kernel row `dy` reads for an output pixel are contiguous in memory, and the
//! rows of consecutive output pixels are `cin` values apart. So the whole convolution is three
//! matrix products (one per kernel row) of `[h * (w + 2), 3 * cin]` views of the padded image
//! with `[3 * cin, cout]` kernel slices, accumulated into `[h * (w + 2), cout]`, with no im2col
//! copy. The two extra columns per output row are padding positions; they are dropped when the
//! rows are compacted. The products run in `gemm`, candle's own matrix-product crate.
//!
//! A forward convolution whose gradient is taken ([`Epilogue::ExactBiasRelu`]) accumulates in f64
//! and rounds once: its outputs are the exact sums rounded once (but where an exact sum lies
//! within an f64 rounding of its terms' sizes of a rounding's edge), so a
//! pre-activation a hair from 0 gets the ReLU decision of the exact network, not one that f32
//! summation order picks (PyTorch's f32 picks its own; where the two disagree, one unit's
//! decision moves the content gradient by 1e-3 relative or more). It costs twice the products.
//! (VGG's layers of 64 channels and more in and out take Winograd's F(4x4, 3x3) in f64 for
//! this instead, with the same outputs: `conv3x3_winograd_exact`; here, the first layer's 3
//! input channels.)
//! The ground truth's features take the same exact forward (equal pictures give equal
//! features); the backward (the adjoint on the gradient, which decides nothing) stays in f32.
#![allow(unsafe_code)]

use rayon::prelude::*;

/// A kernel laid out for [`conv3x3`]: `[3 (dy)][3 (dx) * cin][cout]`, row-major.
#[derive(Clone, Debug)]
pub(crate) struct PackedKernel {
    data: Vec<f32>,
    cin: usize,
    cout: usize,
}

impl PackedKernel {
    /// The convolution of PyTorch weights `[cout, cin, 3, 3]` (row-major in `weight`).
    pub(crate) fn forward(weight: &[f32], cout: usize, cin: usize) -> Self {
        Self::pack(cin, cout, |dy, dx, i, o| {
            weight[((o * cin + i) * 3 + dy) * 3 + dx]
        })
    }

    /// The adjoint of that convolution (the map of output gradients `cout` to input gradients
    /// `cin`): input and output channels swapped and the kernel flipped in both directions.
    pub(crate) fn adjoint(weight: &[f32], cout: usize, cin: usize) -> Self {
        Self::pack(cout, cin, |dy, dx, i, o| {
            weight[((i * cin + o) * 3 + (2 - dy)) * 3 + (2 - dx)]
        })
    }

    /// `tap(dy, dx, input channel, output channel)` for a kernel from `cin` to `cout` channels.
    fn pack(cin: usize, cout: usize, tap: impl Fn(usize, usize, usize, usize) -> f32) -> Self {
        let mut data = Vec::with_capacity(9 * cin * cout);
        for dy in 0..3 {
            for dx in 0..3 {
                for i in 0..cin {
                    data.extend((0..cout).map(|o| tap(dy, dx, i, o)));
                }
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

    /// The taps, `[3 (dy)][3 (dx) * cin][cout]`, row-major.
    pub(crate) fn taps(&self) -> &[f32] {
        &self.data
    }
}

/// What is applied to each output value after the products.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Epilogue<'a> {
    /// `relu(v + bias[channel])`, NaN kept (PyTorch's `relu`), in f32.
    BiasRelu(&'a [f32]),
    /// The same with the products accumulated in f64, the bias added and the ReLU decided
    /// there, and the result rounded once to f32.
    ExactBiasRelu(&'a [f32]),
    /// The value as it is.
    Identity,
}

/// Channels-last images `[images, h, w, channels]`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ImageShape {
    /// Number of images.
    pub images: usize,
    /// Rows.
    pub h: usize,
    /// Columns.
    pub w: usize,
}

/// Convolves `input` (`[images, h, w, kernel.cin()]`) with `kernel`; returns
/// `[images, h, w, kernel.cout()]`. With `input_gate`, an input value counts only where the gate
/// (same shape as `input`) is above 0, and as 0 elsewhere (the ReLU mask of a backward pass;
/// NaN in the gate passes, as PyTorch's `threshold_backward`). `scratch` holds the padded
/// image; it is reused across calls. [`Epilogue::ExactBiasRelu`] takes no gate.
pub(crate) fn conv3x3(
    input: &[f32],
    shape: ImageShape,
    kernel: &PackedKernel,
    input_gate: Option<&[f32]>,
    epilogue: Epilogue<'_>,
    scratch: &mut Vec<f32>,
) -> Vec<f32> {
    let ImageShape { images, h, w } = shape;
    let (cin, cout) = (kernel.cin, kernel.cout);
    let (in_len, out_len) = (h * w * cin, h * w * cout);
    assert_eq!(input.len(), images * in_len, "conv3x3: input size");
    assert!(input_gate.is_none_or(|g| g.len() == input.len()));
    if let Epilogue::ExactBiasRelu(bias) = epilogue {
        assert!(
            input_gate.is_none(),
            "conv3x3: a forward convolution has no gate"
        );
        let band = band_rows(w, cin.max(cout));
        return conv3x3_bias_relu_f64(input, shape, kernel, bias, band);
    }
    let padded_w = w + 2;
    let rows = h * padded_w;
    // Two more padded pixels than the image: the products' last rows read up to
    // `(h + 2) * (w + 2) + 1` pixels in (their outputs are dropped).
    let padded_len = ((h + 2) * padded_w + 2) * cin;
    // Room for the last image's uncompacted rows.
    let mut out = vec![0f32; images * out_len + 2 * h * cout];
    for image in 0..images {
        let gate = input_gate.map(|g| &g[image * in_len..(image + 1) * in_len]);
        pad(
            &input[image * in_len..(image + 1) * in_len],
            gate,
            h,
            w,
            cin,
            padded_len,
            scratch,
        );
        let dst = &mut out[image * out_len..image * out_len + rows * cout];
        kernel_row_products(dst, scratch, &kernel.data, rows, padded_w, cin, cout, 1.0);
        compact_rows(&mut out[image * out_len..], h, w, cout, epilogue);
    }
    out.truncate(images * out_len);
    out
}

/// The three products of a 3x3 convolution, one per kernel row `dy`, accumulated into `dst`
/// (`[m, cout]`, row-major): the `m x 3cin` view of `padded` starting at padded row `dy` (row
/// stride `cin`, rows `padded_w` pixels long) times the `3cin x cout` slice `dy` of `taps`.
/// `one` is the element type's 1.
#[allow(clippy::too_many_arguments)]
fn kernel_row_products<T: Copy + 'static>(
    dst: &mut [T],
    padded: &[T],
    taps: &[T],
    m: usize,
    padded_w: usize,
    cin: usize,
    cout: usize,
    one: T,
) {
    assert!(dst.len() >= m * cout, "conv3x3: destination size");
    for dy in 0..3 {
        let lhs = &padded[dy * padded_w * cin..];
        let rhs = &taps[dy * 3 * cin * cout..(dy + 1) * 3 * cin * cout];
        assert!((m - 1) * cin + 3 * cin <= lhs.len(), "conv3x3: padded size");
        // SAFETY: `dst` holds `m x cout` (row stride `cout`, column stride 1: checked above);
        // `lhs` is read as `m x 3cin` with row stride `cin` and column stride 1, whose last
        // element `(m - 1) * cin + 3cin - 1` lies inside `lhs` (checked above: the padded
        // buffers have two spare pixels); `rhs` is `3cin x cout`, row-major, exactly its length.
        // `dst` is a buffer of its own, apart from `padded` and `taps`.
        unsafe {
            gemm::gemm(
                m,
                cout,
                3 * cin,
                dst.as_mut_ptr(),
                1,
                cout as isize,
                dy > 0,
                lhs.as_ptr(),
                1,
                cin as isize,
                rhs.as_ptr(),
                1,
                cout as isize,
                one,
                one,
                false,
                false,
                false,
                gemm::Parallelism::Rayon(0),
            );
        }
    }
}

/// Output rows per band of [`conv3x3_bias_relu_f64`]: about 2M f64 values (16 MB) in each of its
/// two buffers.
pub(crate) fn band_rows(w: usize, channels: usize) -> usize {
    (2_000_000 / ((w + 2) * channels).max(1)).max(1)
}

/// [`conv3x3`] without a gate and with [`Epilogue::ExactBiasRelu`]: the same three
/// products per band of output rows, on f64 copies of the band's padded input and of the kernel,
/// then `relu(sum + bias)` decided in f64 and rounded once to f32. `band` output rows at a time.
fn conv3x3_bias_relu_f64(
    input: &[f32],
    shape: ImageShape,
    kernel: &PackedKernel,
    bias: &[f32],
    band: usize,
) -> Vec<f32> {
    let ImageShape { images, h, w } = shape;
    let (cin, cout) = (kernel.cin, kernel.cout);
    let (in_len, out_len) = (h * w * cin, h * w * cout);
    let taps: Vec<f64> = kernel.data.par_iter().map(|&v| v as f64).collect();
    let padded_w = w + 2;
    let band = band.clamp(1, h.max(1));
    let mut out = vec![0f32; images * out_len];
    let mut padded: Vec<f64> = Vec::new();
    let mut dst: Vec<f64> = Vec::new();
    for image in 0..images {
        let src = &input[image * in_len..(image + 1) * in_len];
        for y0 in (0..h).step_by(band) {
            let rows_here = band.min(h - y0);
            // Padded rows y0 - 1 ..= y0 + rows_here, and two spare pixels the last product reads.
            let row_len = padded_w * cin;
            padded.clear();
            padded.resize((rows_here + 2) * row_len + 2 * cin, 0.0);
            padded[..(rows_here + 2) * row_len]
                .par_chunks_mut(row_len)
                .enumerate()
                .for_each(|(r, row)| {
                    let Some(y) = (y0 + r).checked_sub(1).filter(|&y| y < h) else {
                        return;
                    };
                    let from = &src[y * w * cin..(y + 1) * w * cin];
                    for (d, &v) in row[cin..(w + 1) * cin].iter_mut().zip(from) {
                        *d = v as f64;
                    }
                });
            let m = rows_here * padded_w;
            dst.clear();
            dst.resize(m * cout, 0.0);
            kernel_row_products(&mut dst, &padded, &taps, m, padded_w, cin, cout, 1.0);
            let first = image * out_len + y0 * w * cout;
            out[first..first + rows_here * w * cout]
                .par_chunks_mut(w * cout)
                .zip(dst.par_chunks(padded_w * cout))
                .for_each(|(row, sums)| {
                    for (pixel, sums) in row.chunks_exact_mut(cout).zip(sums.chunks_exact(cout)) {
                        for ((v, &sum), &b) in pixel.iter_mut().zip(sums).zip(bias) {
                            let x = sum + b as f64;
                            // PyTorch's relu: NaN kept.
                            *v = if x < 0.0 { 0.0 } else { x as f32 };
                        }
                    }
                });
        }
    }
    out
}

/// Writes `image` (`[h, w, cin]`, gated) into `padded` as `[(h + 2) * (w + 2) + 2, cin]` with
/// zeros around it.
fn pad(
    image: &[f32],
    gate: Option<&[f32]>,
    h: usize,
    w: usize,
    cin: usize,
    padded_len: usize,
    padded: &mut Vec<f32>,
) {
    padded.clear();
    padded.resize(padded_len, 0.0);
    let row_len = (w + 2) * cin;
    padded[row_len..(h + 1) * row_len]
        .par_chunks_mut(row_len)
        .enumerate()
        .for_each(|(y, row)| {
            let src = &image[y * w * cin..(y + 1) * w * cin];
            let dst = &mut row[cin..(w + 1) * cin];
            match gate {
                None => dst.copy_from_slice(src),
                Some(gate) => {
                    let gate = &gate[y * w * cin..(y + 1) * w * cin];
                    for ((d, &s), &g) in dst.iter_mut().zip(src).zip(gate) {
                        // PyTorch's threshold_backward: zero where the output is <= 0.
                        *d = if g <= 0.0 { 0.0 } else { s };
                    }
                }
            }
        });
}

/// Moves the `h` output rows of `w + 2` pixels to rows of `w` pixels (dropping the two padding
/// positions of each) and applies `epilogue` ([`Epilogue::BiasRelu`] or none).
fn compact_rows(out: &mut [f32], h: usize, w: usize, cout: usize, epilogue: Epilogue<'_>) {
    for y in 0..h {
        let src = y * (w + 2) * cout;
        let dst = y * w * cout;
        out.copy_within(src..src + w * cout, dst);
        if let Epilogue::BiasRelu(bias) = epilogue {
            for pixel in out[dst..dst + w * cout].chunks_exact_mut(cout) {
                for (v, &b) in pixel.iter_mut().zip(bias) {
                    let x = *v + b;
                    *v = if x < 0.0 { 0.0 } else { x };
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Direct convolution, NCHW weights, f64 accumulation: the oracle.
    fn direct(
        input: &[f32],
        h: usize,
        w: usize,
        weight: &[f32],
        cout: usize,
        cin: usize,
    ) -> Vec<f64> {
        let mut out = vec![0f64; h * w * cout];
        for y in 0..h {
            for x in 0..w {
                for o in 0..cout {
                    let mut acc = 0f64;
                    for dy in 0..3 {
                        for dx in 0..3 {
                            let (sy, sx) =
                                (y as isize + dy as isize - 1, x as isize + dx as isize - 1);
                            if sy < 0 || sx < 0 || sy >= h as isize || sx >= w as isize {
                                continue;
                            }
                            for i in 0..cin {
                                let v = input[((sy as usize) * w + sx as usize) * cin + i];
                                acc += v as f64 * weight[((o * cin + i) * 3 + dy) * 3 + dx] as f64;
                            }
                        }
                    }
                    out[(y * w + x) * cout + o] = acc;
                }
            }
        }
        out
    }

    fn values(len: usize, seed: usize) -> Vec<f32> {
        (0..len)
            .map(|i| (((i * 7919 + seed * 104_729) % 2001) as f32 - 1000.0) * 1e-3)
            .collect()
    }

    #[test]
    fn matches_a_direct_convolution_on_odd_shapes() {
        for (h, w, cin, cout) in [(1, 1, 1, 1), (3, 5, 2, 3), (7, 4, 5, 9), (6, 6, 16, 8)] {
            let input = values(2 * h * w * cin, h + cin);
            let weight = values(cout * cin * 9, w + cout);
            let kernel = PackedKernel::forward(&weight, cout, cin);
            let shape = ImageShape { images: 2, h, w };
            let out = conv3x3(
                &input,
                shape,
                &kernel,
                None,
                Epilogue::Identity,
                &mut Vec::new(),
            );
            for image in 0..2 {
                let len = h * w * cin;
                let expected = direct(
                    &input[image * len..(image + 1) * len],
                    h,
                    w,
                    &weight,
                    cout,
                    cin,
                );
                let got = &out[image * h * w * cout..(image + 1) * h * w * cout];
                for (g, e) in got.iter().zip(&expected) {
                    assert!(
                        (*g as f64 - e).abs() < 1e-5,
                        "{h}x{w} {cin}->{cout}: {g} vs {e}"
                    );
                }
            }
        }
    }

    #[test]
    fn the_adjoint_is_the_transpose() {
        // <conv(x), y> = <x, adjoint(y)> for random x, y.
        let (h, w, cin, cout) = (5, 6, 3, 4);
        let weight = values(cout * cin * 9, 3);
        let x = values(h * w * cin, 1);
        let y = values(h * w * cout, 2);
        let shape = ImageShape { images: 1, h, w };
        let mut scratch = Vec::new();
        let forward = PackedKernel::forward(&weight, cout, cin);
        let adjoint = PackedKernel::adjoint(&weight, cout, cin);
        let ax = conv3x3(&x, shape, &forward, None, Epilogue::Identity, &mut scratch);
        let aty = conv3x3(&y, shape, &adjoint, None, Epilogue::Identity, &mut scratch);
        let dot = |a: &[f32], b: &[f32]| {
            a.iter()
                .zip(b)
                .map(|(p, q)| *p as f64 * *q as f64)
                .sum::<f64>()
        };
        let (lhs, rhs) = (dot(&ax, &y), dot(&x, &aty));
        assert!(
            (lhs - rhs).abs() < 1e-4 * lhs.abs().max(1.0),
            "{lhs} vs {rhs}"
        );
    }

    #[test]
    fn bias_relu_and_the_gate_follow_pytorch() {
        // One channel, identity centre tap: output = relu(x + bias).
        let mut weight = vec![0f32; 9];
        weight[4] = 1.0;
        let kernel = PackedKernel::forward(&weight, 1, 1);
        let shape = ImageShape {
            images: 1,
            h: 1,
            w: 4,
        };
        let x = [-2.0, -1.0, 0.5, 3.0];
        let out = conv3x3(
            &x,
            shape,
            &kernel,
            None,
            Epilogue::BiasRelu(&[1.0]),
            &mut Vec::new(),
        );
        assert_eq!(out, [0.0, 0.0, 1.5, 4.0]);
        // A gate passes where it is > 0 or NaN, not at exactly 0 or below.
        let gate = [0.0, -1.0, 1.5, f32::NAN];
        let g = [1.0, 2.0, 3.0, 4.0];
        let gated = conv3x3(
            &g,
            shape,
            &kernel,
            Some(&gate),
            Epilogue::Identity,
            &mut Vec::new(),
        );
        assert_eq!(gated, [0.0, 0.0, 3.0, 4.0]);
    }

    /// The exact sum 2^-25 of `1 + 2^-25 - 1` survives the exact ReLU (summed in f32 from the
    /// left, `1 + 2^-25` rounds to 1 and the gate closes), and `1 - 2^-25 - 1` does not.
    #[test]
    fn a_pre_activation_a_hair_above_zero_passes_the_relu() {
        let mut weight = vec![0f32; 3 * 9];
        for i in 0..3 {
            weight[i * 9 + 4] = 1.0;
        }
        let kernel = PackedKernel::forward(&weight, 1, 3);
        let tiny = 2f32.powi(-25);
        let shape = ImageShape {
            images: 1,
            h: 1,
            w: 1,
        };
        let out = conv3x3(
            &[1.0, tiny, -1.0],
            shape,
            &kernel,
            None,
            Epilogue::ExactBiasRelu(&[0.0]),
            &mut Vec::new(),
        );
        assert_eq!(out, [tiny]);
        let out = conv3x3(
            &[1.0, -tiny, -1.0],
            shape,
            &kernel,
            None,
            Epilogue::ExactBiasRelu(&[0.0]),
            &mut Vec::new(),
        );
        assert_eq!(out, [0.0]);
    }

    /// The f64 forward equals the f64 direct convolution rounded once, in one band or many.
    #[test]
    fn the_forward_is_the_rounded_exact_sum_in_any_band() {
        let (h, w, cin, cout) = (7, 5, 6, 4);
        let input = values(2 * h * w * cin, 4);
        let weight = values(cout * cin * 9, 9);
        let bias = [0.3f32, -0.2, 0.0, 0.01];
        let kernel = PackedKernel::forward(&weight, cout, cin);
        let shape = ImageShape { images: 2, h, w };
        let whole = conv3x3_bias_relu_f64(&input, shape, &kernel, &bias, h);
        for band in [1, 2, 3] {
            let banded = conv3x3_bias_relu_f64(&input, shape, &kernel, &bias, band);
            assert_eq!(banded, whole, "band {band}");
        }
        for image in 0..2 {
            let len = h * w * cin;
            let exact = direct(
                &input[image * len..(image + 1) * len],
                h,
                w,
                &weight,
                cout,
                cin,
            );
            let got = &whole[image * h * w * cout..(image + 1) * h * w * cout];
            for (k, (g, e)) in got.iter().zip(&exact).enumerate() {
                let x = e + bias[k % cout] as f64;
                let expected = if x < 0.0 { 0.0 } else { x as f32 };
                assert!(
                    (g - expected).abs() <= 1e-7 * expected.abs(),
                    "{g} vs {expected}"
                );
            }
        }
    }
}
