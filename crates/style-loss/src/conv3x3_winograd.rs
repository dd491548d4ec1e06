//! 3x3 convolution, stride 1, zero padding 1, of channels-last f32 images on the CPU by
//! Winograd's minimal filtering F(2x2, 3x3) or F(4x4, 3x3) (Lavin and Gray, "Fast Algorithms
//! for Convolutional Neural Networks", 2016), with bias and ReLU (a forward) or with the input
//! gated by a ReLU mask (a backward's adjoint convolution).
//!
//! Each `m x m` block of outputs (`m` = 2 or 4) is computed from the `a x a` block of padded
//! input around it (`a = m + 2`, the tile's size, the const parameter `A`): the input block is
//! transformed (`V = Bᵀ d B`), multiplied element by element with the transformed kernel
//! (`U = G g Gᵀ`, `a²` numbers per input and output channel, computed once), and transformed
//! back (`Y = Aᵀ M A`). Summed over the input channels, each of the `a²` element-wise products
//! is a matrix product `[blocks, cin] x [cin, cout]`. Per output and channel pair that is
//! 16 / 4 = 4 multiply-adds for F(2x2, 3x3) and 36 / 16 = 2.25 for F(4x4, 3x3), where the
//! direct convolution takes 9.
//!
//! The transforms add, scale and (in `G`) divide, so the outputs carry more roundings than the
//! direct convolution's, and other ones: F(2x2, 3x3) in f32 errs by up to 1.4e-7 of the largest
//! output in the tests (the order of an f32 sum's); F(4x4, 3x3)'s larger coefficients (up to 8
//! in `Aᵀ`, 5 in `Bᵀ`, sixths in `G`) make it about ten times worse, so it runs only in f64,
//! where its error stays about 1e-15 of the terms. VGG runs F(2x2, 3x3) in f32 for the f32
//! backward of every layer but the first (it decides nothing) and for the forward of the layers
//! whose backward is bf16, and F(4x4, 3x3) in f64 for the forward whose ReLUs route an f32
//! backward
//! ([`conv3x3_winograd_exact`]): each output rounded once, and those whose error bound reaches
//! 0 or a rounding's edge (an output a hair from 0 beside large inputs, whose tile's other
//! inputs cancel only up to a rounding) summed again directly, so that every output is the
//! direct f64 sum's.
#![allow(unsafe_code)]

use std::ops::{Add, Mul, Sub};

use rayon::prelude::*;

use gs_core::widest_simd;

/// Tile size of F(2x2, 3x3): 4x4 inputs for 2x2 outputs.
pub(crate) const F2X2: usize = 4;

/// Tile size of F(4x4, 3x3): 6x6 inputs for 4x4 outputs.
pub(crate) const F4X4: usize = 6;

/// The format the transforms and products run in: f32, or f64 for a forward whose ReLUs
/// decide as the exact sums (its rounding errors, about 1e-15 of the terms, far under f32's).
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

/// Outputs per side of a tile of size `A`.
const fn outputs_per_side(a: usize) -> usize {
    a - 2
}

/// Row `k` of `G` applied to the kernel column (or row) `g`, in f64: for F(2x2, 3x3)
/// `G = [[1, 0, 0], [½, ½, ½], [½, -½, ½], [0, 0, 1]]`, for F(4x4, 3x3)
/// `G = [[¼, 0, 0], [-⅙, -⅙, -⅙], [-⅙, ⅙, -⅙], [1/24, 1/12, ⅙], [1/24, -1/12, ⅙], [0, 0, 1]]`.
fn kernel_row<const A: usize>(k: usize, g: [f64; 3]) -> f64 {
    match (A, k) {
        (F2X2, 0) => g[0],
        (F2X2, 1) => 0.5 * (g[0] + g[1] + g[2]),
        (F2X2, 2) => 0.5 * (g[0] - g[1] + g[2]),
        (F2X2, _) => g[2],
        (F4X4, 0) => 0.25 * g[0],
        (F4X4, 1) => -(g[0] + g[1] + g[2]) / 6.0,
        (F4X4, 2) => -(g[0] - g[1] + g[2]) / 6.0,
        (F4X4, 3) => (g[0] + 2.0 * g[1] + 4.0 * g[2]) / 24.0,
        (F4X4, 4) => (g[0] - 2.0 * g[1] + 4.0 * g[2]) / 24.0,
        (F4X4, _) => g[2],
        _ => unreachable!("winograd: tile size {A}"),
    }
}

/// Values of a transformed kernel: `[A² (position in the tile)][cin][cout]`, row-major.
#[derive(Clone, Debug)]
pub(crate) struct WinogradKernel<T = f32, const A: usize = F2X2> {
    data: Vec<T>,
    cin: usize,
    cout: usize,
}

/// `tap(o, i, dy, dx)` of PyTorch weights `[cout, cin, 3, 3]` (row-major in `weight`): output
/// channel `o`, input channel `i`, kernel row `dy` and column `dx`.
fn pytorch_taps(
    weight: &[f32],
    cout: usize,
    cin: usize,
) -> impl Fn(usize, usize, usize, usize) -> f32 + Sync + '_ {
    assert_eq!(weight.len(), cout * cin * 9, "winograd kernel: weight size");
    move |o, i, r, c| weight[((o * cin + i) * 3 + r) * 3 + c]
}

impl<T: WinogradReal, const A: usize> WinogradKernel<T, A> {
    /// `G g Gᵀ` of each 3x3 slice of PyTorch weights `[cout, cin, 3, 3]` (row-major in
    /// `weight`), computed in f64 and rounded once to `T`.
    pub(crate) fn new(weight: &[f32], cout: usize, cin: usize) -> Self {
        Self::from_taps(cout, cin, pytorch_taps(weight, cout, cin))
    }

