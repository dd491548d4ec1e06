//! 3x3 convolution, stride 1, zero padding 1, of channels-last f32 images on the CPU by
//! Winograd's minimal filtering F(2x2, 3x3) (Lavin and Gray, "Fast Algorithms for
//! Convolutional Neural Networks", 2016), with bias and ReLU (a forward) or with the input gated
//! by a ReLU mask (a backward's adjoint convolution).
//!
//! Each 2x2 block of outputs is computed from the 4x4 block of padded input around it: the
//! input block is transformed (`V = Bᵀ d B`), multiplied element by element with the transformed
//! kernel (`U = G g Gᵀ`, 16 numbers per input and output channel, computed once), and
//! transformed back (`Y = Aᵀ M A`). Summed over the input channels, each of the 16 element-wise
//! products is a matrix product `[blocks, cin] x [cin, cout]`: 16 products of 16 multiplies per
//! 4 outputs, where the direct convolution takes 36, so 2.25 times fewer multiply-adds.
//!
//! The transforms add and halve, so the outputs carry a few more f32 roundings than the direct
//! convolution's, and other ones (errors up to 1.4e-7 of the largest output in the tests, the
//! order of an f32 sum's). VGG runs it on its wide layers only (`vgg_channels_last`): in f32
//! for the f32 backward (which decides nothing) and, where the backward is bf16, for the
//! forward too; in f64 for the forward whose ReLUs route an f32 backward (its sums within about
//! 1e-16 of their terms, rounded once, as the direct f64 sums of `conv3x3` on narrow layers).
#![allow(unsafe_code)]

use std::ops::{Add, Mul, Sub};

use rayon::prelude::*;

/// The format the transforms and products run in: f32, or f64 for a forward whose ReLUs
/// decide as the exact sums (its rounding errors, about 1e-16 of the terms, far under f32's).
pub(crate) trait WinogradReal:
    Copy
    + Default
    + PartialOrd
    + Send
    + Sync
    + 'static
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
{
    /// The value of an f32.
    fn from_f32(v: f32) -> Self;
    /// The nearest value to an f64.
    fn from_f64(v: f64) -> Self;
    /// The nearest f32.
    fn to_f32(self) -> f32;
    /// The value in f64 (exact for both formats).
    fn to_f64(self) -> f64;
    /// `v` of another format: exact from f32 into f64, the nearest value otherwise.
    #[inline(always)]
    fn convert<S: WinogradReal>(v: S) -> Self {
        Self::from_f64(v.to_f64())
    }
}

impl WinogradReal for f32 {
    #[inline(always)]
    fn from_f32(v: f32) -> Self {
        v
    }
    #[inline(always)]
    fn from_f64(v: f64) -> Self {
        v as f32
    }
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        f64::from(self)
    }
}

impl WinogradReal for f64 {
    #[inline(always)]
    fn from_f32(v: f32) -> Self {
        f64::from(v)
    }
    #[inline(always)]
    fn from_f64(v: f64) -> Self {
        v
    }
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self as f32
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self
    }
}

/// Values of a transformed kernel: `[16 (position in the 4x4 block)][cin][cout]`, row-major.
#[derive(Clone, Debug)]
pub(crate) struct WinogradKernel<T = f32> {
    data: Vec<T>,
    cin: usize,
    cout: usize,
}

impl<T: WinogradReal> WinogradKernel<T> {
    /// `G g Gᵀ` of each 3x3 slice of PyTorch weights `[cout, cin, 3, 3]` (row-major in
    /// `weight`), with `G = [[1, 0, 0], [½, ½, ½], [½, -½, ½], [0, 0, 1]]`, computed in f64 and
    /// rounded once to `T`.
    pub(crate) fn new(weight: &[f32], cout: usize, cin: usize) -> Self {
        assert_eq!(weight.len(), cout * cin * 9, "winograd kernel: weight size");
        Self::from_taps(cout, cin, |o, i, r, c| {
            weight[((o * cin + i) * 3 + r) * 3 + c]
        })
    }

