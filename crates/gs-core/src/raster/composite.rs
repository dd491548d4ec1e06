//! Front-to-back alpha compositing of binned splats per 16x16 tile, and its backward.
//!
//! The backward is the exact derivative of the forward except at the cap `alpha <= ALPHA_MAX`:
//! there, as in INRIA's rasterizer (and the renderers of every modality's authors, all derived
//! from it), the gradient of `opacity * exp(-sigma)` passes as if the cap were not there,
//! where the exact derivative (gsplat's rule) would be zero. Trained scenes have many Gaussians
//! of opacity near 1, whose centres are capped.
//!
//! Work is split by bands of one tile row, so every band owns a contiguous slice of the image
//! and of the tile lists. Inside a tile the loops are splat-major: each splat visits only the
//! rows of the tile inside its box `mean2d +- extent` (elsewhere its alpha is below 1/255),
//! and every pixel still sees its splats in depth order, so the result is that of the plain
//! per-pixel loop (bit for bit forward; the backward sums a splat's gradient per column, then
//! over the columns). A row is one loop without branches over a window of 8 or 16 columns,
//! which the compiler vectorizes (`exp` included, [`Real::exp_in_loop`]); columns the splat
//! does not composite take alpha 0, which leaves every update exactly as it was (in a tile
//! whose upstream gradients are not all finite, the backward takes those columns' gradients as
//! 0 too, so that a NaN reaches only its own pixel's splats). The band loops are compiled per
//! instruction set ([`crate::widest_simd!`]).

use rayon::prelude::*;

use super::bin::TileBins;
use super::project::{mahalanobis_in_row, Splat, SplatGrad};
use super::{OutputGrads, Rendered, ALPHA_MAX, ALPHA_MIN, TILE_SIZE, TRANSMITTANCE_MIN};
use crate::real::Real;

/// Per-pixel results of the forward pass (row-major).
pub(crate) struct Composited<T: Real> {
    pub rgb: Vec<T>,
    pub alpha: Vec<T>,
    pub depth: Vec<T>,
    /// Transmittance left after the last contributing splat.
    pub final_t: Vec<T>,
    /// Number of entries of the pixel's tile list up to and including its last contributor.
    pub n_contrib: Vec<u32>,
}

/// A splat's terms shared by one row of pixel centres `py`, with `dy = mean2d.y - py` and the
/// conic `(a, b, c)`: `dy`, `b * dy`, `c * dy` and `c * dy * dy`, computed as the per-pixel
/// expressions compute them, so that hoisting them changes no bit.
#[derive(Clone, Copy)]
struct SplatRow<T: Real> {
    dy: T,
    b_dy: T,
    c_dy: T,
    c_dy2: T,
}

impl<T: Real> SplatRow<T> {
    #[inline]
    fn new(s: &Splat<T>, py: T) -> Self {
        let dy = s.mean2d[1] - py;
        let c_dy = s.conic[2] * dy;
        Self {
            dy,
            b_dy: s.conic[1] * dy,
            c_dy,
            c_dy2: c_dy * dy,
        }
    }
}

/// Columns of the narrow window a row's loop takes when a splat covers few of the row's
/// pixels (one AVX2 vector of f32); wider spans take the whole row.
const NARROW: usize = 8;

/// One splat at `L` pixel centres of a tile row, columns `x0..x0 + L`: its alpha, `exp(-sigma)`
/// and x offset `mean2d.x - px` at each, and whether it is composited there (`hit`: inside
/// `cols`, `sigma` neither below 0 nor above `sigma_cut`, and alpha at least `ALPHA_MIN`; the
/// `sigma_cut` test only leaves out pixels where alpha is surely below it). Every column of the
/// window is computed, inside `cols` or not, so that the loop has no branch and the compiler
/// vectorizes it, `exp` included ([`Real::exp_in_loop`]); the per-pixel expressions are those
/// of a per-pixel loop.
struct RowAlphas<T: Real, const L: usize> {
    x0: usize,
    alpha: [T; L],
    falloff: [T; L],
    dx: [T; L],
    hit: [bool; L],
}

/// Calls `$body` with `$alphas`, the splat's [`RowAlphas`] over the narrowest window (of
/// [`NARROW`] or `TILE_SIZE` columns) that holds `$cols`. A macro, not a closure, so that the
/// body is compiled for the two window widths inside the caller's instruction set.
macro_rules! with_row_alphas {
    ($s:expr, $centre_x:expr, $row:expr, $cols:expr, |$alphas:ident| $body:expr) => {{
        let cols: std::ops::Range<usize> = $cols;
        if cols.end <= NARROW || cols.start >= TILE_SIZE - NARROW {
            let x0 = if cols.end <= NARROW {
                0
            } else {
                TILE_SIZE - NARROW
            };
            let $alphas = row_alphas::<T, NARROW>($s, $centre_x, $row, x0, cols);
            $body
        } else {
            let $alphas = row_alphas::<T, TILE_SIZE>($s, $centre_x, $row, 0, cols);
            $body
        }
    }};
}

#[inline(always)]
fn row_alphas<T: Real, const L: usize>(
    s: &Splat<T>,
    centre_x: &[T; TILE_SIZE],
    row: SplatRow<T>,
    x0: usize,
    cols: std::ops::Range<usize>,
) -> RowAlphas<T, L> {
    let (alpha_max, alpha_min) = (T::from_f64(ALPHA_MAX), T::from_f64(ALPHA_MIN));
    let centres: &[T; L] = centre_x[x0..x0 + L]
        .try_into()
        .expect("the window lies in the tile");
    // The splat's fields as locals and `&` for `&&`: a load or test behind a short circuit is
    // a branch, which keeps the compiler from vectorizing the loop.
    let (mean_x, conic, opacity, sigma_cut) = (s.mean2d[0], s.conic, s.opacity, s.sigma_cut);
    let mut out = RowAlphas {
        x0,
        alpha: [T::ZERO; L],
        falloff: [T::ZERO; L],
        dx: [T::ZERO; L],
        hit: [false; L],
    };
    for i in 0..L {
        let lx = x0 + i;
        let dx = mean_x - centres[i];
        let sigma = mahalanobis_in_row(conic, dx, row.dy, row.c_dy2);
        let falloff = (-sigma).exp_in_loop();
        let alpha = (opacity * falloff).min(alpha_max);
        out.hit[i] = !((sigma < T::ZERO) | (sigma > sigma_cut))
            & (alpha >= alpha_min)
            & (lx >= cols.start)
            & (lx < cols.end);
        out.alpha[i] = alpha;
        out.falloff[i] = falloff;
        out.dx[i] = dx;
    }
    out
}

