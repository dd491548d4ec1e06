//! Front-to-back alpha compositing of binned splats per 16x16 tile, and its exact backward.
//! Work is split by bands of one tile row, so every band owns a contiguous slice of the image
//! and of the tile lists.

use rayon::prelude::*;

use super::bin::TileBins;
use super::project::{Splat, SplatGrad};
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

/// Alpha of a splat at a pixel centre with `exp(-sigma)` and the offsets `mean2d - pixel`;
/// `None` when the splat is skipped there (`sigma < 0` or alpha below `ALPHA_MIN`; the
/// `sigma_cut` pre-filter only spares the `exp` where alpha is surely below it).
#[inline]
fn splat_alpha<T: Real>(s: &Splat<T>, px: T, py: T) -> Option<(T, T, T, T)> {
    let dx = s.mean2d[0] - px;
    let dy = s.mean2d[1] - py;
    let half = T::from_f64(0.5);
    let sigma = half * (s.conic[0] * dx * dx + s.conic[2] * dy * dy) + s.conic[1] * dx * dy;
    if sigma < T::ZERO || sigma > s.sigma_cut {
        return None;
    }
    let falloff = (-sigma).exp();
    let alpha = (s.opacity * falloff).min(T::from_f64(ALPHA_MAX));
    (alpha >= T::from_f64(ALPHA_MIN)).then_some((alpha, falloff, dx, dy))
}

/// Copies the splats of one tile list into `out`, contiguous and in list order, so the pixel
/// loops read them from cache.
fn gather<T: Real>(splats: &[Option<Splat<T>>], ids: &[u32], out: &mut Vec<Splat<T>>) {
    out.clear();
    out.extend(
        ids.iter()
            .map(|&g| splats[g as usize].expect("binned splats are visible")),
    );
}

/// The pixels of tile `tx` inside band `ty`: `(x, y_in_band)` pairs.
fn tile_pixels(tx: usize, width: usize, band_rows: usize) -> impl Iterator<Item = (usize, usize)> {
    let x0 = tx * TILE_SIZE;
    let x1 = (x0 + TILE_SIZE).min(width);
    (0..band_rows).flat_map(move |y| (x0..x1).map(move |x| (x, y)))
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
            let half = T::from_f64(0.5);
            let mut local = Vec::new();
            for tx in 0..bins.tiles_x {
                let tile = ty * bins.tiles_x + tx;
                gather(
                    splats,
                    &bins.ids[bins.offsets[tile]..bins.offsets[tile + 1]],
                    &mut local,
                );
                for (x, y) in tile_pixels(tx, width, band_rows) {
                    let px = T::from_f64(x as f64) + half;
                    let py = T::from_f64((ty * TILE_SIZE + y) as f64) + half;
                    let mut trans = T::ONE;
                    let mut c = [T::ZERO; 3];
                    let mut d = T::ZERO;
                    let mut last = 0u32;
                    for (k, s) in local.iter().enumerate() {
                        let Some((a, _, _, _)) = splat_alpha(s, px, py) else {
                            continue;
                        };
                        let next = trans * (T::ONE - a);
                        if next < t_min {
                            break;
                        }
                        let w = a * trans;
                        for ch in 0..3 {
                            c[ch] += w * s.color[ch];
                        }
                        d += w * s.depth;
                        trans = next;
                        last = k as u32 + 1;
                    }
                    let p = y * width + x;
                    for ch in 0..3 {
                        rgb[3 * p + ch] = c[ch] + trans * background[ch];
                    }
                    alpha[p] = T::ONE - trans;
                    depth[p] = d;
                    final_t[p] = trans;
                    n_contrib[p] = last;
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
    let mut slots = vec![SplatGrad::<T>::default(); bins.ids.len()];
    let mut bands: Vec<(usize, &mut [SplatGrad<T>])> = Vec::with_capacity(bins.tiles_y);
    let mut rest: &mut [SplatGrad<T>] = &mut slots;
    for ty in 0..bins.tiles_y {
        let len = bins.offsets[(ty + 1) * bins.tiles_x] - bins.offsets[ty * bins.tiles_x];
        let (head, tail) = rest.split_at_mut(len);
        bands.push((ty, head));
        rest = tail;
    }
    let bg_grad = bands
        .into_par_iter()
        .map(|(ty, band_slots)| {
            let band_start = bins.offsets[ty * bins.tiles_x];
            let row0 = ty * TILE_SIZE;
            let band_rows = TILE_SIZE.min(final_t.len() / width - row0);
            let half = T::from_f64(0.5);
            let one = T::ONE;
            let mut g_bg = [T::ZERO; 3];
            let mut local = Vec::new();
            for tx in 0..bins.tiles_x {
                let tile = ty * bins.tiles_x + tx;
                let start = bins.offsets[tile];
                gather(splats, &bins.ids[start..bins.offsets[tile + 1]], &mut local);
                let tile_slots =
                    &mut band_slots[start - band_start..bins.offsets[tile + 1] - band_start];
                for (x, y) in tile_pixels(tx, width, band_rows) {
                    let p = (row0 + y) * width + x;
                    let g_rgb = [grads.rgb[3 * p], grads.rgb[3 * p + 1], grads.rgb[3 * p + 2]];
                    let g_a = grads.alpha.map_or(T::ZERO, |a| a[p]);
                    let g_d = grads.depth.map_or(T::ZERO, |d| d[p]);
                    let t_final = final_t[p];
                    for ch in 0..3 {
                        g_bg[ch] += t_final * g_rgb[ch];
                    }
                    let px = T::from_f64(x as f64) + half;
                    let py = T::from_f64((row0 + y) as f64) + half;
                    let mut trans = t_final;
                    let mut behind = background;
                    let mut behind_depth = T::ZERO;
                    for k in (0..n_contrib[p] as usize).rev() {
                        let s = &local[k];
                        let Some((a, falloff, dx, dy)) = splat_alpha(s, px, py) else {
                            continue;
                        };
                        let one_minus = one - a;
                        let t_before = trans / one_minus;
                        let w = a * t_before;
                        let slot = &mut tile_slots[k];
                        let mut g_alpha = g_a * t_final / one_minus;
                        for ch in 0..3 {
                            slot.color[ch] += w * g_rgb[ch];
                            g_alpha += t_before * (s.color[ch] - behind[ch]) * g_rgb[ch];
                            behind[ch] = a * s.color[ch] + one_minus * behind[ch];
                        }
                        slot.depth += w * g_d;
                        g_alpha += t_before * (s.depth - behind_depth) * g_d;
                        behind_depth = a * s.depth + one_minus * behind_depth;
                        trans = t_before;
                        if s.opacity * falloff < T::from_f64(ALPHA_MAX) {
                            // alpha = opacity * exp(-sigma) where the clamp is inactive.
                            slot.opacity += g_alpha * falloff;
                            if geometry {
                                let g_sigma = -g_alpha * a;
                                slot.conic[0] += g_sigma * half * dx * dx;
                                slot.conic[1] += g_sigma * dx * dy;
                                slot.conic[2] += g_sigma * half * dy * dy;
                                slot.mean2d[0] += g_sigma * (s.conic[0] * dx + s.conic[1] * dy);
                                slot.mean2d[1] += g_sigma * (s.conic[1] * dx + s.conic[2] * dy);
                            }
                        }
                    }
                }
            }
            g_bg
        })
        .reduce(
            || [T::ZERO; 3],
            |a, b| [a[0] + b[0], a[1] + b[1], a[2] + b[2]],
        );
    (slots, bg_grad)
}