    /// As [`Self::new`], with `tap(o, i, dy, dx)` the weight of output channel `o`, input
    /// channel `i`, kernel row `dy` and column `dx`.
    pub(crate) fn from_taps(
        cout: usize,
        cin: usize,
        tap: impl Fn(usize, usize, usize, usize) -> f32 + Sync,
    ) -> Self {
        // One (input, output) channel pair per task, in the order of a matrix's entries
        // (`i * cout + o`): A² values, one in each matrix.
        let pairs: Vec<[[T; A]; A]> = (0..cin * cout)
            .into_par_iter()
            .map(|io| {
                let (i, o) = (io / cout, io % cout);
                let g = |r: usize, c: usize| f64::from(tap(o, i, r, c));
                // Rows of G g (A x 3), then (G g) Gᵀ (A x A).
                let gg: [[f64; 3]; A] = std::array::from_fn(|r| {
                    std::array::from_fn(|c| kernel_row::<A>(r, [g(0, c), g(1, c), g(2, c)]))
                });
                std::array::from_fn(|r| {
                    std::array::from_fn(|c| T::from_f64(kernel_row::<A>(c, gg[r])))
                })
            })
            .collect();
        // Each matrix filled in order by a task of its own (writing each pair's A² values where
        // they go, one in each matrix, `cin * cout` apart, took most of a large kernel's time).
        let mut data = vec![T::default(); A * A * cin * cout];
        data.par_chunks_mut((cin * cout).max(1))
            .enumerate()
            .for_each(|(xi, matrix)| {
                for (v, u) in matrix.iter_mut().zip(&pairs) {
                    *v = u[xi / A][xi % A];
                }
            });
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

/// A forward convolution with bias and ReLU by Winograd's algorithm in f64 whose outputs are
/// those of the direct f64 sum rounded once to f32 ([`conv3x3_winograd_exact`]): the Winograd
/// kernel, the taps to sum again directly the outputs whose rounding the two sums' errors could
/// change, and the size of those errors per output channel.
#[derive(Clone, Debug)]
pub(crate) struct ExactWinogradKernel<const A: usize> {
    winograd: WinogradKernel<f64, A>,
    /// Weights `[cout][3 (dy)][3 (dx)][cin]`.
    taps: Vec<f32>,
    /// Per output channel, [`EXACT_TOLERANCE`] times the sum of `|weight|` over its taps and
    /// input channels: times the largest `|input|` of a tile, a bound on both sums' errors.
    tolerance: Vec<f64>,
}

/// The error of an f64 sum of a convolution's terms, Winograd's or the direct one, relative
/// to `max |input| * sum |weight| + |bias|` (the largest the terms can add up to): about 1e-15
/// measured for F(4x4, 3x3) up to 512 channels; bounded with a margin of over a hundred.
pub(crate) const EXACT_TOLERANCE: f64 = 1e-13;

impl<const A: usize> ExactWinogradKernel<A> {
    /// The convolution whose weight of output channel `o`, input channel `i`, kernel row `dy`
    /// and column `dx` is `tap(o, i, dy, dx)`.
    pub(crate) fn from_taps(
        cout: usize,
        cin: usize,
        tap: impl Fn(usize, usize, usize, usize) -> f32 + Sync,
    ) -> Self {
        let taps: Vec<f32> = (0..cout * 9 * cin)
            .into_par_iter()
            .map(|k| {
                let (o, t, i) = (k / (9 * cin), (k / cin) % 9, k % cin);
                tap(o, i, t / 3, t % 3)
            })
            .collect();
        let tolerance = taps
            .chunks(9 * cin.max(1))
            .map(|o| EXACT_TOLERANCE * o.iter().map(|&v| f64::from(v.abs())).sum::<f64>())
            .collect();
        Self {
            winograd: WinogradKernel::from_taps(cout, cin, tap),
            taps,
            tolerance,
        }
    }

    /// Input channels.
    pub(crate) fn cin(&self) -> usize {
        self.winograd.cin
    }

    /// Output channels.
    pub(crate) fn cout(&self) -> usize {
        self.winograd.cout
    }
}

/// How [`winograd`] spreads a convolution over the threads: by its transformed kernel's size.
///
/// A kernel that stays in the last-level cache runs bands of a few block rows in parallel
/// (at least one band per thread where the image has the rows), each on one thread from its
/// input transform through its products to its outputs, so that a band's transformed input
/// and products (about 4 MB) stay in that thread's share of the cache between the three
/// passes. A larger kernel (VGG's 256- and 512-channel layers in f64, its 512-channel ones in
/// f32) runs the bands one after another, each product split over the threads, so that the
/// kernel is read from memory once per band rather than once per band and thread. Timed layer
/// by layer on a 2-core Zen 3 (docs/benchmarks.md, 2026-11-29): parallel bands took 384x384
/// 64->64 from 165-215 to 97-121 ms in f64 F(4x4, 3x3) and from 94-143 to 62-76 ms in f32
/// F(2x2, 3x3); sequential bands stayed faster from 256 channels in f64 (19 MB) and 512 in
/// f32 (17 MB).
#[derive(Clone, Copy, Debug)]
enum Schedule {
    /// Bands of `rows` block rows, one thread each, in parallel.
    ParallelBands { rows: usize },
    /// Bands of `rows` block rows in turn, each product split over the threads.
    SequentialBands { rows: usize },
}

/// The largest transformed kernel (bytes) whose convolution runs in [`Schedule::ParallelBands`].
const PARALLEL_BANDS_MAX_KERNEL_BYTES: usize = 8 << 20;

/// Bytes of one parallel band's transformed input and products together (at least one block
/// row): about a core's share of the last-level cache.
const PARALLEL_BAND_BYTES: usize = 4 << 20;

/// Values of one sequential band's transformed input, and of its products (about 4M each).
const SEQUENTIAL_BAND_VALUES: usize = 4_000_000;

impl Schedule {
    /// The schedule of `kernel` on images `w` wide.
    fn of<T, const A: usize>(kernel: &WinogradKernel<T, A>, w: usize) -> Self {
        let (cin, cout) = (kernel.cin, kernel.cout);
        let value_bytes = std::mem::size_of::<T>();
        let kernel_bytes = kernel.data.len() * value_bytes;
        let row_values = (A * A * w.div_ceil(outputs_per_side(A))).max(1);
        if kernel_bytes <= PARALLEL_BANDS_MAX_KERNEL_BYTES {
            let row_bytes = row_values * (cin + cout) * value_bytes;
            Self::ParallelBands {
                rows: (PARALLEL_BAND_BYTES / row_bytes.max(1)).max(1),
            }
        } else {
            Self::SequentialBands {
                rows: (SEQUENTIAL_BAND_VALUES / (row_values * cin.max(cout)).max(1)).max(1),
            }
        }
    }
}

/// `conv(input)` of `input` `[images, h, w, kernel.cin()]`; returns
/// `[images, h, w, kernel.cout()]`. With `input_gate` (same shape as `input`), an input value
/// counts only where the gate is above 0 or NaN (PyTorch's `threshold_backward`: the ReLU mask of
/// a backward pass); with `bias_relu`, the output is `relu(conv + bias)` (PyTorch's ReLU: NaN
/// kept).
pub(crate) fn conv3x3_winograd<T: WinogradReal, const A: usize>(
    input: &[f32],
    shape: (usize, usize, usize),
    kernel: &WinogradKernel<T, A>,
    input_gate: Option<&[f32]>,
    bias_relu: Option<&[f32]>,
) -> Vec<f32> {
    let schedule = Schedule::of(kernel, shape.2);
    winograd(input, shape, kernel, input_gate, bias_relu, None, schedule)
}

/// `relu(conv(input) + bias)` of `input` `[images, h, w, kernel.cin()]` by Winograd's algorithm
/// in f64, each output bit for bit the direct f64 sum's rounded once to f32 (`conv3x3`'s
/// exact forward): where an output lies within its error bound (the errors of both sums,
/// [`EXACT_TOLERANCE`] times the largest `|input|` of its tile times its channel's
/// `sum |weight|`, plus as much of `|bias|`) of 0 or of a point where the rounding to f32
/// changes, it is summed again directly. Near-zero sums beside large inputs (where the
/// tile's other inputs cancel only up to a rounding), flat regions that must tie in a max pool
/// and the rare sum at a rounding's edge come out as the direct sum's. A non-finite input
/// makes its tile's outputs summed directly: NaN reaches the outputs whose window holds it.
pub(crate) fn conv3x3_winograd_exact<const A: usize>(
    input: &[f32],
    shape: (usize, usize, usize),
    kernel: &ExactWinogradKernel<A>,
    bias: &[f32],
) -> Vec<f32> {
    let schedule = Schedule::of(&kernel.winograd, shape.2);
    winograd(
        input,
        shape,
        &kernel.winograd,
        None,
        Some(bias),
        Some(kernel),
        schedule,
    )
}

/// One image's convolution as [`winograd`] runs it band by band.
struct ImageConv<'a, T, const A: usize> {
    /// The image, `[h, w, cin]`.
    src: &'a [f32],
    /// The input's gate (a backward's ReLU mask), as `src`.
    gate: Option<&'a [f32]>,
    /// `(h, w)` of the image.
    size: (usize, usize),
    /// The transformed kernel.
    kernel: &'a WinogradKernel<T, A>,
    /// The bias, added before a ReLU.
    bias_relu: Option<&'a [f32]>,
    /// With the exact forward: each block's largest `|input|` ([`tile_max_abs`]), per output
    /// channel the error per unit of it, and the error the bias adds.
    bounds: Option<Bounds<'a>>,
}

impl<T: WinogradReal, const A: usize> ImageConv<'_, T, A> {
    /// The band of block rows from `by0` whose output rows are `dst` (`[.., w, cout]`: `m`
    /// per block row, fewer at the image's last), through the scratch buffers `transformed`
    /// and `products`; with `parallel`, the transforms and products split over the threads.
    /// Returns the outputs the exact forward's bound leaves open (indices into the image).
    fn band(
        &self,
        by0: usize,
        dst: &mut [f32],
        (transformed, products): (&mut Vec<T>, &mut Vec<T>),
        parallel: bool,
    ) -> Vec<usize> {
        let ((h, w), (cin, cout)) = (self.size, (self.kernel.cin, self.kernel.cout));
        let m = outputs_per_side(A);
        let blocks_x = w.div_ceil(m);
        let rows = (dst.len() / (w * cout).max(1)).div_ceil(m);
        let blocks = rows * blocks_x;
        // Every value is written before it is read: no clearing between bands.
        transformed.resize(A * A * blocks * cin, T::default());
        transform_input::<T, A>(
            self.src,
            self.gate,
            (h, w, cin),
            (by0, rows, blocks_x),
            transformed,
            parallel,
        );
        products.resize(A * A * blocks * cout, T::default());
        let parallelism = if parallel {
            gemm::Parallelism::Rayon(0)
        } else {
            gemm::Parallelism::None
        };
        for xi in 0..A * A {
            let lhs = &transformed[xi * blocks * cin..(xi + 1) * blocks * cin];
            let rhs = &self.kernel.data[xi * cin * cout..(xi + 1) * cin * cout];
            let prod = &mut products[xi * blocks * cout..(xi + 1) * blocks * cout];
            // SAFETY: `prod` is `blocks x cout`, `lhs` `blocks x cin` and `rhs` `cin x cout`,
            // each row-major with unit column stride and exactly its slice's length; `prod` is
            // a buffer of its own, apart from the two operands.
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
                    parallelism,
                );
            }
        }
        let bounds = self.bounds.map(|b| Bounds {
            tile_max: &b.tile_max[by0 * blocks_x..(by0 + rows) * blocks_x],
            ..b
        });
        let first = by0 * m * w * cout;
        let open = transform_output::<T, A>(
            products,
            dst,
            (w, cout),
            (rows, blocks_x),
            self.bias_relu,
            bounds,
            parallel,
        );
        open.into_iter().map(|at| first + at).collect()
    }
}