    /// As [`Self::new`], with `tap(o, i, dy, dx)` the weight of output channel `o`, input
    /// channel `i`, kernel row `dy` and column `dx`.
    pub(crate) fn from_taps(
        cout: usize,
        cin: usize,
        tap: impl Fn(usize, usize, usize, usize) -> f32 + Sync,
    ) -> Self {
        let mut data = vec![T::default(); 16 * cin * cout];
        // One (output, input) channel pair per task: 16 values, one in each matrix.
        let columns: Vec<[T; 16]> = (0..cout * cin)
            .into_par_iter()
            .map(|oi| {
                let (o, i) = (oi / cin.max(1), oi % cin.max(1));
                let g = |r: usize, c: usize| f64::from(tap(o, i, r, c));
                // Rows of G g (4 x 3), then (G g) Gᵀ (4 x 4).
                let gg: [[f64; 3]; 4] = std::array::from_fn(|r| {
                    std::array::from_fn(|c| match r {
                        0 => g(0, c),
                        1 => 0.5 * (g(0, c) + g(1, c) + g(2, c)),
                        2 => 0.5 * (g(0, c) - g(1, c) + g(2, c)),
                        _ => g(2, c),
                    })
                });
                let mut u = [T::default(); 16];
                for (r, row) in gg.iter().enumerate() {
                    let u_row = [
                        row[0],
                        0.5 * (row[0] + row[1] + row[2]),
                        0.5 * (row[0] - row[1] + row[2]),
                        row[2],
                    ];
                    for (c, &v) in u_row.iter().enumerate() {
                        u[r * 4 + c] = T::from_f64(v);
                    }
                }
                u
            })
            .collect();
        for (oi, u) in columns.iter().enumerate() {
            let (o, i) = (oi / cin.max(1), oi % cin.max(1));
            for (xi, &v) in u.iter().enumerate() {
                data[(xi * cin + i) * cout + o] = v;
            }
        }
        Self { data, cin, cout }
    }

