//! Nearest neighbours of points on a plane (or in space): the mean squared distance of each
//! point to its `k` nearest others, as 3DGS's `distCUDA2` gives it for the initial scales
//! (MiraGe's and VeGaS's random points on the picture plane, D-MiSo's random points in a cube),
//! found on a uniform grid.

use rand::Rng;
use rayon::prelude::*;

/// Lower bound of the mean squared neighbour distance, world units squared (`distCUDA2`'s).
pub const MIN_DIST2: f64 = 1e-7;

/// `count` points drawn from `rng` uniformly on the rectangle `[-half_width, half_width] x
/// [-half_height, half_height]`, and each one's initial log-scale
/// `ln sqrt(max(mean squared distance to its 3 nearest others, MIN_DIST2))`, as MiraGe and VeGaS
/// initialise the Gaussians of a picture plane.
pub fn random_points_with_log_scales<R: Rng>(
    count: usize,
    half_width: f64,
    half_height: f64,
    rng: &mut R,
) -> Vec<([f64; 2], f64)> {
    let points: Vec<[f64; 2]> = (0..count)
        .map(|_| {
            [
                rng.random_range(-half_width..=half_width),
                rng.random_range(-half_height..=half_height),
            ]
        })
        .collect();
    let dist2 = mean_nearest_dist2(&points, 3);
    points
        .into_iter()
        .zip(dist2)
        .map(|(p, d2)| (p, 0.5 * d2.max(MIN_DIST2).ln()))
        .collect()
}

/// For every point (of 2 or 3 coordinates), the mean squared distance to its `k` nearest other
/// points (fewer when there are fewer other points; infinity when there are none), found on a
/// uniform grid.
pub fn mean_nearest_dist2<const D: usize>(points: &[[f64; D]], k: usize) -> Vec<f64> {
    if points.is_empty() {
        return Vec::new();
    }
    let grid = Grid::new(points);
    points
        .par_iter()
        .enumerate()
        .map(|(i, p)| grid.mean_nearest_dist2(points, i, p, k))
        .collect()
}

/// Points bucketed into cubic cells of about two points each.
struct Grid<const D: usize> {
    min: [f64; D],
    cell: f64,
    /// Cells along each axis.
    dims: [usize; D],
    /// `starts[c]..starts[c + 1]` indexes `order` for cell `c`.
    starts: Vec<usize>,
    order: Vec<usize>,
}

impl<const D: usize> Grid<D> {
    /// Most cells along one axis: 4096 in 2D, 256 in 3D (about 16.7 million cells).
    const MAX_CELLS: usize = match D {
        1 | 2 => 4096,
        _ => 256,
    };

    fn new(points: &[[f64; D]]) -> Self {
        let mut min = [f64::INFINITY; D];
        let mut max = [f64::NEG_INFINITY; D];
        for p in points {
            for a in 0..D {
                min[a] = min[a].min(p[a]);
                max[a] = max[a].max(p[a]);
            }
        }
        let volume = (0..D)
            .map(|a| max[a] - min[a])
            .product::<f64>()
            .max(f64::MIN_POSITIVE);
        let side = (0..D).map(|a| max[a] - min[a]).fold(0.0, f64::max);
        let cell = (2.0 * volume / points.len() as f64)
            .powf(1.0 / D as f64)
            .max(side / Self::MAX_CELLS as f64)
            .max(f64::MIN_POSITIVE);
        let mut dims = [0; D];
        for a in 0..D {
            dims[a] = (((max[a] - min[a]) / cell) as usize + 1).min(Self::MAX_CELLS);
        }
        let mut grid = Self {
            min,
            cell,
            dims,
            starts: Vec::new(),
            order: Vec::new(),
        };
        let cells: usize = dims.iter().product();
        let mut starts = vec![0usize; cells + 1];
        for p in points {
            starts[grid.index(&grid.cell_of(p)) + 1] += 1;
        }
        for c in 0..cells {
            starts[c + 1] += starts[c];
        }
        let mut fill = starts.clone();
        let mut order = vec![0usize; points.len()];
        for (i, p) in points.iter().enumerate() {
            let c = grid.index(&grid.cell_of(p));
            order[fill[c]] = i;
            fill[c] += 1;
        }
        grid.starts = starts;
        grid.order = order;
        grid
    }

    /// The cell coordinates of `p`.
    fn cell_of(&self, p: &[f64; D]) -> [isize; D] {
        let mut c = [0isize; D];
        for a in 0..D {
            c[a] = (((p[a] - self.min[a]) / self.cell) as usize).min(self.dims[a] - 1) as isize;
        }
        c
    }