/// [`conv3x3_winograd`], and [`conv3x3_winograd_exact`] with `exact` (then `bias_relu` is the
/// bias and there is no gate), run in `schedule`.
fn winograd<T: WinogradReal, const A: usize>(
    input: &[f32],
    (images, h, w): (usize, usize, usize),
    kernel: &WinogradKernel<T, A>,
    input_gate: Option<&[f32]>,
    bias_relu: Option<&[f32]>,
    exact: Option<&ExactWinogradKernel<A>>,
    schedule: Schedule,
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
    let m = outputs_per_side(A);
    let blocks_y = h.div_ceil(m);
    let mut out = vec![0f32; images * h * w * cout];
    let (mut transformed, mut products) = (Vec::new(), Vec::new());
    // Per output channel, the part of the error bound the bias adds.
    let bias_tolerance: Vec<f64> = match (exact, bias_relu) {
        (Some(_), Some(bias)) => bias
            .iter()
            .map(|&b| EXACT_TOLERANCE * f64::from(b.abs()))
            .collect(),
        _ => Vec::new(),
    };
    for image in 0..images {
        let src = &input[image * h * w * cin..(image + 1) * h * w * cin];
        let dst = &mut out[image * h * w * cout..(image + 1) * h * w * cout];
        let tile_max = exact.map(|_| tile_max_abs::<A>(src, (h, w, cin)));
        let conv = ImageConv {
            src,
            gate: input_gate.map(|g| &g[image * h * w * cin..(image + 1) * h * w * cin]),
            size: (h, w),
            kernel,
            bias_relu,
            bounds: exact
                .zip(tile_max.as_deref())
                .map(|(exact, tile_max)| Bounds {
                    tile_max,
                    tolerance: &exact.tolerance,
                    bias_tolerance: &bias_tolerance,
                }),
        };
        // A band's outputs: its block rows' output rows (fewer at the image's last).
        let uncertain: Vec<usize> = match schedule {
            Schedule::ParallelBands { rows } => {
                // At least one band per thread where the image has the block rows.
                let rows = rows.min(blocks_y.div_ceil(rayon::current_num_threads()).max(1));
                dst.par_chunks_mut((rows * m * w * cout).max(1))
                    .enumerate()
                    .map_init(
                        || (Vec::new(), Vec::new()),
                        |(transformed, products), (k, band_dst)| {
                            conv.band(k * rows, band_dst, (transformed, products), false)
                        },
                    )
                    .flatten_iter()
                    .collect()
            }
            Schedule::SequentialBands { rows } => dst
                .chunks_mut((rows * m * w * cout).max(1))
                .enumerate()
                .flat_map(|(k, band_dst)| {
                    let buffers = (&mut transformed, &mut products);
                    conv.band(k * rows, band_dst, buffers, true)
                })
                .collect(),
        };
        if let (Some(exact), Some(bias)) = (exact, bias_relu) {
            let sums: Vec<f32> = uncertain
                .par_iter()
                .map(|&at| direct_bias_relu_f64(src, (h, w, cin), &exact.taps, bias, at))
                .collect();
            for (&at, v) in uncertain.iter().zip(sums) {
                dst[at] = v;
            }
        }
    }
    out
}

/// The largest `|input|` of each block's `A x A` tile (`[blocks_y][blocks_x]`, every channel
/// of the padded input around the block's outputs), in f64; infinite where the tile holds a
/// NaN or an infinity.
fn tile_max_abs<const A: usize>(src: &[f32], (h, w, cin): (usize, usize, usize)) -> Vec<f64> {
    let m = outputs_per_side(A);
    // |v|'s bits, read as an integer, order the finite values and put infinities and NaNs
    // above them: a maximum of integers, which vectorizes.
    let pixel_max: Vec<u32> = src
        .par_chunks(cin.max(1))
        .map(|pixel| {
            pixel
                .iter()
                .fold(0u32, |acc, &v| acc.max(v.to_bits() & 0x7fff_ffff))
        })
        .collect();
    let (blocks_y, blocks_x) = (h.div_ceil(m), w.div_ceil(m));
    (0..blocks_y * blocks_x)
        .into_par_iter()
        .map(|block| {
            let (by, bx) = (block / blocks_x, block % blocks_x);
            let rows = (m * by).saturating_sub(1)..(m * by + A - 1).min(h);
            let cols = (m * bx).saturating_sub(1)..(m * bx + A - 1).min(w);
            let mut max = 0u32;
            for y in rows {
                for &v in &pixel_max[y * w + cols.start..y * w + cols.end] {
                    max = max.max(v);
                }
            }
            if max >= f32::INFINITY.to_bits() {
                f64::INFINITY
            } else {
                f64::from(f32::from_bits(max))
            }
        })
        .collect()
}

