//! Tile binning: each visible splat is listed in every 16x16 tile its square radius touches,
//! and each tile's list is in front-to-back depth order.

use rayon::prelude::*;

use super::project::{mahalanobis, Splat};
use super::TILE_SIZE;
use crate::real::Real;

/// Per-tile lists of splat indices, depth-sorted, stored back to back.
#[derive(Clone, Debug)]
pub(crate) struct TileBins {
    /// Tiles per row.
    pub tiles_x: usize,
    /// Tile rows.
    pub tiles_y: usize,
    /// `offsets[t]..offsets[t+1]` is tile `t`'s range in `ids` (`tiles_x * tiles_y + 1` entries).
    pub offsets: Vec<usize>,
    /// Gaussian indices, grouped by tile, each group front to back.
    pub ids: Vec<u32>,
}

/// The tile rectangle `[x0, x1) x [y0, y1)` of a splat at `mean2d` (pixels, centres at
/// `i + 0.5`) of square radius `radius`, in a grid of `tiles` (per row, per column): INRIA's
/// `getRect` in its pixel coordinates (centres at integers, so `mean2d - 0.5`),
/// `floor((p - r) / 16)` to `floor((p + r + 15) / 16)` clamped to the grid. A pixel outside it
/// gets nothing from the splat even where its alpha would pass 1/255, and an empty rectangle
/// culls the splat, as in the authors' renderers.
pub(crate) fn tile_rect<T: Real>(mean2d: [T; 2], radius: T, tiles: [usize; 2]) -> [usize; 4] {
    let t = TILE_SIZE as f64;
    let r = radius.to_f64();
    let (px, py) = (mean2d[0].to_f64() - 0.5, mean2d[1].to_f64() - 0.5);
    // `as usize` saturates: negative values give 0 and huge radii give usize::MAX.
    let tile = |v: f64, n: usize| ((v / t).floor().max(0.0) as usize).min(n);
    [
        tile(px - r, tiles[0]),
        tile(px + r + t - 1.0, tiles[0]),
        tile(py - r, tiles[1]),
        tile(py + r + t - 1.0, tiles[1]),
    ]
}

/// True when some pixel centre of tile `(tx, ty)` has `sigma <= sigma_cut`, i.e. the splat may
/// reach alpha `ALPHA_MIN` there. Tiles of the square bounding box that fail this have no pixel
/// the splat contributes to, so leaving them out changes no output.
fn touches_tile<T: Real>(s: &Splat<T>, tx: usize, ty: usize) -> bool {
    let t = TILE_SIZE as f64;
    let (x0, x1) = (tx as f64 * t + 0.5, (tx + 1) as f64 * t - 0.5);
    let (y0, y1) = (ty as f64 * t + 0.5, (ty + 1) as f64 * t - 0.5);
    let (mx, my) = (s.mean2d[0].to_f64(), s.mean2d[1].to_f64());
    if (x0..=x1).contains(&mx) && (y0..=y1).contains(&my) {
        return true;
    }
    let conic = s.conic.map(|v| v.to_f64());
    let [a, b, c] = conic;
    let sigma = |dx: f64, dy: f64| mahalanobis(conic, dx, dy);
    // The minimum over the rectangle lies on an edge: minimise the 1D quadratic on each edge
    // (offsets are mean - pixel, so an edge at x = X has dx = mx - X and dy in [my-y1, my-y0]).
    let mut best = f64::INFINITY;
    for dx in [mx - x0, mx - x1] {
        let dy = (-b * dx / c).clamp(my - y1, my - y0);
        best = best.min(sigma(dx, dy));
    }
    for dy in [my - y0, my - y1] {
        let dx = (-b * dy / a).clamp(mx - x1, mx - x0);
        best = best.min(sigma(dx, dy));
    }
    best <= s.sigma_cut.to_f64()
}