    /// The index of the cell at `c` (inside the grid).
    fn index(&self, c: &[isize; D]) -> usize {
        (0..D)
            .rev()
            .fold(0, |i, a| i * self.dims[a] + c[a] as usize)
    }

    /// Searches shells of cells around point `i` until the `k` best cannot improve.
    fn mean_nearest_dist2(&self, points: &[[f64; D]], i: usize, p: &[f64; D], k: usize) -> f64 {
        let centre = self.cell_of(p);
        let mut best: Vec<f64> = Vec::with_capacity(k + 1);
        let max_ring = self.dims.iter().copied().max().unwrap_or(1) as isize;
        for ring in 0..=max_ring {
            // Every point outside the shells searched so far is at least this far away.
            let reach = (ring - 1).max(0) as f64 * self.cell;
            if best.len() == k && best[k - 1] <= reach * reach {
                break;
            }
            let side = (2 * ring + 1) as usize;
            for n in 0..side.pow(D as u32) {
                let mut c = [0isize; D];
                let mut rest = n;
                let mut on_shell = false;
                let mut inside = true;
                for a in 0..D {
                    let offset = (rest % side) as isize - ring;
                    rest /= side;
                    on_shell |= offset.abs() == ring;
                    c[a] = centre[a] + offset;
                    inside &= c[a] >= 0 && c[a] < self.dims[a] as isize;
                }
                if !on_shell || !inside {
                    continue;
                }
                let cell = self.index(&c);
                for &j in &self.order[self.starts[cell]..self.starts[cell + 1]] {
                    if j == i {
                        continue;
                    }
                    let d2: f64 = (0..D).map(|a| (points[j][a] - p[a]).powi(2)).sum();
                    if best.len() < k || d2 < best[best.len() - 1] {
                        let at = best.partition_point(|&b| b <= d2);
                        best.insert(at, d2);
                        best.truncate(k);
                    }
                }
            }
        }
        if best.is_empty() {
            f64::INFINITY
        } else {
            best.iter().sum::<f64>() / best.len() as f64
        }
    }
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;

    fn brute_force(points: &[[f64; 2]], k: usize) -> Vec<f64> {
        (0..points.len())
            .map(|i| {
                let mut d: Vec<f64> = (0..points.len())
                    .filter(|&j| j != i)
                    .map(|j| {
                        (points[j][0] - points[i][0]).powi(2)
                            + (points[j][1] - points[i][1]).powi(2)
                    })
                    .collect();
                d.sort_by(f64::total_cmp);
                d.truncate(k);
                d.iter().sum::<f64>() / d.len() as f64
            })
            .collect()
    }

    #[test]
    fn grid_neighbours_equal_brute_force() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for (n, w, h) in [
            (500, 1.0, 1.0),
            (300, 3.0, 0.01),
            (4, 1.0, 1.0),
            (50, 0.0, 1.0),
        ] {
            let points: Vec<[f64; 2]> = (0..n)
                .map(|_| [rng.random_range(-w..=w), rng.random_range(-h..=h)])
                .collect();
            let grid = mean_nearest_dist2(&points, 3);
            let exact = brute_force(&points, 3);
            for (a, b) in grid.iter().zip(&exact) {
                assert!((a - b).abs() <= 1e-12 * b.max(1e-30), "{a} vs {b} (n {n})");
            }
        }
    }

    #[test]
    fn grid_neighbours_in_space_equal_brute_force() {
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        for (n, w) in [
            (400, [1.3, 1.3, 1.3]),
            (200, [2.0, 0.01, 1.0]),
            (3, [1.0; 3]),
        ] {
            let points: Vec<[f64; 3]> = (0..n)
                .map(|_| w.map(|s: f64| rng.random_range(-s..=s)))
                .collect();
            let grid = mean_nearest_dist2(&points, 3);
            for (i, a) in grid.iter().enumerate() {
                let mut d: Vec<f64> = (0..n)
                    .filter(|&j| j != i)
                    .map(|j| (0..3).map(|k| (points[j][k] - points[i][k]).powi(2)).sum())
                    .collect();
                d.sort_by(f64::total_cmp);
                d.truncate(3);
                let b = d.iter().sum::<f64>() / d.len() as f64;
                assert!((a - b).abs() <= 1e-12 * b.max(1e-30), "{a} vs {b} (n {n})");
            }
        }
    }

    #[test]
    fn duplicate_and_lonely_points() {
        let same = mean_nearest_dist2(&[[0.5, 0.5]; 5], 3);
        assert!(same.iter().all(|&d| d == 0.0));
        assert_eq!(mean_nearest_dist2(&[[1.0, 2.0]], 3), vec![f64::INFINITY]);
        assert!(mean_nearest_dist2::<2>(&[], 3).is_empty());
    }
}