/// `relu(sum + bias)` of the output at `at` (`(pixel * cout + o)` of an `[h, w, cout]` image)
/// summed directly in f64 from `src` (`[h, w, cin]`) and `taps` (`[cout][3][3][cin]`), rounded
/// once to f32 (PyTorch's ReLU: NaN kept). The products go to [`LANES`] partial sums, which
/// vectorize (one running sum waits on each addition); any order keeps the direct sum's error
/// bound.
fn direct_bias_relu_f64(
    src: &[f32],
    (h, w, cin): (usize, usize, usize),
    taps: &[f32],
    bias: &[f32],
    at: usize,
) -> f32 {
    let cout = bias.len();
    let (pixel, o) = (at / cout, at % cout);
    let (y, x) = (pixel / w, pixel % w);
    let mut partial = [0f64; LANES];
    for dy in 0..3 {
        let sy = (y + dy).wrapping_sub(1);
        if sy >= h {
            continue;
        }
        for dx in 0..3 {
            let sx = (x + dx).wrapping_sub(1);
            if sx >= w {
                continue;
            }
            let input = &src[(sy * w + sx) * cin..(sy * w + sx + 1) * cin];
            let weight = &taps[((o * 3 + dy) * 3 + dx) * cin..((o * 3 + dy) * 3 + dx + 1) * cin];
            add_products(&mut partial, input, weight);
        }
    }
    let v = partial.iter().sum::<f64>() + f64::from(bias[o]);
    if v < 0.0 {
        0.0
    } else {
        v as f32
    }
}

/// Channels handled together by the transforms: fixed-size arrays the compiler vectorizes.
const LANES: usize = 16;

/// A vector of `LANES` channels.
type Lanes<T> = [T; LANES];

/// `out[l] = expr` for every lane `l`: a plain loop the compiler vectorizes (a closure per lane,
/// as `std::array::from_fn` takes, may stay a call per element).
macro_rules! lanewise {
    ($out:ident, $l:ident => $value:expr) => {
        for $l in 0..LANES {
            $out[$l] = $value;
        }
    };
}