    /// The adjoint of the convolution by PyTorch weights `[cout, cin, 3, 3]` (the map of output
    /// gradients `cout` to input gradients `cin`): channels swapped, each 3x3 slice flipped in
    /// both directions.
    pub(crate) fn adjoint(weight: &[f32], cout: usize, cin: usize) -> Self {
        assert_eq!(weight.len(), cout * cin * 9, "winograd kernel: weight size");
        Self::from_taps(cin, cout, |i, o, r, c| {
            weight[((o * cin + i) * 3 + 2 - r) * 3 + 2 - c]
        })
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

/// Blocks (2x2 outputs each) per band: the band's transformed input and products take about
/// 4M f32 values (16 MB) each.
fn band_block_rows(blocks_x: usize, channels: usize) -> usize {
    (4_000_000 / (16 * blocks_x * channels).max(1)).max(1)
}

/// `conv(input)` of `input` `[images, h, w, kernel.cin()]`; returns
/// `[images, h, w, kernel.cout()]`. With `input_gate` (same shape as `input`), an input value
/// counts only where the gate is above 0 or NaN (PyTorch's `threshold_backward`: the ReLU mask of
/// a backward pass); with `bias_relu`, the output is `relu(conv + bias)` (PyTorch's ReLU: NaN
/// kept).
pub(crate) fn conv3x3_winograd<T: WinogradReal>(
    input: &[f32],
    (images, h, w): (usize, usize, usize),
    kernel: &WinogradKernel<T>,
    input_gate: Option<&[f32]>,
    bias_relu: Option<&[f32]>,
) -> Vec<f32> {
    let (cin, cout) = (kernel.cin, kernel.cout);
    assert_eq!(input.len(), images * h * w * cin, "winograd: input size");
    assert!(
        input_gate.is_none_or(|g| g.len() == input.len()),
        "winograd: gate size"
    );
    assert!(
        bias_relu.is_none_or(|b| b.len() == cout),
        "winograd: bias size"
    );
    let (blocks_y, blocks_x) = (h.div_ceil(2), w.div_ceil(2));
    let band = band_block_rows(blocks_x, cin.max(cout));
    let mut out = vec![0f32; images * h * w * cout];
    let mut transformed = Vec::new();
    let mut products = Vec::new();
    for image in 0..images {
        let src = &input[image * h * w * cin..(image + 1) * h * w * cin];
        let gate = input_gate.map(|g| &g[image * h * w * cin..(image + 1) * h * w * cin]);
        let dst = &mut out[image * h * w * cout..(image + 1) * h * w * cout];
        for by0 in (0..blocks_y).step_by(band) {
            let rows = band.min(blocks_y - by0);
            let blocks = rows * blocks_x;
            // Every value is written before it is read: no clearing between bands.
            transformed.resize(16 * blocks * cin, T::default());
            transform_input(src, gate, h, w, cin, by0, rows, blocks_x, &mut transformed);
            products.resize(16 * blocks * cout, T::default());
            for xi in 0..16 {
                let lhs = &transformed[xi * blocks * cin..(xi + 1) * blocks * cin];
                let rhs = &kernel.data[xi * cin * cout..(xi + 1) * cin * cout];
                let prod = &mut products[xi * blocks * cout..(xi + 1) * blocks * cout];
                // SAFETY: `prod` is `blocks x cout`, `lhs` `blocks x cin` and `rhs` `cin x cout`,
                // each row-major with unit column stride and exactly its slice's length; `prod`
                // is a buffer of its own, apart from the two operands.
                unsafe {
                    gemm::gemm(
                        blocks,
                        cout,
                        cin,
                        prod.as_mut_ptr(),
                        1,
                        cout as isize,
                        false,
                        lhs.as_ptr(),
                        1,
                        cin as isize,
                        rhs.as_ptr(),
                        1,
                        cout as isize,
                        T::default(),
                        T::from_f32(1.0),
                        false,
                        false,
                        false,
                        gemm::Parallelism::Rayon(0),
                    );
                }
            }
            transform_output(&products, dst, h, w, cout, by0, rows, blocks_x, bias_relu);
        }
    }
    out
}

/// Channels handled together by the transforms: fixed-size arrays the compiler vectorizes.
const LANES: usize = 16;

/// A vector of `LANES` channels.
type Lanes<T> = [T; LANES];

/// The first `src.len() <= LANES` lanes of `dst` from `src`, converted: a whole vector moves as
/// one (a copy of variable length is a call to `memmove`).
#[inline(always)]
fn load<S: WinogradReal, T: WinogradReal>(dst: &mut Lanes<T>, src: &[S]) {
    match <&Lanes<S>>::try_from(src) {
        Ok(whole) => *dst = std::array::from_fn(|l| T::convert(whole[l])),
        Err(_) => {
            for (d, &s) in dst.iter_mut().zip(src) {
                *d = T::convert(s);
            }
        }
    }
}

/// [`load`] of `src` where `gate` (as long) is above 0 or NaN, 0 elsewhere (PyTorch's
/// `threshold_backward`: zero where the forward output is `<= 0`).
#[inline(always)]
fn load_gated<T: WinogradReal>(dst: &mut Lanes<T>, src: &[f32], gate: &[f32]) {
    let open = |s: f32, g: f32| T::from_f32(if g <= 0.0 { 0.0 } else { s });
    match (<&Lanes<f32>>::try_from(src), <&Lanes<f32>>::try_from(gate)) {
        (Ok(src), Ok(gate)) => *dst = std::array::from_fn(|l| open(src[l], gate[l])),
        _ => {
            for ((d, &s), &g) in dst.iter_mut().zip(src).zip(gate) {
                *d = open(s, g);
            }
        }
    }
}

/// `dst` (`len() <= LANES`) from the first lanes of `src`, as [`load`].
#[inline(always)]
fn store<T: Copy>(dst: &mut [T], src: &Lanes<T>) {
    match <&mut Lanes<T>>::try_from(&mut *dst) {
        Ok(whole) => *whole = *src,
        Err(_) => {
            for (d, &s) in dst.iter_mut().zip(src) {
                *d = s;
            }
        }
    }
}

/// Row `k` of `Bᵀ = [[1, 0, -1, 0], [0, 1, 1, 0], [0, -1, 1, 0], [0, 1, 0, -1]]` applied to
/// four vectors, lane by lane.
#[inline(always)]
fn input_row<T: WinogradReal>(k: usize, x: [&Lanes<T>; 4]) -> Lanes<T> {
    std::array::from_fn(|l| match k {
        0 => x[0][l] - x[2][l],
        1 => x[1][l] + x[2][l],
        2 => x[2][l] - x[1][l],
        _ => x[1][l] - x[3][l],
    })
}

/// Row `k` of `Aᵀ = [[1, 1, 1, 0], [0, 1, -1, -1]]` applied to four vectors, lane by lane.
#[inline(always)]
fn output_row<T: WinogradReal>(k: usize, x: [&Lanes<T>; 4]) -> Lanes<T> {
    std::array::from_fn(|l| match k {
        0 => x[0][l] + x[1][l] + x[2][l],
        _ => x[1][l] - x[2][l] - x[3][l],
    })
}

/// `Bᵀ d B` of the 4x4 input blocks of block rows `by0..by0 + rows` into `transformed`
/// (`[16][blocks][cin]`), `d` the padded input around each 2x2 output block (zeros outside the
/// image; input values where `gate` is `<= 0` count as 0).
#[allow(clippy::too_many_arguments)]
fn transform_input<T: WinogradReal>(
    src: &[f32],
    gate: Option<&[f32]>,
    h: usize,
    w: usize,
    cin: usize,
    by0: usize,
    rows: usize,
    blocks_x: usize,
    transformed: &mut [T],
) {
    let blocks = rows * blocks_x;
    // Each block row fills its own range of every one of the 16 matrices: split them by rows.
    let mut parts: Vec<Vec<&mut [T]>> = (0..rows).map(|_| Vec::with_capacity(16)).collect();
    for matrix in transformed.chunks_mut(blocks * cin) {
        for (part, block_row) in parts.iter_mut().zip(matrix.chunks_mut(blocks_x * cin)) {
            part.push(block_row);
        }
    }
    parts.into_par_iter().enumerate().for_each(|(r, mut part)| {
        let by = by0 + r;
        for bx in 0..blocks_x {
            for i0 in (0..cin).step_by(LANES) {
                let n = LANES.min(cin - i0);
                // The block's 16 input pixels (padded row 2 by + a, column 2 bx + b), channels
                // i0..i0 + n.
                let mut d = [[[T::default(); LANES]; 4]; 4];
                for (a, d_row) in d.iter_mut().enumerate() {
                    let y = (2 * by + a).wrapping_sub(1);
                    if y >= h {
                        continue;
                    }
                    for (b, d) in d_row.iter_mut().enumerate() {
                        let x = (2 * bx + b).wrapping_sub(1);
                        if x < w {
                            let at = (y * w + x) * cin + i0;
                            match gate {
                                None => load(d, &src[at..at + n]),
                                Some(gate) => load_gated(d, &src[at..at + n], &gate[at..at + n]),
                            }
                        }
                    }
                }
                // t = Bᵀ d (t[k][b]: row k, column b), then V = t B.
                let t: [[Lanes<T>; 4]; 4] = std::array::from_fn(|k| {
                    std::array::from_fn(|b| input_row(k, [&d[0][b], &d[1][b], &d[2][b], &d[3][b]]))
                });
                let at = bx * cin + i0;
                for (k, t) in t.iter().enumerate() {
                    for c in 0..4 {
                        let v = input_row(c, [&t[0], &t[1], &t[2], &t[3]]);
                        store(&mut part[k * 4 + c][at..at + n], &v);
                    }
                }
            }
        }
    });
}

/// `Aᵀ M A` (`relu(Aᵀ M A + bias)` with `bias_relu`, added and decided in `T`, then rounded
/// once) of the products of block rows `by0..by0 + rows` (`[16][blocks][cout]`) into the
/// output image `dst` (`[h, w, cout]`); the outputs of a block past the image's last row or
/// column are dropped.
#[allow(clippy::too_many_arguments)]
fn transform_output<T: WinogradReal>(
    products: &[T],
    dst: &mut [f32],
    h: usize,
    w: usize,
    cout: usize,
    by0: usize,
    rows: usize,
    blocks_x: usize,
    bias_relu: Option<&[f32]>,
) {
    let blocks = rows * blocks_x;
    let first_row = 2 * by0;
    let last_row = (2 * (by0 + rows)).min(h);
    dst[first_row * w * cout..last_row * w * cout]
        .par_chunks_mut(2 * w * cout)
        .enumerate()
        .for_each(|(r, out_rows)| {
            let out_h = out_rows.len() / (w * cout);
            for bx in 0..blocks_x {
                let block = r * blocks_x + bx;
                for o0 in (0..cout).step_by(LANES) {
                    let n = LANES.min(cout - o0);
                    let mut m = [[T::default(); LANES]; 16];
                    for (xi, m) in m.iter_mut().enumerate() {
                        let at = (xi * blocks + block) * cout + o0;
                        load(m, &products[at..at + n]);
                    }
                    let mut b = [T::default(); LANES];
                    if let Some(bias) = bias_relu {
                        load(&mut b, &bias[o0..o0 + n]);
                    }
                    // s = Aᵀ m (s[k][c]: row k, column c), then Y = s A.
                    let s: [[Lanes<T>; 4]; 2] = std::array::from_fn(|k| {
                        std::array::from_fn(|c| {
                            output_row(k, [&m[c], &m[4 + c], &m[8 + c], &m[12 + c]])
                        })
                    });
                    for (dy, s) in s.iter().enumerate().take(out_h) {
                        for dx in 0..2 {
                            let x = 2 * bx + dx;
                            if x >= w {
                                continue;
                            }
                            let y = output_row(dx, [&s[0], &s[1], &s[2], &s[3]]);
                            // + bias, then PyTorch's relu (NaN kept).
                            let v: Lanes<f32> = match bias_relu {
                                None => std::array::from_fn(|l| y[l].to_f32()),
                                Some(_) => std::array::from_fn(|l| {
                                    let v = y[l] + b[l];
                                    if v < T::default() {
                                        0.0
                                    } else {
                                        v.to_f32()
                                    }
                                }),
                            };
                            let at = (dy * w + x) * cout + o0;
                            store(&mut out_rows[at..at + n], &v);
                        }
                    }
                }
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `relu(direct convolution + bias)` in f64 (NCHW weights): the oracle.
    fn direct_bias_relu(
        input: &[f32],
        (h, w): (usize, usize),
        weight: &[f32],
        bias: &[f32],
        (cout, cin): (usize, usize),
    ) -> Vec<f64> {
        let mut out = vec![0f64; h * w * cout];
        for y in 0..h {
            for x in 0..w {
                for o in 0..cout {
                    let mut acc = bias[o] as f64;
                    for dy in 0..3 {
                        for dx in 0..3 {
                            let (sy, sx) = ((y + dy).wrapping_sub(1), (x + dx).wrapping_sub(1));
                            if sy >= h || sx >= w {
                                continue;
                            }
                            for i in 0..cin {
                                let v = input[(sy * w + sx) * cin + i] as f64;
                                acc += v * weight[((o * cin + i) * 3 + dy) * 3 + dx] as f64;
                            }
                        }
                    }
                    out[(y * w + x) * cout + o] = acc.max(0.0);
                }
            }
        }
        out
    }

    /// Values in [-1, 1) from a small linear congruential generator.
    fn values(len: usize, seed: u64) -> Vec<f32> {
        let mut state = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        (0..len)
            .map(|_| {
                state = state
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1_442_695_040_888_963_407);
                ((state >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
            })
            .collect()
    }

    #[test]
    fn matches_the_direct_convolution_on_odd_even_and_tiny_shapes() {
        // Odd and even sides (a last half block), one pixel, one channel, more channels than
        // pixels, and bands of several block rows (the 40x9 image at 64 channels).
        let (mut zeros, mut outputs) = (0, 0);
        for (seed, (h, w, cin, cout)) in [
            (1, 1, 1, 1),
            (2, 3, 1, 2),
            (5, 4, 3, 4),
            (7, 7, 8, 5),
            (6, 9, 16, 24),
            (40, 9, 64, 64),
        ]
        .into_iter()
        .enumerate()
        {
            let images = 2;
            let input = values(images * h * w * cin, seed as u64);
            let weight: Vec<f32> = values(cout * cin * 9, seed as u64 + 100)
                .iter()
                .map(|v| v / (9 * cin) as f32)
                .collect();
            let bias = values(cout, seed as u64 + 200)
                .iter()
                .map(|v| 0.1 * v)
                .collect::<Vec<_>>();
            let kernel = WinogradKernel::<f32>::new(&weight, cout, cin);
            let out = conv3x3_winograd(&input, (images, h, w), &kernel, None, Some(&bias));
            for image in 0..images {
                let len = h * w * cin;
                let expected = direct_bias_relu(
                    &input[image * len..(image + 1) * len],
                    (h, w),
                    &weight,
                    &bias,
                    (cout, cin),
                );
                let got = &out[image * h * w * cout..(image + 1) * h * w * cout];
                let scale = expected.iter().fold(1e-3f64, |m, v| m.max(v.abs()));
                for (g, e) in got.iter().zip(&expected) {
                    assert!(
                        (*g as f64 - e).abs() <= 1e-6 * scale,
                        "{h}x{w} {cin}->{cout}: {g} vs {e}"
                    );
                    zeros += usize::from(*g == 0.0);
                }
            }
            outputs += out.len();
        }
        // The ReLU cut some outputs and kept others.
        assert!(zeros > 0 && zeros < outputs, "{zeros} zeros of {outputs}");
    }

    /// The adjoint kernel on a gated input, no bias or ReLU (the backward's form), against the
    /// f64 adjoint of the gated input: the gate closes at 0 and below, and passes NaN.
    #[test]
    fn the_gated_adjoint_matches_the_direct_one() {
        for (seed, (h, w, cin, cout)) in [(5, 4, 3, 4), (7, 6, 16, 24), (9, 11, 32, 8)]
            .into_iter()
            .enumerate()
        {
            let seed = seed as u64;
            // The adjoint maps `cout` channels to `cin`: its input has `cout`.
            let grad = values(h * w * cout, seed + 300);
            let mut gate = values(h * w * cout, seed + 400);
            gate[0] = 0.0;
            gate[1] = f32::NAN;
            let weight: Vec<f32> = values(cout * cin * 9, seed + 500)
                .iter()
                .map(|v| v / (9 * cout) as f32)
                .collect();
            let kernel = WinogradKernel::<f32>::adjoint(&weight, cout, cin);
            let out = conv3x3_winograd(&grad, (1, h, w), &kernel, Some(&gate), None);
            let gated: Vec<f32> = grad
                .iter()
                .zip(&gate)
                .map(|(&g, &m)| if m <= 0.0 { 0.0 } else { g })
                .collect();
            let mut flipped = vec![0f32; cin * cout * 9];
            for o in 0..cout {
                for i in 0..cin {
                    for tap in 0..9 {
                        flipped[(i * cout + o) * 9 + tap] = weight[(o * cin + i) * 9 + 8 - tap];
                    }
                }
            }
            // relu(x + b) with b far below every value is x itself: the oracle without ReLU.
            let shift = vec![1e3f32; cin];
            let expected: Vec<f64> =
                direct_bias_relu(&gated, (h, w), &flipped, &shift, (cin, cout))
                    .iter()
                    .map(|v| v - 1e3)
                    .collect();
            let scale = expected.iter().fold(1e-3f64, |m, v| m.max(v.abs()));
            let mut negative = 0;
            for (g, e) in out.iter().zip(&expected) {
                assert!(
                    (f64::from(*g) - e).abs() <= 1e-5 * scale,
                    "{h}x{w} {cout}->{cin}: {g} vs {e}"
                );
                negative += usize::from(*g < 0.0);
            }
            // No ReLU: negative outputs stay.
            assert!(negative > 0);
        }
    }

    #[test]
    fn a_nan_input_stays_nan_where_it_reaches_and_the_relu_keeps_it() {
        let (h, w, cin, cout) = (6, 6, 2, 3);
        let mut input = values(h * w * cin, 9);
        input[(3 * w + 3) * cin] = f32::NAN;
        let weight = values(cout * cin * 9, 10);
        let kernel = WinogradKernel::<f32>::new(&weight, cout, cin);
        let out = conv3x3_winograd(&input, (1, h, w), &kernel, None, Some(&[0.0; 3]));
        // The pixels whose 3x3 window holds (3, 3) are NaN; the ReLU passes NaN on.
        for o in 0..cout {
            assert!(out[(3 * w + 3) * cout + o].is_nan());
            assert!(out[(2 * w + 4) * cout + o].is_nan());
        }
        // A pixel of another 2x2 block whose window misses (3, 3) stays finite.
        assert!(out[(w + 1) * cout].is_finite());
    }
}
