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
//! pixels of the tile inside its box `mean2d +- extent` (elsewhere its alpha is below 1/255),
//! and every pixel still sees its splats in depth order, so the result is that of the plain
//! per-pixel loop.

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

/// Alpha of a splat at the pixel centre `(px, row)` with `exp(-sigma)` and the offsets
/// `mean2d - pixel`; `None` when the splat is skipped there (`sigma < 0` or alpha below
/// `ALPHA_MIN`; the `sigma_cut` pre-filter only spares the `exp` where alpha is surely below it).
#[inline]
fn splat_alpha<T: Real>(s: &Splat<T>, px: T, row: SplatRow<T>) -> Option<(T, T, T, T)> {
    let dx = s.mean2d[0] - px;
    let dy = row.dy;
    let sigma = mahalanobis_in_row(s.conic, dx, dy, row.c_dy2);
    if sigma < T::ZERO || sigma > s.sigma_cut {
        return None;
    }
    let falloff = (-sigma).exp();
    let alpha = (s.opacity * falloff).min(T::from_f64(ALPHA_MAX));
    (alpha >= T::from_f64(ALPHA_MIN)).then_some((alpha, falloff, dx, dy))
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
            let band_rows = alpha.len() / width;
            let t_min = T::from_f64(TRANSMITTANCE_MIN);
            let mut local = Vec::new();
            const P: usize = TILE_SIZE * TILE_SIZE;
            for tx in 0..bins.tiles_x {
                let tile = ty * bins.tiles_x + tx;
                gather(
                    splats,
                    &bins.ids[bins.offsets[tile]..bins.offsets[tile + 1]],
                    &mut local,
                );
                let rect = TileRect::new(tx, ty, width, band_rows);
                let (centre_x, centre_y) =
                    (pixel_centres::<T>(rect.x0), pixel_centres::<T>(rect.y0));
                let mut trans = [T::ONE; P];
                let mut color = [[T::ZERO; 3]; P];
                let mut dep = [T::ZERO; P];
                let mut last = [0u32; P];
                let mut done = [false; P];
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
                        let lo = xs.start.max(alive_lo[ly]);
                        let hi = xs.end.min(alive_hi[ly]);
                        let row = SplatRow::new(s, centre_y[ly]);
                        for lx in lo..hi {
                            let q = ly * TILE_SIZE + lx;
                            if done[q] {
                                continue;
                            }
                            let Some((a, _, _, _)) = splat_alpha(s, centre_x[lx], row) else {
                                continue;
                            };
                            let next = trans[q] * (T::ONE - a);
                            if next < t_min {
                                done[q] = true;
                                remaining -= 1;
                                let row = &done[ly * TILE_SIZE..ly * TILE_SIZE + rect.w];
                                while alive_lo[ly] < alive_hi[ly] && row[alive_lo[ly]] {
                                    alive_lo[ly] += 1;
                                }
                                while alive_hi[ly] > alive_lo[ly] && row[alive_hi[ly] - 1] {
                                    alive_hi[ly] -= 1;
                                }
                                continue;
                            }
                            let w = a * trans[q];
                            for ch in 0..3 {
                                color[q][ch] += w * s.color[ch];
                            }
                            dep[q] += w * s.depth;
                            trans[q] = next;
                            last[q] = k as u32 + 1;
                        }
                    }
                }
                for ly in 0..rect.h {
                    for lx in 0..rect.w {
                        let q = ly * TILE_SIZE + lx;
                        let p = ly * width + rect.x0 + lx;
                        for ch in 0..3 {
                            rgb[3 * p + ch] = color[q][ch] + trans[q] * background[ch];
                        }
                        alpha[p] = T::ONE - trans[q];
                        depth[p] = dep[q];
                        final_t[p] = trans[q];
                        n_contrib[p] = last[q];
                    }
                }
            }
        });
    out
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
        .map(|(ty, band_slots)| {
            if extras {
                backward_band::<T, true>(rendered, grads, geometry, ty, band_slots)
            } else {
                backward_band::<T, false>(rendered, grads, geometry, ty, band_slots)
            }
        })
        .reduce(
            || [T::ZERO; 3],
            |a, b| [a[0] + b[0], a[1] + b[1], a[2] + b[2]],
        );
    (slots, bg_grad)
}