/// `dst` from `src` (`len() <= LANES`), converted, its lanes past `src` zero: a whole vector
/// moves as one (a copy of variable length is a call to `memmove`).
#[inline(always)]
fn load<S: WinogradReal, T: WinogradReal>(dst: &mut Lanes<T>, src: &[S]) {
    match <&Lanes<S>>::try_from(src) {
        Ok(whole) => lanewise!(dst, l => T::convert(whole[l])),
        Err(_) => {
            *dst = [T::default(); LANES];
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
        (Ok(src), Ok(gate)) => lanewise!(dst, l => open(src[l], gate[l])),
        _ => {
            *dst = [T::default(); LANES];
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

/// Row `k` of `Bᵀ` applied to the `A` vectors `x`, lane by lane, into `out`: for F(2x2, 3x3)
/// `[[1, 0, -1, 0], [0, 1, 1, 0], [0, -1, 1, 0], [0, 1, 0, -1]]`, for F(4x4, 3x3)
/// `[[4, 0, -5, 0, 1, 0], [0, -4, -4, 1, 1, 0], [0, 4, -4, -1, 1, 0], [0, -2, -1, 2, 1, 0],
/// [0, 2, -1, -2, 1, 0], [0, 4, 0, -5, 0, 1]]`.
#[inline(always)]
fn input_row<T: WinogradReal, const A: usize>(k: usize, x: &[&Lanes<T>; A], out: &mut Lanes<T>) {
    let (two, four, five) = (T::from_f32(2.0), T::from_f32(4.0), T::from_f32(5.0));
    match (A, k) {
        (F2X2, 0) => lanewise!(out, l => x[0][l] - x[2][l]),
        (F2X2, 1) => lanewise!(out, l => x[1][l] + x[2][l]),
        (F2X2, 2) => lanewise!(out, l => x[2][l] - x[1][l]),
        (F2X2, _) => lanewise!(out, l => x[1][l] - x[3][l]),
        (F4X4, 0) => lanewise!(out, l => four * x[0][l] - five * x[2][l] + x[4][l]),
        (F4X4, 1) => lanewise!(out, l => x[4][l] + x[3][l] - four * (x[1][l] + x[2][l])),
        (F4X4, 2) => lanewise!(out, l => x[4][l] - x[3][l] + four * (x[1][l] - x[2][l])),
        (F4X4, 3) => lanewise!(out, l => x[4][l] - x[2][l] + two * (x[3][l] - x[1][l])),
        (F4X4, 4) => lanewise!(out, l => x[4][l] - x[2][l] - two * (x[3][l] - x[1][l])),
        (F4X4, _) => lanewise!(out, l => four * x[1][l] - five * x[3][l] + x[5][l]),
        _ => unreachable!("winograd: tile size {A}"),
    }
}

/// Row `k` of `Aᵀ` applied to the `A` vectors `x`, lane by lane, into `out`: for F(2x2, 3x3)
/// `[[1, 1, 1, 0], [0, 1, -1, -1]]`, for F(4x4, 3x3) `[[1, 1, 1, 1, 1, 0], [0, 1, -1, 2, -2, 0],
/// [0, 1, 1, 4, 4, 0], [0, 1, -1, 8, -8, 1]]`.
#[inline(always)]
fn output_row<T: WinogradReal, const A: usize>(k: usize, x: &[&Lanes<T>; A], out: &mut Lanes<T>) {
    let (two, four, eight) = (T::from_f32(2.0), T::from_f32(4.0), T::from_f32(8.0));
    match (A, k) {
        (F2X2, 0) => lanewise!(out, l => x[0][l] + x[1][l] + x[2][l]),
        (F2X2, _) => lanewise!(out, l => x[1][l] - x[2][l] - x[3][l]),
        (F4X4, 0) => lanewise!(out, l => x[0][l] + (x[1][l] + x[2][l]) + (x[3][l] + x[4][l])),
        (F4X4, 1) => lanewise!(out, l => (x[1][l] - x[2][l]) + two * (x[3][l] - x[4][l])),
        (F4X4, 2) => lanewise!(out, l => (x[1][l] + x[2][l]) + four * (x[3][l] + x[4][l])),
        (F4X4, _) => {
            lanewise!(out, l => (x[1][l] - x[2][l]) + eight * (x[3][l] - x[4][l]) + x[5][l])
        }
        _ => unreachable!("winograd: tile size {A}"),
    }
}

/// The `A` vectors `column(0..A)` as an array of references.
#[inline(always)]
fn refs<'a, T, const A: usize>(column: impl Fn(usize) -> &'a Lanes<T>) -> [&'a Lanes<T>; A] {
    let mut out = [column(0); A];
    for (a, out) in out.iter_mut().enumerate().skip(1) {
        *out = column(a);
    }
    out
}

/// `Bᵀ d B` of the `A x A` input blocks of block rows `by0..by0 + rows` into `transformed`
/// (`[A²][blocks][cin]`), `d` the padded input around each output block (zeros outside the
/// image; input values where `gate` is `<= 0` count as 0); with `parallel`, the block rows
/// split over the threads.
fn transform_input<T: WinogradReal, const A: usize>(
    src: &[f32],
    gate: Option<&[f32]>,
    (h, w, cin): (usize, usize, usize),
    (by0, rows, blocks_x): (usize, usize, usize),
    transformed: &mut [T],
    parallel: bool,
) {
    let blocks = rows * blocks_x;
    // Each block row fills its own range of every one of the A² matrices: split them by rows.
    let mut parts: Vec<Vec<&mut [T]>> = (0..rows).map(|_| Vec::with_capacity(A * A)).collect();
    for matrix in transformed.chunks_mut(blocks * cin) {
        for (part, block_row) in parts.iter_mut().zip(matrix.chunks_mut(blocks_x * cin)) {
            part.push(block_row);
        }
    }
    let row = |(r, mut part): (usize, Vec<&mut [T]>)| {
        transform_input_block_row::<T, A>(src, gate, (h, w, cin), by0 + r, blocks_x, &mut part)
    };
    if parallel {
        parts.into_par_iter().enumerate().for_each(row);
    } else {
        parts.into_iter().enumerate().for_each(row);
    }
}

widest_simd! {
/// [`transform_input`] of block row `by` into `part` (its range of each of the A² matrices).
fn transform_input_block_row<T: WinogradReal, const A: usize>(
    src: &[f32],
    gate: Option<&[f32]>,
    (h, w, cin): (usize, usize, usize),
    by: usize,
    blocks_x: usize,
    part: &mut [&mut [T]],
) {
    let m = outputs_per_side(A);
    // Every value of `d` and `t` is written for each block before it is read (no clearing).
    let mut d = [[[T::default(); LANES]; A]; A];
    let mut t = [[[T::default(); LANES]; A]; A];
    for bx in 0..blocks_x {
        for i0 in (0..cin).step_by(LANES) {
            let n = LANES.min(cin - i0);
            // The block's A² input pixels (padded row m by + a, column m bx + b), channels
            // i0..i0 + n; zeros outside the image.
            for (a, d_row) in d.iter_mut().enumerate() {
                let y = (m * by + a).wrapping_sub(1);
                for (b, d) in d_row.iter_mut().enumerate() {
                    let x = (m * bx + b).wrapping_sub(1);
                    if y < h && x < w {
                        let at = (y * w + x) * cin + i0;
                        match gate {
                            None => load(d, &src[at..at + n]),
                            Some(gate) => load_gated(d, &src[at..at + n], &gate[at..at + n]),
                        }
                    } else {
                        *d = [T::default(); LANES];
                    }
                }
            }
            // t = Bᵀ d (t[k][b]: row k, column b), then V = t B.
            for (k, t_row) in t.iter_mut().enumerate() {
                for (b, t) in t_row.iter_mut().enumerate() {
                    input_row::<T, A>(k, &refs(|a| &d[a][b]), t);
                }
            }
            let at = bx * cin + i0;
            let mut v = [T::default(); LANES];
            for (k, t_row) in t.iter().enumerate() {
                let t_row = refs::<T, A>(|b| &t_row[b]);
                for c in 0..A {
                    input_row::<T, A>(c, &t_row, &mut v);
                    store(&mut part[k * A + c][at..at + n], &v);
                }
            }
        }
    }
}
}

/// What [`conv3x3_winograd_exact`] bounds an output's error by: for a whole image in
/// [`ImageConv`], for one band's blocks in [`transform_output`].
#[derive(Clone, Copy)]
struct Bounds<'a> {
    /// The largest `|input|` of each block's tile ([`tile_max_abs`]), row-major.
    tile_max: &'a [f64],
    /// Per output channel, the error per unit of `tile_max` ([`ExactWinogradKernel`]).
    tolerance: &'a [f64],
    /// Per output channel, the error the bias adds.
    bias_tolerance: &'a [f64],
}

/// `Aᵀ M A` (`relu(Aᵀ M A + bias)` with `bias_relu`, added and decided in `T`, then rounded
/// once) of a band's `rows` block rows (products `[A²][blocks][cout]`) into its output rows
/// `dst` (`[.., w, cout]`: `m` per block row, fewer at the image's last); the outputs of a
/// block past the image's last row or column are dropped. With `bounds`, returns the outputs
/// (indices into `dst`) whose ReLU decision or rounding their error bound leaves open, written
/// as 0. With `parallel`, the block rows split over the threads.
fn transform_output<T: WinogradReal, const A: usize>(
    products: &[T],
    dst: &mut [f32],
    (w, cout): (usize, usize),
    (rows, blocks_x): (usize, usize),
    bias_relu: Option<&[f32]>,
    bounds: Option<Bounds<'_>>,
    parallel: bool,
) -> Vec<usize> {
    let blocks = rows * blocks_x;
    let chunk = outputs_per_side(A) * w * cout;
    let row = |(r, out_rows): (usize, &mut [f32])| {
        let mut uncertain = Vec::new();
        transform_output_block_row::<T, A>(
            products,
            out_rows,
            (w, cout),
            (r, blocks, blocks_x),
            bias_relu,
            bounds,
            &mut uncertain,
        );
        uncertain.into_iter().map(move |at| r * chunk + at)
    };
    if parallel {
        dst.par_chunks_mut(chunk)
            .enumerate()
            .flat_map_iter(row)
            .collect()
    } else {
        dst.chunks_mut(chunk).enumerate().flat_map(row).collect()
    }
}

widest_simd! {
/// [`transform_output`] of the `r`-th block row of the band (of `blocks` blocks, `blocks_x` to
/// a row) into its output rows `out_rows` (`m`, or fewer at the image's last); with `bounds`,
/// the outputs left open pushed onto `uncertain` (indices into `out_rows`).
fn transform_output_block_row<T: WinogradReal, const A: usize>(
    products: &[T],
    out_rows: &mut [f32],
    (w, cout): (usize, usize),
    (r, blocks, blocks_x): (usize, usize, usize),
    bias_relu: Option<&[f32]>,
    bounds: Option<Bounds<'_>>,
    uncertain: &mut Vec<usize>,
) {
    let m = outputs_per_side(A);
    let out_h = out_rows.len() / (w * cout);
    // Every value of `p` is written for each block before it is read (no clearing).
    let mut p = [[[T::default(); LANES]; A]; A];
    // Per lane: the error bound, and 1 where the value is left open.
    let (mut error, mut open) = ([0f64; LANES], [0u32; LANES]);
    for bx in 0..blocks_x {
        let block = r * blocks_x + bx;
        for o0 in (0..cout).step_by(LANES) {
            let n = LANES.min(cout - o0);
            for (xi, p) in p.iter_mut().flatten().enumerate() {
                let at = (xi * blocks + block) * cout + o0;
                load(p, &products[at..at + n]);
            }
            let mut b = [T::default(); LANES];
            if let Some(bias) = bias_relu {
                load(&mut b, &bias[o0..o0 + n]);
            }
            if let Some(bounds) = bounds {
                let (mut tolerance, mut bias_tolerance) = ([0f64; LANES], [0f64; LANES]);
                load(&mut tolerance, &bounds.tolerance[o0..o0 + n]);
                load(&mut bias_tolerance, &bounds.bias_tolerance[o0..o0 + n]);
                let tile_max = bounds.tile_max[block];
                lanewise!(error, l => tile_max * tolerance[l] + bias_tolerance[l]);
            }
            // Row dy of s = Aᵀ p (s[c]: column c), then row dy of Y = s A.
            let (mut s, mut y) = ([[T::default(); LANES]; A], [T::default(); LANES]);
            for dy in 0..out_h.min(m) {
                for (c, s) in s.iter_mut().enumerate() {
                    output_row::<T, A>(dy, &refs(|a| &p[a][c]), s);
                }
                let s = refs::<T, A>(|c| &s[c]);
                for dx in 0..m {
                    let x = m * bx + dx;
                    if x >= w {
                        continue;
                    }
                    output_row::<T, A>(dx, &s, &mut y);
                    // + bias, then PyTorch's relu (NaN kept).
                    let mut v = [0f32; LANES];
                    match (bias_relu, bounds) {
                        (None, _) => lanewise!(v, l => y[l].to_f32()),
                        (Some(_), None) => lanewise!(v, l => {
                            let v = y[l] + b[l];
                            if v < T::default() {
                                0.0
                            } else {
                                v.to_f32()
                            }
                        }),
                        (Some(_), Some(_)) => {
                            lanewise!(v, l => {
                                // The direct sum lies in `sum ± error`: where the whole
                                // interval is `<= 0` the ReLU cuts both; where it is above 0
                                // and both its ends round to one f32, both sums round to it
                                // (rounding is monotonic). NaN settles nothing.
                                let sum = (y[l] + b[l]).to_f64();
                                let (low, high) = (sum - error[l], sum + error[l]);
                                let rounded = low as f32;
                                let off = high <= 0.0;
                                let on = low > 0.0 && rounded == high as f32;
                                open[l] = u32::from(!(off || on));
                                if on {
                                    rounded
                                } else {
                                    0.0
                                }
                            });
                            if open[..n].iter().any(|&o| o != 0) {
                                let at = (dy * w + x) * cout + o0;
                                for (l, &open) in open[..n].iter().enumerate() {
                                    if open != 0 {
                                        uncertain.push(at + l);
                                    }
                                }
                            }
                        }
                    }
                    let at = (dy * w + x) * cout + o0;
                    store(&mut out_rows[at..at + n], &v);
                }
            }
        }
    }
}
}

widest_simd! {
/// `partial[l] += input[i] weight[i]` in f64 over `i = l mod LANES`.
fn add_products(partial: &mut Lanes<f64>, input: &[f32], weight: &[f32]) {
    let mut terms = [0f64; LANES];
    for (input, weight) in input.chunks(LANES).zip(weight.chunks(LANES)) {
        let (mut a, mut b) = ([0f64; LANES], [0f64; LANES]);
        load(&mut a, input);
        load(&mut b, weight);
        lanewise!(terms, l => a[l] * b[l]);
        lanewise!(partial, l => partial[l] + terms[l]);
    }
}
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `relu(direct convolution + bias)` in f64 (NCHW weights), each sum compensated
    /// ([`compensated_sum`]): the oracle.
    fn direct_bias_relu(
        input: &[f32],
        (h, w): (usize, usize),
        weight: &[f32],
        bias: &[f32],
        (cout, cin): (usize, usize),
    ) -> Vec<f64> {
        (0..h * w * cout)
            .map(|at| {
                compensated_sum(input, (h, w, cin), weight, bias, at)
                    .0
                    .max(0.0)
            })
            .collect()
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

    /// `input` (`[.., w, cin]`) made as after a ReLU: non-negative, a third of the channels
    /// zero and the others 0.25 over the left half of each row (flat), the values shifted,
    /// clamped at 0 and scaled elsewhere.
    fn after_relu_with_a_flat_half(input: &mut [f32], w: usize, cin: usize) {
        for (k, v) in input.iter_mut().enumerate() {
            let (x, i) = ((k / cin) % w, k % cin);
            *v = match (x < w / 2, i % 3 == 0) {
                (true, true) => 0.0,
                (true, false) => 0.25,
                (false, _) => (*v - 0.3).max(0.0) * 4.0,
            };
        }
    }

    /// Odd and even sides (a last partial block of either tile), one pixel, one channel, more
    /// channels than pixels, and bands of several block rows (the 40x9 image at 64 channels).
    const SHAPES: [(usize, usize, usize, usize); 7] = [
        (1, 1, 1, 1),
        (2, 3, 1, 2),
        (5, 4, 3, 4),
        (7, 7, 8, 5),
        (6, 9, 16, 24),
        (13, 10, 17, 3),
        (40, 9, 64, 64),
    ];

    /// `relu(conv + bias)` by Winograd's `F(m x m, 3x3)` with tile `A` in `T` on [`SHAPES`],
    /// two images each, against the f64 oracle: `check(got, expected, scale)` for every
    /// output. Returns the outputs the ReLU zeroed and the number of outputs.
    fn against_the_direct_convolution<T: WinogradReal, const A: usize>(
        check: impl Fn(f32, f64, f64),
    ) -> (usize, usize) {
        let (mut zeros, mut outputs) = (0, 0);
        for (seed, (h, w, cin, cout)) in SHAPES.into_iter().enumerate() {
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
            let kernel = WinogradKernel::<T, A>::new(&weight, cout, cin);
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
                for (&g, &e) in got.iter().zip(&expected) {
                    check(g, e, scale);
                    zeros += usize::from(g == 0.0);
                }
            }
            outputs += out.len();
        }
        (zeros, outputs)
    }

    #[test]
    fn f32_products_match_the_direct_convolution_on_odd_even_and_tiny_shapes() {
        let (zeros, outputs) = against_the_direct_convolution::<f32, F2X2>(|g, e, scale| {
            assert!((f64::from(g) - e).abs() <= 1e-6 * scale, "{g} vs {e}");
        });
        // The ReLU cut some outputs and kept others.
        assert!(zeros > 0 && zeros < outputs, "{zeros} zeros of {outputs}");
    }

    /// In f64, both tiles give the oracle's sums rounded once to f32: to the ulp but for a
    /// handful of outputs one ulp off, and 0 exactly where the oracle's ReLU cuts.
    #[test]
    fn f64_products_round_the_direct_convolutions_sums_on_odd_even_and_tiny_shapes() {
        fn check<const A: usize>() {
            let off = std::cell::Cell::new(0usize);
            let (zeros, outputs) = against_the_direct_convolution::<f64, A>(|g, e, scale| {
                assert_eq!(g == 0.0, e == 0.0, "tile {A}: {g} vs {e:e}");
                let ulps =
                    (i64::from(g.to_bits() as i32) - i64::from((e as f32).to_bits() as i32)).abs();
                assert!(
                    ulps <= 1 || (f64::from(g) - e).abs() <= 1e-14 * scale,
                    "tile {A}: {g} vs {e:e}"
                );
                off.set(off.get() + usize::from(ulps > 0));
            });
            assert!(zeros > 0 && zeros < outputs, "{zeros} zeros of {outputs}");
            assert!(
                off.get() * 1000 <= outputs,
                "tile {A}: {} outputs off",
                off.get()
            );
        }
        check::<F2X2>();
        check::<F4X4>();
    }

    /// The adjoint kernel on a gated input, no bias or ReLU (the backward's form), against the
    /// f64 adjoint of the gated input: the gate closes at 0 and below, and passes NaN.
    #[test]
    fn the_gated_adjoint_matches_the_direct_one() {
        gated_adjoint_within::<f32, F2X2>(1e-5);
        gated_adjoint_within::<f64, F4X4>(1e-7);
    }

    fn gated_adjoint_within<T: WinogradReal, const A: usize>(tolerance: f64) {
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
            let kernel = WinogradKernel::<T, A>::adjoint(&weight, cout, cin);
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
                    (f64::from(*g) - e).abs() <= tolerance * scale,
                    "tile {A}, {h}x{w} {cout}->{cin}: {g} vs {e}"
                );
                negative += usize::from(*g < 0.0);
            }
            // No ReLU: negative outputs stay.
            assert!(negative > 0);
        }
    }

    /// Where an output's 3x3 window is all zero (a dead region after a ReLU) its value is the
    /// bias exactly, as the direct sum gives, also where F(4x4, 3x3)'s tile holds non-zero
    /// inputs beyond the window (their transformed terms cancel only up to a rounding, which
    /// the exact forward's bound catches): with zero biases the ReLU then sees an exact 0 and
    /// its gradient stops there, as PyTorch's. F(2x2, 3x3)'s outputs read their own window
    /// only; F(4x4, 3x3) without the bound does not give the bias exactly there. So the f32
    /// backward's F(2x2, 3x3) adjoint gives an input exactly 0 gradient where the ReLU mask
    /// closes its whole window (F(4x4, 3x3) in f32 would not: checked to fail).
    #[test]
    fn an_output_whose_window_is_all_zero_is_exactly_the_bias() {
        let (h, w, cin, cout) = (12, 13, 24, 20);
        // Non-zero inputs only in columns 4, 5 and from 10: outputs in columns 1, 2 and 7, 8
        // see zero windows, with non-zero inputs in their tiles.
        let mut input = values(h * w * cin, 21);
        for (k, v) in input.iter_mut().enumerate() {
            let x = (k / cin) % w;
            if !(x == 4 || x == 5 || x >= 10) {
                *v = 0.0;
            }
        }
        let weight: Vec<f32> = values(cout * cin * 9, 22).iter().map(|v| v * 7.0).collect();
        let zero_windows = |out: &[f32], bias: &[f32]| {
            (0..h).all(|y| {
                [1, 2, 7, 8].iter().all(|&x| {
                    (0..cout).all(|o| {
                        out[(y * w + x) * cout + o].to_bits() == bias[o].max(0.0).to_bits()
                    })
                })
            })
        };
        for bias in [vec![0f32; cout], values(cout, 23)] {
            let f32_tile = WinogradKernel::<f32, F2X2>::new(&weight, cout, cin);
            let f64_tile = WinogradKernel::<f64, F2X2>::new(&weight, cout, cin);
            let exact =
                ExactWinogradKernel::<F4X4>::from_taps(cout, cin, pytorch_taps(&weight, cout, cin));
            for out in [
                conv3x3_winograd(&input, (1, h, w), &f32_tile, None, Some(&bias)),
                conv3x3_winograd(&input, (1, h, w), &f64_tile, None, Some(&bias)),
                conv3x3_winograd_exact(&input, (1, h, w), &exact, &bias),
            ] {
                assert!(zero_windows(&out, &bias));
            }
            // With zero biases the rounding F(4x4, 3x3) leaves reaches the output (a bias
            // absorbs it).
            if bias.iter().all(|&b| b == 0.0) {
                let unbounded =
                    conv3x3_winograd(&input, (1, h, w), &exact.winograd, None, Some(&bias));
                assert!(
                    !zero_windows(&unbounded, &bias),
                    "the test sees the rounding"
                );
            }
        }
        // A backward's adjoint (`cout` channels to `cin`): the gradient non-zero everywhere,
        // its gate closed (0 or below, as a ReLU's mask) outside those columns: exactly 0
        // there, no bias, no ReLU.
        let grad = values(h * w * cout, 24);
        let gate: Vec<f32> = (0..h * w * cout)
            .map(|k| {
                let x = (k / cout) % w;
                if x == 4 || x == 5 || x >= 10 {
                    1.0
                } else if k % 2 == 0 {
                    0.0
                } else {
                    -1.0
                }
            })
            .collect();
        let adjoint = WinogradKernel::<f32, F2X2>::adjoint(&weight, cout, cin);
        let out = conv3x3_winograd(&grad, (1, h, w), &adjoint, Some(&gate), None);
        let closed = |y: usize, x: usize| (0..cin).all(|i| out[(y * w + x) * cin + i] == 0.0);
        assert!((0..h).all(|y| [1, 2, 7, 8].iter().all(|&x| closed(y, x))));
        assert!(
            !closed(0, 4) && out.iter().any(|v| *v < 0.0),
            "no ReLU on the adjoint"
        );
    }

    /// `sum + bias` of the output at `at`, before the ReLU, summed with Neumaier's compensation
    /// (far within an f64 rounding of the exact sum), and the sum of the terms' sizes.
    fn compensated_sum(
        input: &[f32],
        (h, w, cin): (usize, usize, usize),
        weight: &[f32],
        bias: &[f32],
        at: usize,
    ) -> (f64, f64) {
        let cout = bias.len();
        let (pixel, o) = (at / cout, at % cout);
        let (y, x) = (pixel / w, pixel % w);
        let (mut sum, mut compensation, mut size) =
            (f64::from(bias[o]), 0f64, f64::from(bias[o].abs()));
        for dy in 0..3 {
            for dx in 0..3 {
                let (sy, sx) = ((y + dy).wrapping_sub(1), (x + dx).wrapping_sub(1));
                if sy >= h || sx >= w {
                    continue;
                }
                for i in 0..cin {
                    let term = f64::from(input[(sy * w + sx) * cin + i])
                        * f64::from(weight[((o * cin + i) * 3 + dy) * 3 + dx]);
                    let next = sum + term;
                    compensation += if sum.abs() >= term.abs() {
                        (sum - next) + term
                    } else {
                        (term - next) + sum
                    };
                    sum = next;
                    size += term.abs();
                }
            }
        }
        (sum + compensation, size)
    }

    /// The exact forward by F(4x4, 3x3) rounds the exact sums: against a compensated sum, every
    /// output is its value rounded once to f32, or one ulp off where that value lies within
    /// 1e-14 of its terms' sizes of a rounding's edge (where the direct f64 sum's own error
    /// decides too). On random inputs; on post-ReLU-like ones with flat regions (equal windows,
    /// equal outputs: the max pool's ties); and on outputs exactly 0 beside large inputs: sums
    /// exact in f32 whose biases cancel a flat region's outputs. Over a thousand outputs lie
    /// within the bound of 0 (their sum again directly).
    #[test]
    fn the_exact_forward_rounds_the_exact_sums() {
        let (mut open, mut outputs, mut zeros) = (0usize, 0usize, 0usize);
        for (seed, (h, w, cin, cout)) in SHAPES.into_iter().enumerate() {
            let seed = seed as u64;
            for kind in 0..3 {
                let mut input = values(h * w * cin, seed + 600);
                if kind > 0 {
                    after_relu_with_a_flat_half(&mut input, w, cin);
                }
                let mut weight: Vec<f32> = values(cout * cin * 9, seed + 700)
                    .iter()
                    .map(|v| v / (3 * cin) as f32)
                    .collect();
                let mut bias: Vec<f32> = values(cout, seed + 800).iter().map(|v| 0.1 * v).collect();
                let shape = (h, w, cin);
                if kind == 2 {
                    // Inputs on a grid of 1/16 and weights on one of 1/1024: every sum is exact
                    // in f32. Each odd channel's bias then cancels exactly the sum of the
                    // flat region's windows (the image's left quarter, padding included where
                    // it is narrow), whose outputs are exactly 0 beside large ones; even
                    // channels have zero biases.
                    for v in input.iter_mut() {
                        *v = (*v * 16.0).round() / 16.0;
                    }
                    for v in weight.iter_mut() {
                        *v = (*v * 1024.0).round() / 1024.0;
                    }
                    let pixel = (h / 2) * w + w / 4;
                    let no_bias = vec![0f32; cout];
                    for o in 0..cout {
                        let (sum, _) =
                            compensated_sum(&input, shape, &weight, &no_bias, pixel * cout + o);
                        bias[o] = if o % 2 == 1 { -sum as f32 } else { 0.0 };
                    }
                }
                let kernel = ExactWinogradKernel::<F4X4>::from_taps(
                    cout,
                    cin,
                    pytorch_taps(&weight, cout, cin),
                );
                let out = conv3x3_winograd_exact(&input, (1, h, w), &kernel, &bias);
                let tile_max = tile_max_abs::<F4X4>(&input, shape);
                for (at, &got) in out.iter().enumerate() {
                    let (sum, size) = compensated_sum(&input, shape, &weight, &bias, at);
                    let exact = sum.max(0.0);
                    let rounded = exact as f32;
                    zeros += usize::from(got == 0.0);
                    if got.to_bits() != rounded.to_bits() {
                        let edge = 0.5 * (f64::from(got) + f64::from(rounded));
                        assert!(
                            (exact - edge).abs() <= 1e-14 * size,
                            "{h}x{w} {cin}->{cout}, kind {kind}, output {at}: {got:e} vs {exact:e}"
                        );
                    }
                    // The outputs the bound leaves open, counted as the kernel does.
                    let (pixel, o) = (at / cout, at % cout);
                    let block = (pixel / w / 4) * w.div_ceil(4) + (pixel % w) / 4;
                    let error = tile_max[block] * kernel.tolerance[o]
                        + EXACT_TOLERANCE * f64::from(bias[o].abs());
                    open += usize::from(sum.abs() <= error);
                }
                outputs += out.len();
            }
        }
        assert!(zeros > 0 && zeros < outputs, "{zeros} zeros of {outputs}");
        assert!(open > 1000, "{open} outputs near 0 of {outputs}");
    }

    /// A NaN input reaches every output of the blocks whose input tile holds it (the
    /// transforms mix a tile's inputs), the ReLU passes it on, and the outputs of a block whose
    /// tile misses it stay finite.
    #[test]
    fn a_nan_input_stays_nan_where_it_reaches_and_the_relu_keeps_it() {
        fn check<T: WinogradReal, const A: usize>() {
            let (h, w, cin, cout) = (11, 11, 2, 3);
            let mut input = values(h * w * cin, 9);
            input[(5 * w + 5) * cin] = f32::NAN;
            let weight = values(cout * cin * 9, 10);
            let kernel = WinogradKernel::<T, A>::new(&weight, cout, cin);
            let out = conv3x3_winograd(&input, (1, h, w), &kernel, None, Some(&[0.0; 3]));
            for o in 0..cout {
                // The pixels whose 3x3 window holds (5, 5).
                for (y, x) in [(5, 5), (4, 6), (6, 4)] {
                    assert!(out[(y * w + x) * cout + o].is_nan(), "tile {A}: ({y}, {x})");
                }
                // (0, 0)'s block reads rows and columns up to m, short of 5 for both tiles.
                assert!(out[o].is_finite(), "tile {A}");
            }
        }
        check::<f32, F2X2>();
        check::<f64, F4X4>();
    }

    /// The exact forward sums a tile holding a NaN or an infinity directly: NaN reaches the
    /// outputs whose 3x3 window holds it and no other (the direct convolution's, PyTorch's),
    /// and an infinity leaves every output outside its windows finite.
    #[test]
    fn the_exact_forward_keeps_a_non_finite_input_to_its_windows() {
        let (h, w, cin, cout) = (11, 11, 2, 3);
        let weight = values(cout * cin * 9, 10);
        let kernel =
            ExactWinogradKernel::<F4X4>::from_taps(cout, cin, pytorch_taps(&weight, cout, cin));
        for bad in [f32::NAN, f32::INFINITY] {
            let mut input = values(h * w * cin, 9);
            input[(5 * w + 5) * cin] = bad;
            let out = conv3x3_winograd_exact(&input, (1, h, w), &kernel, &[0.0; 3]);
            for (at, v) in out.iter().enumerate() {
                let (y, x) = (at / cout / w, at / cout % w);
                if y.abs_diff(5) > 1 || x.abs_diff(5) > 1 {
                    assert!(v.is_finite(), "{bad}: ({y}, {x}) {v}");
                } else if bad.is_nan() {
                    assert!(v.is_nan(), "({y}, {x}) {v}");
                }
            }
        }
    }

    /// Every schedule (bands in parallel or in turn, of one block row up to the whole image,
    /// the image's height a multiple of the band's or not) gives the same outputs, bit for
    /// bit: the f32 gated adjoint, the f32 forward with bias and ReLU, and the f64 exact
    /// forward with its bound checked, two images each.
    #[test]
    fn every_schedule_gives_the_same_outputs() {
        fn check<T: WinogradReal, const A: usize>(exact: bool) {
            for (seed, (h, w, cin, cout)) in [(1, 1, 1, 1), (7, 9, 8, 5), (13, 10, 17, 3)]
                .into_iter()
                .enumerate()
            {
                let seed = seed as u64;
                let mut input = values(2 * h * w * cin, seed + 800);
                after_relu_with_a_flat_half(&mut input, w, cin);
                // A NaN in the first image's last pixel: outputs its window reaches are NaN.
                input[h * w * cin - 1] = f32::NAN;
                let gate = values(2 * h * w * cin, seed + 810);
                let weight: Vec<f32> = values(cout * cin * 9, seed + 820)
                    .iter()
                    .map(|v| v / (3 * cin) as f32)
                    .collect();
                let bias: Vec<f32> = values(cout, seed + 830).iter().map(|v| 0.1 * v).collect();
                let taps = pytorch_taps(&weight, cout, cin);
                let exact_kernel = ExactWinogradKernel::<A>::from_taps(cout, cin, taps);
                let kernel = WinogradKernel::<T, A>::new(&weight, cout, cin);
                let run = |schedule| {
                    if exact {
                        let (kernel, bias) = (&exact_kernel.winograd, Some(&bias[..]));
                        let exact = Some(&exact_kernel);
                        winograd(&input, (2, h, w), kernel, None, bias, exact, schedule)
                    } else {
                        let gated = winograd(
                            &input,
                            (2, h, w),
                            &kernel,
                            Some(&gate),
                            None,
                            None,
                            schedule,
                        );
                        let biased = winograd(
                            &input,
                            (2, h, w),
                            &kernel,
                            None,
                            Some(&bias),
                            None,
                            schedule,
                        );
                        [gated, biased].concat()
                    }
                };
                let expected = run(Schedule::SequentialBands { rows: h });
                if exact && h > outputs_per_side(A) {
                    // The NaN in the last row is left open and summed directly: only its
                    // window's outputs (in the last band) are NaN, not the first row's.
                    let row = w * cout;
                    assert!(expected[(h - 1) * row..h * row].iter().any(|v| v.is_nan()));
                    assert!(expected[..row].iter().all(|v| !v.is_nan()), "{h}x{w}");
                }
                for schedule in [
                    Schedule::ParallelBands { rows: 1 },
                    Schedule::ParallelBands { rows: 2 },
                    Schedule::ParallelBands { rows: h },
                    Schedule::SequentialBands { rows: 1 },
                    Schedule::SequentialBands { rows: 3 },
                ] {
                    let got = run(schedule);
                    assert!(
                        got.iter()
                            .zip(&expected)
                            .all(|(g, e)| g.to_bits() == e.to_bits()),
                        "tile {A}, {h}x{w} {cin}->{cout}, exact {exact}, {schedule:?}"
                    );
                }
            }
        }
        check::<f32, F2X2>(false);
        check::<f64, F4X4>(false);
        check::<f64, F4X4>(true);
    }

    /// The schedules VGG-19's layers take at 384x384: parallel bands of one block row or more
    /// while the transformed kernel stays under 8 MB (f64 F(4x4, 3x3) to 128 channels, f32
    /// F(2x2, 3x3) to 256), bands in turn above.
    #[test]
    fn small_kernels_run_their_bands_in_parallel_and_large_ones_in_turn() {
        fn schedule<T: WinogradReal, const A: usize>(w: usize, channels: usize) -> Schedule {
            let weight = vec![0f32; channels * channels * 9];
            Schedule::of(&WinogradKernel::<T, A>::new(&weight, channels, channels), w)
        }
        for (w, channels) in [(384, 64), (192, 128)] {
            assert!(matches!(
                schedule::<f64, F4X4>(w, channels),
                Schedule::ParallelBands { rows: 1.. }
            ));
        }
        for (w, channels) in [(384, 64), (192, 128), (96, 256)] {
            assert!(matches!(
                schedule::<f32, F2X2>(w, channels),
                Schedule::ParallelBands { rows: 1.. }
            ));
        }
        assert!(matches!(
            schedule::<f64, F4X4>(96, 256),
            Schedule::SequentialBands { .. }
        ));
        assert!(matches!(
            schedule::<f32, F2X2>(48, 512),
            Schedule::SequentialBands { .. }
        ));
        // A band of a narrow, small image holds several block rows.
        assert!(matches!(
            schedule::<f32, F2X2>(24, 8),
            Schedule::ParallelBands { rows: 2.. }
        ));
    }
}