/// Bins the visible splats (`splats[i]` is `None` when culled) of a `width` x `height` image.
pub(crate) fn bin<T: Real>(splats: &[Option<Splat<T>>], width: u32, height: u32) -> TileBins {
    let tiles_x = (width as usize).div_ceil(TILE_SIZE);
    let tiles_y = (height as usize).div_ceil(TILE_SIZE);
    let n_tiles = tiles_x * tiles_y;
    assert!(
        splats.len() <= u32::MAX as usize && n_tiles <= u32::MAX as usize,
        "tile lists index Gaussians and tiles with u32"
    );

    let mut order: Vec<(T, u32)> = splats
        .par_iter()
        .enumerate()
        .filter_map(|(i, s)| s.as_ref().map(|s| (s.depth, i as u32)))
        .collect();
    // Depths are finite (culling guarantees it); ties go to the lower index.
    order.par_sort_unstable_by(|a, b| {
        a.0.partial_cmp(&b.0)
            .unwrap_or(std::cmp::Ordering::Equal)
            .then(a.1.cmp(&b.1))
    });
    // (tile, Gaussian) pairs in depth order, found in parallel chunks.
    let pairs: Vec<Vec<(u32, u32)>> = order
        .par_chunks(2048)
        .map(|chunk| {
            let mut out = Vec::with_capacity(chunk.len() * 4);
            for &(_, i) in chunk {
                let s = splats[i as usize]
                    .as_ref()
                    .expect("only visible splats are ordered");
                let r = tile_rect(s.mean2d, s.radius, [tiles_x, tiles_y]);
                for ty in r[2]..r[3] {
                    for tx in r[0]..r[1] {
                        if touches_tile(s, tx, ty) {
                            out.push(((ty * tiles_x + tx) as u32, i));
                        }
                    }
                }
            }
            out
        })
        .collect();

    // Stable counting sort by tile keeps each tile's list in depth order.
    let mut offsets = vec![0usize; n_tiles + 1];
    for &(t, _) in pairs.iter().flatten() {
        offsets[t as usize + 1] += 1;
    }
    for t in 0..n_tiles {
        offsets[t + 1] += offsets[t];
    }
    let mut cursor = offsets[..n_tiles].to_vec();
    let mut ids = vec![0u32; offsets[n_tiles]];
    for &(t, i) in pairs.iter().flatten() {
        ids[cursor[t as usize]] = i;
        cursor[t as usize] += 1;
    }
    TileBins {
        tiles_x,
        tiles_y,
        offsets,
        ids,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The tile test never drops a tile in which some pixel centre has `sigma <= sigma_cut`.
    #[test]
    fn tile_culling_has_no_false_negatives() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let mut kept = 0;
        let mut dropped = 0;
        for _ in 0..400 {
            // A random positive-definite conic: R diag(1/l1, 1/l2) R^T.
            let th: f64 = rng.random_range(0.0..3.2);
            let (l1, l2): (f64, f64) = (rng.random_range(0.5..400.0), rng.random_range(0.5..40.0));
            let (c, s) = (th.cos(), th.sin());
            let conic = [
                c * c / l1 + s * s / l2,
                c * s * (1.0 / l1 - 1.0 / l2),
                s * s / l1 + c * c / l2,
            ];
            let splat = Splat {
                mean2d: [rng.random_range(-20.0..70.0), rng.random_range(-20.0..70.0)],
                conic,
                sigma_cut: rng.random_range(0.5..6.0),
                ..Splat::default()
            };
            for ty in 0..3 {
                for tx in 0..3 {
                    let mut any = false;
                    for py in ty * TILE_SIZE..(ty + 1) * TILE_SIZE {
                        for px in tx * TILE_SIZE..(tx + 1) * TILE_SIZE {
                            let dx = splat.mean2d[0] - (px as f64 + 0.5);
                            let dy = splat.mean2d[1] - (py as f64 + 0.5);
                            let sig = mahalanobis(conic, dx, dy);
                            any |= sig <= splat.sigma_cut;
                        }
                    }
                    let touched = touches_tile(&splat, tx, ty);
                    assert!(touched || !any, "tile ({tx},{ty}) dropped for {splat:?}");
                    if touched {
                        kept += 1;
                    } else {
                        dropped += 1;
                    }
                }
            }
        }
        // The test must see both outcomes to mean anything.
        assert!(
            kept > 100 && dropped > 100,
            "kept {kept}, dropped {dropped}"
        );
    }
}