/// `if take { a } else { b }`, written so that a vectorizing compiler makes it a blend.
#[inline(always)]
fn pick<T: Copy>(take: bool, a: T, b: T) -> T {
    if take {
        a
    } else {
        b
    }
}

/// Pixel-centre coordinates `origin + i + 0.5` of the `TILE_SIZE` pixels of a tile row or column.
fn pixel_centres<T: Real>(origin: usize) -> [T; TILE_SIZE] {
    std::array::from_fn(|i| T::from_f64((origin + i) as f64) + T::from_f64(0.5))
}

/// Copies the splats of one tile list into `out`, contiguous and in list order.
fn gather<T: Real>(splats: &[Option<Splat<T>>], ids: &[u32], out: &mut Vec<Splat<T>>) {
    out.clear();
    out.extend(
        ids.iter()
            .map(|&g| splats[g as usize].expect("binned splats are visible")),
    );
}

/// A tile's pixels: columns `x0..x0+w` of the image, rows `y0..y0+h` (image rows).
#[derive(Clone, Copy)]
struct TileRect {
    x0: usize,
    y0: usize,
    w: usize,
    h: usize,
}

impl TileRect {
    fn new(tx: usize, ty: usize, width: usize, band_rows: usize) -> Self {
        let x0 = tx * TILE_SIZE;
        Self {
            x0,
            y0: ty * TILE_SIZE,
            w: TILE_SIZE.min(width - x0),
            h: band_rows,
        }
    }

    /// Tile-local pixel ranges `(xs, ys)` inside the splat's box.
    #[inline]
    fn clip<T: Real>(&self, s: &Splat<T>) -> (std::ops::Range<usize>, std::ops::Range<usize>) {
        // Pixel centres i + 0.5 in [m - e, m + e]  <=>  i in [m - e - 0.5, m + e - 0.5].
        let range = |m: T, e: T, origin: usize, len: usize| {
            let lo = (m - e - T::from_f64(0.5 + origin as f64)).ceil().to_f64();
            let hi = (m + e - T::from_f64(0.5 + origin as f64)).floor().to_f64();
            let lo = lo.max(0.0).min(len as f64) as usize;
            let hi = (hi + 1.0).max(0.0).min(len as f64) as usize;
            lo..hi.max(lo)
        };
        (
            range(s.mean2d[0], s.extent[0], self.x0, self.w),
            range(s.mean2d[1], s.extent[1], self.y0, self.h),
        )
    }
}

/// Pixels of a tile, row-major in rows of `TILE_SIZE` whatever the tile's width.
const TILE_PIXELS: usize = TILE_SIZE * TILE_SIZE;

/// Composites every pixel over `background`.
pub(crate) fn forward<T: Real>(
    splats: &[Option<Splat<T>>],
    bins: &TileBins,
    width: usize,
    height: usize,
    background: [T; 3],
) -> Composited<T> {
    let n = width * height;
    let mut out = Composited {
        rgb: vec![T::ZERO; 3 * n],
        alpha: vec![T::ZERO; n],
        depth: vec![T::ZERO; n],
        final_t: vec![T::ONE; n],
        n_contrib: vec![0; n],
    };
    let band = TILE_SIZE * width;
    (
        out.rgb.par_chunks_mut(3 * band),
        out.alpha.par_chunks_mut(band),
        out.depth.par_chunks_mut(band),
        out.final_t.par_chunks_mut(band),
        out.n_contrib.par_chunks_mut(band),
    )
        .into_par_iter()
        .enumerate()
        .for_each(|(ty, (rgb, alpha, depth, final_t, n_contrib))| {
            let outputs = BandOutputs {
                rgb,
                alpha,
                depth,
                final_t,
                n_contrib,
            };
            forward_band(splats, bins, width, background, ty, outputs);
        });
    out
}

/// One tile row's slices of the [`Composited`] outputs.
struct BandOutputs<'a, T: Real> {
    rgb: &'a mut [T],
    alpha: &'a mut [T],
    depth: &'a mut [T],
    final_t: &'a mut [T],
    n_contrib: &'a mut [u32],
}

/// A tile's per-pixel compositing state (indexed as [`TILE_PIXELS`]), channels apart so that a
/// row of pixels is one run of memory.
struct TileFront<T: Real> {
    trans: [T; TILE_PIXELS],
    color: [[T; TILE_PIXELS]; 3],
    depth: [T; TILE_PIXELS],
    last: [u32; TILE_PIXELS],
    done: [bool; TILE_PIXELS],
}