/// The backward of tile row `ty` into its tile-list entries `band_slots`; returns the band's
/// background gradient. With `EXTRAS` false (no alpha or depth gradient) the terms that would
/// only add zeros are left out; the sums are otherwise the same.
fn backward_band<T: Real, const EXTRAS: bool>(
    rendered: &Rendered<T>,
    grads: &OutputGrads<'_, T>,
    geometry: bool,
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
    let background = *background;
    let width = rendered.image.width as usize;
    let height = rendered.image.height as usize;
    let band_start = bins.offsets[ty * bins.tiles_x];
    let band_rows = TILE_SIZE.min(height - ty * TILE_SIZE);
    let half = T::from_f64(0.5);
    let one = T::ONE;
    const P: usize = TILE_SIZE * TILE_SIZE;
    let mut g_bg = [T::ZERO; 3];
    let mut local = Vec::new();
    for tx in 0..bins.tiles_x {
        let tile = ty * bins.tiles_x + tx;
        let start = bins.offsets[tile];
        gather(splats, &bins.ids[start..bins.offsets[tile + 1]], &mut local);
        let tile_slots = &mut band_slots[start - band_start..bins.offsets[tile + 1] - band_start];
        let rect = TileRect::new(tx, ty, width, band_rows);
        let (centre_x, centre_y) = (pixel_centres::<T>(rect.x0), pixel_centres::<T>(rect.y0));

        // Per-pixel state, walked back to front from each pixel's last contributor.
        let mut trans = [T::ZERO; P];
        let mut behind = [background; P];
        let mut behind_depth = [T::ZERO; P];
        let mut count = [0u32; P];
        let mut g_rgb = [[T::ZERO; 3]; P];
        let mut g_a = [T::ZERO; P];
        let mut g_d = [T::ZERO; P];
        let mut t_final = [T::ZERO; P];
        let mut max_count = 0usize;
        for ly in 0..rect.h {
            for lx in 0..rect.w {
                let q = ly * TILE_SIZE + lx;
                let p = (rect.y0 + ly) * width + rect.x0 + lx;
                g_rgb[q] = [grads.rgb[3 * p], grads.rgb[3 * p + 1], grads.rgb[3 * p + 2]];
                g_a[q] = grads.alpha.map_or(T::ZERO, |a| a[p]);
                g_d[q] = grads.depth.map_or(T::ZERO, |d| d[p]);
                t_final[q] = final_t[p];
                trans[q] = final_t[p];
                count[q] = n_contrib[p];
                max_count = max_count.max(n_contrib[p] as usize);
                for ch in 0..3 {
                    g_bg[ch] += final_t[p] * g_rgb[q][ch];
                }
            }
        }

        // Each row's columns by decreasing count; a pixel joins at the first k below its
        // count, and [active_lo, active_hi) spans every pixel of the row that has joined.
        let mut by_count = [[0u8; TILE_SIZE]; TILE_SIZE];
        let mut joined = [0usize; TILE_SIZE];
        let mut active_lo = [rect.w; TILE_SIZE];
        let mut active_hi = [0usize; TILE_SIZE];
        for ly in 0..rect.h {
            let order = &mut by_count[ly][..rect.w];
            for (lx, o) in order.iter_mut().enumerate() {
                *o = lx as u8;
            }
            order
                .sort_unstable_by_key(|&lx| std::cmp::Reverse(count[ly * TILE_SIZE + lx as usize]));
        }

        for k in (0..max_count).rev() {
            let s = &local[k];
            let (xs, ys) = rect.clip(s);
            let mut acc = SplatGrad::<T>::default();
            for ly in ys {
                while joined[ly] < rect.w {
                    let lx = by_count[ly][joined[ly]] as usize;
                    if count[ly * TILE_SIZE + lx] as usize <= k {
                        break;
                    }
                    active_lo[ly] = active_lo[ly].min(lx);
                    active_hi[ly] = active_hi[ly].max(lx + 1);
                    joined[ly] += 1;
                }
                let lo = xs.start.max(active_lo[ly]);
                let hi = xs.end.min(active_hi[ly]);
                let row = SplatRow::new(s, centre_y[ly]);
                for lx in lo..hi {
                    let q = ly * TILE_SIZE + lx;
                    if k as u32 >= count[q] {
                        continue;
                    }
                    let Some((a, falloff, dx, dy)) = splat_alpha(s, centre_x[lx], row) else {
                        continue;
                    };
                    let one_minus = one - a;
                    let t_before = trans[q] / one_minus;
                    let w = a * t_before;
                    let mut g_alpha = if EXTRAS {
                        g_a[q] * t_final[q] / one_minus
                    } else {
                        T::ZERO
                    };
                    for ch in 0..3 {
                        acc.color[ch] += w * g_rgb[q][ch];
                        g_alpha += t_before * (s.color[ch] - behind[q][ch]) * g_rgb[q][ch];
                        behind[q][ch] = a * s.color[ch] + one_minus * behind[q][ch];
                    }
                    if EXTRAS {
                        acc.depth += w * g_d[q];
                        g_alpha += t_before * (s.depth - behind_depth[q]) * g_d[q];
                        behind_depth[q] = a * s.depth + one_minus * behind_depth[q];
                    }
                    trans[q] = t_before;
                    // alpha = opacity * exp(-sigma), differentiated as if the
                    // cap at ALPHA_MAX were not there (INRIA's rule, see the module
                    // documentation).
                    acc.opacity += g_alpha * falloff;
                    if geometry {
                        let g_sigma = -g_alpha * s.opacity * falloff;
                        acc.conic[0] += g_sigma * half * dx * dx;
                        acc.conic[1] += g_sigma * dx * dy;
                        acc.conic[2] += g_sigma * half * dy * dy;
                        acc.mean2d[0] += g_sigma * (s.conic[0] * dx + row.b_dy);
                        acc.mean2d[1] += g_sigma * (s.conic[1] * dx + row.c_dy);
                    }
                }
            }
            tile_slots[k] = acc;
        }
    }
    g_bg
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
            for &px in &centres {
                let dx = s.mean2d[0] - px;
                let direct = mahalanobis(s.conic, dx, dy);
                let hoisted = mahalanobis_in_row(s.conic, dx, dy, row.c_dy2);
                assert_eq!(hoisted.to_bits(), direct.to_bits(), "conic {:?}", s.conic);
                let regrouped =
                    0.5 * (s.conic[0] * dx * dx + s.conic[2] * (dy * dy)) + s.conic[1] * dx * dy;
                differing_sigma += usize::from(regrouped.to_bits() != direct.to_bits());
                let expected = (!(direct < 0.0 || direct > s.sigma_cut))
                    .then(|| (s.opacity * (-direct).exp()).min(ALPHA_MAX as f32))
                    .filter(|&alpha| alpha >= ALPHA_MIN as f32);
                let got = splat_alpha(&s, px, row).map(|(alpha, ..)| alpha);
                assert_eq!(got.map(f32::to_bits), expected.map(f32::to_bits));
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
}