crate::widest_simd! {
    /// The forward of tile row `ty` into its outputs.
    fn forward_band<T: Real>(
        splats: &[Option<Splat<T>>],
        bins: &TileBins,
        width: usize,
        background: [T; 3],
        ty: usize,
        out: BandOutputs<'_, T>,
    ) {
        let band_rows = out.alpha.len() / width;
        let t_min = T::from_f64(TRANSMITTANCE_MIN);
        let mut local = Vec::new();
        for tx in 0..bins.tiles_x {
            let tile = ty * bins.tiles_x + tx;
            gather(
                splats,
                &bins.ids[bins.offsets[tile]..bins.offsets[tile + 1]],
                &mut local,
            );
            let rect = TileRect::new(tx, ty, width, band_rows);
            let (centre_x, centre_y) = (pixel_centres::<T>(rect.x0), pixel_centres::<T>(rect.y0));
            let mut st = TileFront {
                trans: [T::ONE; TILE_PIXELS],
                color: [[T::ZERO; TILE_PIXELS]; 3],
                depth: [T::ZERO; TILE_PIXELS],
                last: [0; TILE_PIXELS],
                done: [false; TILE_PIXELS],
            };
            let mut remaining = rect.w * rect.h;
            // Columns [alive_lo, alive_hi) of each row still hold every unfinished pixel.
            let mut alive_lo = [0usize; TILE_SIZE];
            let mut alive_hi = [rect.w; TILE_SIZE];
            for (k, s) in local.iter().enumerate() {
                if remaining == 0 {
                    break;
                }
                let (xs, ys) = rect.clip(s);
                for ly in ys {
                    let cols = xs.start.max(alive_lo[ly])..xs.end.min(alive_hi[ly]);
                    if cols.is_empty() {
                        continue;
                    }
                    let row = SplatRow::new(s, centre_y[ly]);
                    let stopped = with_row_alphas!(s, &centre_x, row, cols, |alphas| {
                        composite_row(&mut st, ly, s, k as u32 + 1, &alphas, t_min)
                    });
                    if stopped > 0 {
                        remaining -= stopped;
                        let row = &st.done[ly * TILE_SIZE..ly * TILE_SIZE + rect.w];
                        while alive_lo[ly] < alive_hi[ly] && row[alive_lo[ly]] {
                            alive_lo[ly] += 1;
                        }
                        while alive_hi[ly] > alive_lo[ly] && row[alive_hi[ly] - 1] {
                            alive_hi[ly] -= 1;
                        }
                    }
                }
            }
            for ly in 0..rect.h {
                for lx in 0..rect.w {
                    let q = ly * TILE_SIZE + lx;
                    let p = ly * width + rect.x0 + lx;
                    for ch in 0..3 {
                        out.rgb[3 * p + ch] = st.color[ch][q] + st.trans[q] * background[ch];
                    }
                    out.alpha[p] = T::ONE - st.trans[q];
                    out.depth[p] = st.depth[q];
                    out.final_t[p] = st.trans[q];
                    out.n_contrib[p] = st.last[q];
                }
            }
        }
    }
}

/// `L` entries of `a` from `start`, as an array of their own.
#[inline(always)]
fn window<V: Copy, const L: usize>(a: &[V], start: usize) -> [V; L] {
    let w: &[V; L] = a[start..start + L]
        .try_into()
        .expect("the window lies in the tile");
    *w
}

/// [`window`] of each of three channels (written out: `array::map` here costs copies the
/// compiler does not remove).
#[inline(always)]
fn window3<V: Copy, const L: usize>(a: &[impl AsRef<[V]>; 3], start: usize) -> [[V; L]; 3] {
    [
        window(a[0].as_ref(), start),
        window(a[1].as_ref(), start),
        window(a[2].as_ref(), start),
    ]
}

/// Composites splat `s` (number `count` in its tile's list, from 1) over the unfinished pixels
/// of tile row `ly` where `alphas` says it hits; a pixel whose transmittance it would take below
/// `t_min` stops there instead. Returns how many pixels stopped. The window's state is copied
/// to arrays of its own and back: on those the compiler needs no proof that the loop's loads
/// and stores do not overlap, and vectorizes it.
#[inline(always)]
fn composite_row<T: Real, const L: usize>(
    st: &mut TileFront<T>,
    ly: usize,
    s: &Splat<T>,
    count: u32,
    alphas: &RowAlphas<T, L>,
    t_min: T,
) -> usize {
    let q0 = ly * TILE_SIZE + alphas.x0;
    let mut trans: [T; L] = window(&st.trans, q0);
    let mut color: [[T; L]; 3] = window3(&st.color, q0);
    let mut depth: [T; L] = window(&st.depth, q0);
    let mut last: [u32; L] = window(&st.last, q0);
    let mut done: [bool; L] = window(&st.done, q0);
    // The splat's fields as locals (see `row_alphas`).
    let (splat_color, splat_depth) = (s.color, s.depth);
    let mut stopped = 0u32;
    for i in 0..L {
        let live = alphas.hit[i] & !done[i];
        let next = trans[i] * (T::ONE - alphas.alpha[i]);
        let stop = live & (next < t_min);
        let keep = live & !stop;
        // Where the splat is not composited, alpha 0 makes every update below exactly
        // nothing (for a finite colour: an SH colour that overflowed to infinity would give
        // the window's other columns NaN, where it already makes its own pixels infinite or
        // NaN): no select of the stored values, which the compiler would turn into masked
        // stores (microcoded, slow, on AMD's cores).
        let a = pick(keep, alphas.alpha[i], T::ZERO);
        let w = a * trans[i];
        for ch in 0..3 {
            color[ch][i] += w * splat_color[ch];
        }
        depth[i] += w * splat_depth;
        trans[i] *= T::ONE - a;
        // Counts grow along the list, so the largest is the last composited.
        last[i] = last[i].max(u32::from(keep) * count);
        done[i] |= stop;
        stopped += u32::from(stop);
    }
    let span = q0..q0 + L;
    st.trans[span.clone()].copy_from_slice(&trans);
    for (dst, src) in st.color.iter_mut().zip(&color) {
        dst[span.clone()].copy_from_slice(src);
    }
    st.depth[span.clone()].copy_from_slice(&depth);
    st.last[span.clone()].copy_from_slice(&last);
    st.done[span].copy_from_slice(&done);
    stopped as usize
}

/// Gradients with respect to every tile-list entry (same layout as `bins.ids`) and the
/// background colour. `geometry` false skips the mean and conic gradients.
pub(crate) fn backward<T: Real>(
    rendered: &Rendered<T>,
    grads: &OutputGrads<'_, T>,
    geometry: bool,
) -> (Vec<SplatGrad<T>>, [T; 3]) {
    let bins = &rendered.bins;
    let mut slots = vec![SplatGrad::<T>::default(); bins.ids.len()];
    let mut bands: Vec<(usize, &mut [SplatGrad<T>])> = Vec::with_capacity(bins.tiles_y);
    let mut rest: &mut [SplatGrad<T>] = &mut slots;
    for ty in 0..bins.tiles_y {
        let len = bins.offsets[(ty + 1) * bins.tiles_x] - bins.offsets[ty * bins.tiles_x];
        let (head, tail) = rest.split_at_mut(len);
        bands.push((ty, head));
        rest = tail;
    }
    // Training passes only dL/dRGB; the alpha and depth terms then drop out of the loop.
    let extras = grads.alpha.is_some() || grads.depth.is_some();
    let bg_grad = bands
        .into_par_iter()
        .map(|(ty, band_slots)| match (extras, geometry) {
            (true, true) => backward_band::<T, true, true>(rendered, grads, ty, band_slots),
            (true, false) => backward_band::<T, true, false>(rendered, grads, ty, band_slots),
            (false, true) => backward_band::<T, false, true>(rendered, grads, ty, band_slots),
            (false, false) => backward_band::<T, false, false>(rendered, grads, ty, band_slots),
        })
        .reduce(
            || [T::ZERO; 3],
            |a, b| [a[0] + b[0], a[1] + b[1], a[2] + b[2]],
        );
    (slots, bg_grad)
}

/// A tile's per-pixel state in the backward (indexed as [`TILE_PIXELS`]), walked back to front
/// from each pixel's last contributor, channels apart.
struct TileBack<T: Real> {
    /// Transmittance in front of the splat being walked.
    trans: [T; TILE_PIXELS],
    /// Colour (and depth) composited behind it, over the background.
    behind: [[T; TILE_PIXELS]; 3],
    behind_depth: [T; TILE_PIXELS],
    /// Number of tile-list entries up to the pixel's last contributor.
    count: [u32; TILE_PIXELS],
    g_rgb: [[T; TILE_PIXELS]; 3],
    g_alpha: [T; TILE_PIXELS],
    g_depth: [T; TILE_PIXELS],
    t_final: [T; TILE_PIXELS],
}

/// One splat's gradient summed per column of the tile (over its rows), added up by
/// [`ColumnGrads::total`] once the splat's rows are done.
struct ColumnGrads<T: Real> {
    mean2d: [[T; TILE_SIZE]; 2],
    conic: [[T; TILE_SIZE]; 3],
    opacity: [T; TILE_SIZE],
    color: [[T; TILE_SIZE]; 3],
    depth: [T; TILE_SIZE],
}

impl<T: Real> ColumnGrads<T> {
    fn zero() -> Self {
        Self {
            mean2d: [[T::ZERO; TILE_SIZE]; 2],
            conic: [[T::ZERO; TILE_SIZE]; 3],
            opacity: [T::ZERO; TILE_SIZE],
            color: [[T::ZERO; TILE_SIZE]; 3],
            depth: [T::ZERO; TILE_SIZE],
        }
    }

    /// The sums over the columns, in column order.
    #[inline(always)]
    fn total(&self) -> SplatGrad<T> {
        let sum = |v: &[T; TILE_SIZE]| v.iter().fold(T::ZERO, |acc, &x| acc + x);
        SplatGrad {
            mean2d: [sum(&self.mean2d[0]), sum(&self.mean2d[1])],
            conic: [
                sum(&self.conic[0]),
                sum(&self.conic[1]),
                sum(&self.conic[2]),
            ],
            opacity: sum(&self.opacity),
            color: [
                sum(&self.color[0]),
                sum(&self.color[1]),
                sum(&self.color[2]),
            ],
            depth: sum(&self.depth),
        }
    }
}

crate::widest_simd! {
    /// The backward of tile row `ty` into its tile-list entries `band_slots`; returns the band's
    /// background gradient. With `EXTRAS` false (no alpha or depth gradient) the terms that
    /// would only add zeros are left out; with `GEOMETRY` false the mean and conic gradients
    /// are (they stay zero).
    fn backward_band<T: Real, const EXTRAS: bool, const GEOMETRY: bool>(
        rendered: &Rendered<T>,
        grads: &OutputGrads<'_, T>,
        ty: usize,
        band_slots: &mut [SplatGrad<T>],
    ) -> [T; 3] {
        let Rendered {
            splats,
            bins,
            final_t,
            n_contrib,
            background,
            ..
        } = rendered;
        let width = rendered.image.width as usize;
        let height = rendered.image.height as usize;
        let band_start = bins.offsets[ty * bins.tiles_x];
        let band_rows = TILE_SIZE.min(height - ty * TILE_SIZE);
        let mut g_bg = [T::ZERO; 3];
        let mut local = Vec::new();
        for tx in 0..bins.tiles_x {
            let tile = ty * bins.tiles_x + tx;
            let start = bins.offsets[tile];
            gather(splats, &bins.ids[start..bins.offsets[tile + 1]], &mut local);
            let tile_slots =
                &mut band_slots[start - band_start..bins.offsets[tile + 1] - band_start];
            let rect = TileRect::new(tx, ty, width, band_rows);
            let (centre_x, centre_y) = (pixel_centres::<T>(rect.x0), pixel_centres::<T>(rect.y0));

            let mut st = TileBack {
                trans: [T::ZERO; TILE_PIXELS],
                behind: background.map(|b| [b; TILE_PIXELS]),
                behind_depth: [T::ZERO; TILE_PIXELS],
                count: [0; TILE_PIXELS],
                g_rgb: [[T::ZERO; TILE_PIXELS]; 3],
                g_alpha: [T::ZERO; TILE_PIXELS],
                g_depth: [T::ZERO; TILE_PIXELS],
                t_final: [T::ZERO; TILE_PIXELS],
            };
            // The largest count of each row: splat k reaches no pixel of a row whose largest
            // count is at most k.
            let mut row_count = [0u32; TILE_SIZE];
            // Whether every upstream gradient of the tile is finite (see `backward_row`).
            let mut finite = true;
            for ly in 0..rect.h {
                for lx in 0..rect.w {
                    let q = ly * TILE_SIZE + lx;
                    let p = (rect.y0 + ly) * width + rect.x0 + lx;
                    for ch in 0..3 {
                        st.g_rgb[ch][q] = grads.rgb[3 * p + ch];
                        g_bg[ch] += final_t[p] * st.g_rgb[ch][q];
                    }
                    st.g_alpha[q] = grads.alpha.map_or(T::ZERO, |a| a[p]);
                    st.g_depth[q] = grads.depth.map_or(T::ZERO, |d| d[p]);
                    finite &= (0..3).all(|ch| st.g_rgb[ch][q].is_finite())
                        && st.g_alpha[q].is_finite()
                        && st.g_depth[q].is_finite();
                    st.t_final[q] = final_t[p];
                    st.trans[q] = final_t[p];
                    st.count[q] = n_contrib[p];
                    row_count[ly] = row_count[ly].max(n_contrib[p]);
                }
            }
            let max_count = row_count.iter().copied().max().unwrap_or(0) as usize;

            for k in (0..max_count).rev() {
                let s = &local[k];
                let (xs, ys) = rect.clip(s);
                let mut acc = ColumnGrads::zero();
                for ly in ys {
                    if row_count[ly] as usize <= k || xs.is_empty() {
                        continue;
                    }
                    let row = SplatRow::new(s, centre_y[ly]);
                    with_row_alphas!(s, &centre_x, row, xs.clone(), |alphas| {
                        if finite {
                            backward_row::<T, EXTRAS, GEOMETRY, true, _>(
                                &mut st, &mut acc, ly, s, k, row, &alphas,
                            )
                        } else {
                            backward_row::<T, EXTRAS, GEOMETRY, false, _>(
                                &mut st, &mut acc, ly, s, k, row, &alphas,
                            )
                        }
                    });
                }
                tile_slots[k] = acc.total();
            }
        }
        g_bg
    }
}

/// Walks splat `s` (entry `k` of its tile's list) back out of tile row `ly` where `alphas` says
/// it hits a pixel it contributed to (`k` below the pixel's count), adding its gradient to
/// `acc`'s columns.
#[inline(always)]
fn backward_row<
    T: Real,
    const EXTRAS: bool,
    const GEOMETRY: bool,
    const FINITE: bool,
    const L: usize,
>(
    st: &mut TileBack<T>,
    acc: &mut ColumnGrads<T>,
    ly: usize,
    s: &Splat<T>,
    k: usize,
    row: SplatRow<T>,
    alphas: &RowAlphas<T, L>,
) {
    let half = T::from_f64(0.5);
    let (q0, x0) = (ly * TILE_SIZE + alphas.x0, alphas.x0);
    // The window's state and sums in arrays of their own (see `composite_row`).
    let mut trans: [T; L] = window(&st.trans, q0);
    let mut behind: [[T; L]; 3] = window3(&st.behind, q0);
    let mut behind_depth: [T; L] = window(&st.behind_depth, q0);
    let count: [u32; L] = window(&st.count, q0);
    let g_rgb: [[T; L]; 3] = window3(&st.g_rgb, q0);
    let (g_a, g_d, t_final): ([T; L], [T; L], [T; L]) = (
        window(&st.g_alpha, q0),
        window(&st.g_depth, q0),
        window(&st.t_final, q0),
    );
    let mut sum_color: [[T; L]; 3] = window3(&acc.color, x0);
    let mut sum_depth: [T; L] = window(&acc.depth, x0);
    let mut sum_opacity: [T; L] = window(&acc.opacity, x0);
    let mut sum_conic: [[T; L]; 3] = window3(&acc.conic, x0);
    let mut sum_mean: [[T; L]; 2] = [window(&acc.mean2d[0], x0), window(&acc.mean2d[1], x0)];
    // The splat's fields as locals (see `row_alphas`).
    let (color, depth, opacity, conic) = (s.color, s.depth, s.opacity, s.conic);
    for i in 0..L {
        let live = alphas.hit[i] & ((k as u32) < count[i]);
        // Where the splat did not composite, alpha and exp(-sigma) 0 make every update below
        // exactly nothing (see `composite_row`), as long as the upstream gradients are finite;
        // where a tile's are not, they are taken as 0 there too, so that a pixel's non-finite
        // gradient reaches only its own splats (selects that cost the loop its speed, so only
        // in such a tile).
        let upstream = |g: T| if FINITE { g } else { pick(live, g, T::ZERO) };
        let a = pick(live, alphas.alpha[i], T::ZERO);
        let falloff = pick(live, alphas.falloff[i], T::ZERO);
        let (dx, dy) = (alphas.dx[i], row.dy);
        let one_minus = T::ONE - a;
        let t_before = trans[i] / one_minus;
        let w = a * t_before;
        let mut g_alpha = if EXTRAS {
            upstream(g_a[i]) * t_final[i] / one_minus
        } else {
            T::ZERO
        };
        for ch in 0..3 {
            let g = upstream(g_rgb[ch][i]);
            sum_color[ch][i] += w * g;
            g_alpha += t_before * (color[ch] - behind[ch][i]) * g;
            behind[ch][i] = a * color[ch] + one_minus * behind[ch][i];
        }
        if EXTRAS {
            let g = upstream(g_d[i]);
            sum_depth[i] += w * g;
            g_alpha += t_before * (depth - behind_depth[i]) * g;
            behind_depth[i] = a * depth + one_minus * behind_depth[i];
        }
        trans[i] = t_before;
        // alpha = opacity * exp(-sigma), differentiated as if the cap at ALPHA_MAX were not
        // there (INRIA's rule, see the module documentation).
        sum_opacity[i] += g_alpha * falloff;
        if GEOMETRY {
            let g_sigma = -g_alpha * opacity * falloff;
            sum_conic[0][i] += g_sigma * half * dx * dx;
            sum_conic[1][i] += g_sigma * dx * dy;
            sum_conic[2][i] += g_sigma * half * dy * dy;
            sum_mean[0][i] += g_sigma * (conic[0] * dx + row.b_dy);
            sum_mean[1][i] += g_sigma * (conic[1] * dx + row.c_dy);
        }
    }
    let (span, cols) = (q0..q0 + L, x0..x0 + L);
    st.trans[span.clone()].copy_from_slice(&trans);
    for (dst, src) in st.behind.iter_mut().zip(&behind) {
        dst[span.clone()].copy_from_slice(src);
    }
    acc.opacity[cols.clone()].copy_from_slice(&sum_opacity);
    for (dst, src) in acc.color.iter_mut().zip(&sum_color) {
        dst[cols.clone()].copy_from_slice(src);
    }
    if EXTRAS {
        st.behind_depth[span].copy_from_slice(&behind_depth);
        acc.depth[cols.clone()].copy_from_slice(&sum_depth);
    }
    if GEOMETRY {
        for (dst, src) in acc.conic.iter_mut().zip(&sum_conic) {
            dst[cols.clone()].copy_from_slice(src);
        }
        for (dst, src) in acc.mean2d.iter_mut().zip(&sum_mean) {
            dst[cols.clone()].copy_from_slice(src);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::project::mahalanobis;

    /// A splat with the given centre and conic, opaque enough that most pixels near it count.
    fn splat(mean2d: [f32; 2], conic: [f32; 3]) -> Splat<f32> {
        Splat {
            mean2d,
            conic,
            depth: 1.0,
            opacity: 0.9,
            color: [0.2, 0.5, 0.8],
            radius: 20.0,
            sigma_cut: 6.0,
            extent: [20.0, 20.0],
        }
    }

    /// The terms hoisted out of a row are the per-pixel expressions bit for bit: `sigma` through
    /// `SplatRow` is `mahalanobis` of the same offsets, and the row's `b * dy` and `c * dy` are
    /// those the mean gradient used per pixel, over centres, conics and rows of all signs and
    /// scales (a wrong hoist, say `c * (dy * dy)`, differs on many of them).
    #[test]
    fn the_row_terms_are_the_per_pixel_expressions_bit_for_bit() {
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            ((state >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
        };
        let centres: [f32; TILE_SIZE] = pixel_centres(37);
        let mut differing_sigma = 0;
        for _ in 0..400 {
            let scale = 10f32.powf(3.0 * next());
            let (a, c) = (scale * (1.0 + next().abs()), scale * (1.0 + next().abs()));
            let b = 0.9 * next() * (a * c).sqrt();
            let s = splat([37.0 + 20.0 * next(), 11.0 + 20.0 * next()], [a, b, c]);
            let py = 11.5 + (8.0 * next()).round();
            let row = SplatRow::new(&s, py);
            let dy = s.mean2d[1] - py;
            assert_eq!(row.dy.to_bits(), dy.to_bits());
            assert_eq!(row.b_dy.to_bits(), (s.conic[1] * dy).to_bits());
            assert_eq!(row.c_dy.to_bits(), (s.conic[2] * dy).to_bits());
            let alphas = row_alphas::<f32, TILE_SIZE>(&s, &centres, row, 0, 0..TILE_SIZE);
            let narrow = row_alphas::<f32, TILE_SIZE>(&s, &centres, row, 0, 5..9);
            // The narrow windows are the same columns' values.
            for x0 in [0, TILE_SIZE - NARROW] {
                let window = row_alphas::<f32, NARROW>(&s, &centres, row, x0, 0..TILE_SIZE);
                for i in 0..NARROW {
                    assert_eq!(window.alpha[i].to_bits(), alphas.alpha[x0 + i].to_bits());
                    assert_eq!(
                        window.falloff[i].to_bits(),
                        alphas.falloff[x0 + i].to_bits()
                    );
                    assert_eq!(window.dx[i].to_bits(), alphas.dx[x0 + i].to_bits());
                    assert_eq!(window.hit[i], alphas.hit[x0 + i]);
                }
            }
            for (lx, &px) in centres.iter().enumerate() {
                let dx = s.mean2d[0] - px;
                assert_eq!(alphas.dx[lx].to_bits(), dx.to_bits());
                let direct = mahalanobis(s.conic, dx, dy);
                let hoisted = mahalanobis_in_row(s.conic, dx, dy, row.c_dy2);
                assert_eq!(hoisted.to_bits(), direct.to_bits(), "conic {:?}", s.conic);
                let regrouped =
                    0.5 * (s.conic[0] * dx * dx + s.conic[2] * (dy * dy)) + s.conic[1] * dx * dy;
                differing_sigma += usize::from(regrouped.to_bits() != direct.to_bits());
                let expected = (!(direct < 0.0 || direct > s.sigma_cut))
                    .then(|| (s.opacity * (-direct).exp_in_loop()).min(ALPHA_MAX as f32))
                    .filter(|&alpha| alpha >= ALPHA_MIN as f32);
                let got = alphas.hit[lx].then_some(alphas.alpha[lx]);
                assert_eq!(got.map(f32::to_bits), expected.map(f32::to_bits));
                // Outside the columns asked for, nothing hits.
                assert_eq!(narrow.hit[lx], got.is_some() && (5..9).contains(&lx));
            }
        }
        // The check is sharp: another grouping of the same sum changes bits.
        assert!(differing_sigma > 100, "{differing_sigma}");
    }

    /// Pixel centres are `origin + i + 0.5`, exactly, as the per-pixel loop computed them.
    #[test]
    fn pixel_centres_are_the_integer_plus_a_half() {
        let centres: [f32; TILE_SIZE] = pixel_centres(4080);
        for (i, &c) in centres.iter().enumerate() {
            assert_eq!(c, (4080 + i) as f32 + 0.5);
        }
    }

    /// `n` Gaussians in front of a `w x h` camera (sizes not multiples of the tile, so edge
    /// tiles are narrow and short), from faint to opaque so that many pixels stop early, some
    /// large enough to span tiles.
    fn scene<T: Real>(seed: u64, n: usize, (w, h): (u32, u32), fov_x: f64) -> Rendered<T> {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut g = crate::GaussianSet::<f64>::zeros(n, 0);
        for v in &mut g.means {
            *v = rng.random_range(-0.9..0.9);
        }
        for v in &mut g.log_scales {
            *v = rng.random_range(-3.0..-0.8);
        }
        for v in &mut g.quats {
            *v = rng.random_range(-1.0..1.0);
        }
        for v in &mut g.opacity_logits {
            *v = rng.random_range(-3.0..8.0);
        }
        for v in &mut g.sh_dc {
            *v = rng.random_range(-1.5..1.5);
        }
        let cam =
            crate::Camera::look_at([0.2, -0.1, -3.0], [0.0; 3], [0.0, -1.0, 0.0], fov_x, w, h)
                .unwrap();
        super::super::render(&g.cast(), &cam, [0.1, 0.4, 0.7].map(T::from_f64))
    }

    /// The splats of pixel `(px, py)`'s tile list, in list order, from the list's first entry.
    fn pixel_list<T: Real>(r: &Rendered<T>, px: usize, py: usize) -> (usize, Vec<Splat<T>>) {
        let tile = (py / TILE_SIZE) * r.bins.tiles_x + px / TILE_SIZE;
        let (start, end) = (r.bins.offsets[tile], r.bins.offsets[tile + 1]);
        let list = r.bins.ids[start..end]
            .iter()
            .map(|&g| r.splats[g as usize].unwrap())
            .collect();
        (start, list)
    }

    /// Alpha, `exp(-sigma)` and the offsets of `s` at a pixel centre, as a per-pixel loop
    /// computes them; `None` where the splat is skipped.
    fn alpha_at<T: Real>(s: &Splat<T>, cx: T, cy: T) -> Option<(T, T, T, T)> {
        let (dx, dy) = (s.mean2d[0] - cx, s.mean2d[1] - cy);
        let sigma = mahalanobis(s.conic, dx, dy);
        if sigma < T::ZERO || sigma > s.sigma_cut {
            return None;
        }
        let falloff = (-sigma).exp_in_loop();
        let alpha = (s.opacity * falloff).min(T::from_f64(ALPHA_MAX));
        (alpha >= T::from_f64(ALPHA_MIN)).then_some((alpha, falloff, dx, dy))
    }

    fn centre<T: Real>(i: usize) -> T {
        T::from_f64(i as f64) + T::from_f64(0.5)
    }

    /// The tiled, row-at-a-time forward against the plain per-pixel loop over the pixel's tile
    /// list: the same bits, in f32 (the vectorized clone) and f64.
    fn check_forward_is_the_per_pixel_loop<T: Real>(r: &Rendered<T>) -> usize {
        let (w, h) = (r.image.width as usize, r.image.height as usize);
        let t_min = T::from_f64(TRANSMITTANCE_MIN);
        let mut stopped = 0;
        for py in 0..h {
            for px in 0..w {
                let (_, list) = pixel_list(r, px, py);
                let (mut t, mut rgb, mut depth, mut last) = (T::ONE, [T::ZERO; 3], T::ZERO, 0);
                for (k, s) in list.iter().enumerate() {
                    let Some((a, ..)) = alpha_at(s, centre(px), centre(py)) else {
                        continue;
                    };
                    let next = t * (T::ONE - a);
                    if next < t_min {
                        stopped += 1;
                        break;
                    }
                    for ch in 0..3 {
                        rgb[ch] += a * t * s.color[ch];
                    }
                    depth += a * t * s.depth;
                    t = next;
                    last = k as u32 + 1;
                }
                let p = py * w + px;
                let at = format!("pixel ({px}, {py})");
                for ch in 0..3 {
                    let want = rgb[ch] + t * r.background[ch];
                    assert_eq!(r.image.data[3 * p + ch].to_f64(), want.to_f64(), "{at}");
                }
                assert_eq!(r.alpha[p].to_f64(), (T::ONE - t).to_f64(), "{at}");
                assert_eq!(r.depth[p].to_f64(), depth.to_f64(), "{at}");
                assert_eq!(r.final_t[p].to_f64(), t.to_f64(), "{at}");
                assert_eq!(r.n_contrib[p], last, "{at}");
            }
        }
        stopped
    }

    /// The per-pixel backward, walking each pixel's list back to front from its last
    /// contributor: every entry's gradient and, beside it, the sum of the absolute values of
    /// the terms that made it (the scale of its rounding error).
    fn per_pixel_backward<T: Real>(
        r: &Rendered<T>,
        grads: &OutputGrads<'_, T>,
        geometry: bool,
    ) -> (Vec<SplatGrad<f64>>, Vec<f64>) {
        let (w, h) = (r.image.width as usize, r.image.height as usize);
        let mut slots = vec![SplatGrad::<f64>::default(); r.bins.ids.len()];
        let mut scale = vec![0.0; r.bins.ids.len()];
        for py in 0..h {
            for px in 0..w {
                let (start, list) = pixel_list(r, px, py);
                let p = py * w + px;
                let g_rgb = [0, 1, 2].map(|ch| grads.rgb[3 * p + ch].to_f64());
                let g_a = grads.alpha.map_or(0.0, |a| a[p].to_f64());
                let g_d = grads.depth.map_or(0.0, |d| d[p].to_f64());
                let t_final = r.final_t[p].to_f64();
                let (mut trans, mut behind) = (t_final, r.background.map(|b| b.to_f64()));
                let mut behind_depth = 0.0;
                for k in (0..r.n_contrib[p] as usize).rev() {
                    let s = &list[k];
                    let Some((a, falloff, dx, dy)) = alpha_at(s, centre(px), centre(py)) else {
                        continue;
                    };
                    let [a, falloff, dx, dy] = [a, falloff, dx, dy].map(|v| v.to_f64());
                    let (color, z) = (s.color.map(|c| c.to_f64()), s.depth.to_f64());
                    let conic = s.conic.map(|c| c.to_f64());
                    let t_before = trans / (1.0 - a);
                    let wgt = a * t_before;
                    let mut g_alpha = g_a * t_final / (1.0 - a);
                    let slot = &mut slots[start + k];
                    let mut terms = vec![];
                    for ch in 0..3 {
                        slot.color[ch] += wgt * g_rgb[ch];
                        g_alpha += t_before * (color[ch] - behind[ch]) * g_rgb[ch];
                        behind[ch] = a * color[ch] + (1.0 - a) * behind[ch];
                        terms.push(wgt * g_rgb[ch]);
                    }
                    slot.depth += wgt * g_d;
                    g_alpha += t_before * (z - behind_depth) * g_d;
                    behind_depth = a * z + (1.0 - a) * behind_depth;
                    trans = t_before;
                    slot.opacity += g_alpha * falloff;
                    terms.extend([wgt * g_d, g_alpha * falloff]);
                    if geometry {
                        let g_sigma = -g_alpha * s.opacity.to_f64() * falloff;
                        let more = [
                            g_sigma * 0.5 * dx * dx,
                            g_sigma * dx * dy,
                            g_sigma * 0.5 * dy * dy,
                            g_sigma * (conic[0] * dx + conic[1] * dy),
                            g_sigma * (conic[1] * dx + conic[2] * dy),
                        ];
                        for (c, m) in slot.conic.iter_mut().zip(&more[..3]) {
                            *c += m;
                        }
                        slot.mean2d[0] += more[3];
                        slot.mean2d[1] += more[4];
                        terms.extend(more);
                    }
                    scale[start + k] += terms.iter().map(|v| v.abs()).sum::<f64>();
                }
            }
        }
        (slots, scale)
    }

    /// The tiled, row-at-a-time backward (every variant: with and without the alpha and depth
    /// gradients, with and without geometry) against the per-pixel backward in f64, within
    /// `tolerance` of each entry's scale: only the order of its sums differs.
    fn check_backward_is_the_per_pixel_loop<T: Real>(r: &Rendered<T>, seed: u64, tolerance: f64) {
        let n = r.alpha.len();
        let value = |i: usize, salt: u64| {
            let x = ((i as u64 + 1) * 2_654_435_761 + salt * 40_503 + seed) % 1000;
            T::from_f64(x as f64 / 500.0 - 1.0)
        };
        let rgb: Vec<T> = (0..3 * n).map(|i| value(i, 1)).collect();
        let alpha: Vec<T> = (0..n).map(|i| value(i, 2)).collect();
        let depth: Vec<T> = (0..n).map(|i| value(i, 3)).collect();
        for (extras, geometry) in [(true, true), (true, false), (false, true), (false, false)] {
            let grads = OutputGrads {
                rgb: &rgb,
                alpha: extras.then_some(&alpha[..]),
                depth: extras.then_some(&depth[..]),
            };
            let (got, g_bg) = backward(r, &grads, geometry);
            let (want, scale) = per_pixel_backward(r, &grads, geometry);
            let mut checked = 0;
            for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                let pairs = [
                    (g.mean2d[0], w.mean2d[0]),
                    (g.mean2d[1], w.mean2d[1]),
                    (g.conic[0], w.conic[0]),
                    (g.conic[1], w.conic[1]),
                    (g.conic[2], w.conic[2]),
                    (g.opacity, w.opacity),
                    (g.color[0], w.color[0]),
                    (g.color[1], w.color[1]),
                    (g.color[2], w.color[2]),
                    (g.depth, w.depth),
                ];
                for (field, (g, w)) in pairs.into_iter().enumerate() {
                    let err = (g.to_f64() - w).abs();
                    assert!(
                        err <= tolerance * scale[i],
                        "entry {i} field {field} ({extras}, {geometry}): {g:?} against {w}"
                    );
                    checked += usize::from(w != 0.0);
                }
            }
            assert!(checked > 100, "only {checked} nonzero gradients");
            let bg: f64 = (0..n)
                .map(|p| r.final_t[p].to_f64() * rgb[3 * p].to_f64())
                .sum();
            assert!(
                (g_bg[0].to_f64() - bg).abs() <= tolerance * n as f64,
                "{g_bg:?} {bg}"
            );
        }
    }

    /// The compositing loops work a splat's tile row at a time over a window of 8 or 16
    /// columns, alpha 0 where it does not composite (the form the compiler vectorizes); they
    /// must composite exactly the pixels and splats the plain per-pixel loop does, narrow and
    /// short edge tiles (of 5, 2, 7 and 12 columns: windows past the image's edge on both
    /// halves), pixels that stop early and the skipped columns of a row included. Forward bit
    /// for bit, backward to rounding.
    #[test]
    fn compositing_is_the_per_pixel_loop() {
        let cases = [
            (1, 150, (37, 29), 0.9),
            (2, 300, (50, 21), 0.9),
            (3, 30, (16, 16), 0.9),
            // Narrow pictures seen closely: opaque splats reach past the right edge, where
            // the edge tile's columns are not pixels.
            (4, 400, (7, 40), 0.25),
            (5, 400, (21, 9), 0.3),
            (6, 300, (44, 19), 0.4),
        ];
        for (seed, n, size, fov_x) in cases {
            let r64 = scene::<f64>(seed, n, size, fov_x);
            let r32 = scene::<f32>(seed, n, size, fov_x);
            let stopped = check_forward_is_the_per_pixel_loop(&r64);
            check_forward_is_the_per_pixel_loop(&r32);
            assert!(
                stopped > 0 || seed == 3,
                "seed {seed}: no pixel stops early"
            );
            check_backward_is_the_per_pixel_loop(&r64, seed, 1e-12);
            check_backward_is_the_per_pixel_loop(&r32, seed, 1e-5);
        }
    }

    /// A non-finite upstream gradient at one pixel reaches only the tile-list entries
    /// composited there, not the splats whose window merely spans its column (their columns
    /// that do not composite must add exactly nothing).
    #[test]
    fn a_non_finite_gradient_reaches_only_the_splats_of_its_pixel() {
        let r = scene::<f32>(1, 150, (37, 29), 0.9);
        let (w, n) = (37, r.alpha.len());
        let p = (0..n).max_by_key(|&p| r.n_contrib[p]).unwrap();
        let (px, py) = (p % w, p / w);
        let (start, list) = pixel_list(&r, px, py);
        let reached: Vec<usize> = (0..r.n_contrib[p] as usize)
            .filter(|&k| alpha_at(&list[k], centre(px), centre(py)).is_some())
            .map(|k| start + k)
            .collect();
        assert!(reached.len() > 1, "{} splats at the pixel", reached.len());
        for (bad, extras) in [(f32::NAN, false), (f32::INFINITY, true)] {
            let mut rgb = vec![0.5f32; 3 * n];
            rgb[3 * p + 1] = bad;
            let mut alpha = vec![0.25f32; n];
            alpha[p] = bad;
            let depth = vec![-0.5f32; n];
            let grads = OutputGrads {
                rgb: &rgb,
                alpha: extras.then_some(&alpha[..]),
                depth: extras.then_some(&depth[..]),
            };
            let (got, _) = backward(&r, &grads, true);
            for (i, g) in got.iter().enumerate() {
                let values = [
                    g.mean2d.as_slice(),
                    &g.conic,
                    &[g.opacity],
                    &g.color,
                    &[g.depth],
                ];
                let finite = values.concat().iter().all(|v| v.is_finite());
                assert_eq!(finite, !reached.contains(&i), "entry {i} ({bad})");
            }
        }
    }
}
