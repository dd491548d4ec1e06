//! Nearest neighbours of points on a plane: the mean squared distance of each point to its `k`
//! nearest others, as 3DGS's `distCUDA2` gives it for the initial scales (MiraGe's and VeGaS's
//! random points on the picture plane), found on a uniform grid.

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

/// For every point, the mean squared distance to its `k` nearest other points (fewer when
/// there are fewer other points; infinity when there are none), found on a uniform grid.
pub fn mean_nearest_dist2(points: &[[f64; 2]], k: usize) -> Vec<f64> {
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

/// Points bucketed into square cells of about two points each.
struct Grid {
    min: [f64; 2],
    cell: f64,
    cols: usize,
    rows: usize,
    /// `starts[c]..starts[c + 1]` indexes `order` for cell `c`.
    starts: Vec<usize>,
    order: Vec<usize>,
}

impl Grid {
    fn new(points: &[[f64; 2]]) -> Self {
        let mut min = [f64::INFINITY; 2];
        let mut max = [f64::NEG_INFINITY; 2];
        for p in points {
            for a in 0..2 {
                min[a] = min[a].min(p[a]);
                max[a] = max[a].max(p[a]);
            }
        }
        let area = ((max[0] - min[0]) * (max[1] - min[1])).max(f64::MIN_POSITIVE);
        let side = (max[0] - min[0]).max(max[1] - min[1]);
        let cell = (2.0 * area / points.len() as f64)
            .sqrt()
            .max(side / 4096.0)
            .max(f64::MIN_POSITIVE);
        let cols = (((max[0] - min[0]) / cell) as usize + 1).min(4096);
        let rows = (((max[1] - min[1]) / cell) as usize + 1).min(4096);
        let cell_of = |p: &[f64; 2]| {
            let cx = (((p[0] - min[0]) / cell) as usize).min(cols - 1);
            let cy = (((p[1] - min[1]) / cell) as usize).min(rows - 1);
            cy * cols + cx
        };
        let mut starts = vec![0usize; cols * rows + 1];
        for p in points {
            starts[cell_of(p) + 1] += 1;
        }
        for c in 0..cols * rows {
            starts[c + 1] += starts[c];
        }
        let mut fill = starts.clone();
        let mut order = vec![0usize; points.len()];
        for (i, p) in points.iter().enumerate() {
            let c = cell_of(p);
            order[fill[c]] = i;
            fill[c] += 1;
        }
        Self {
            min,
            cell,
            cols,
            rows,
            starts,
            order,
        }
    }

    /// Searches rings of cells around point `i` until the `k` best cannot improve.
    fn mean_nearest_dist2(&self, points: &[[f64; 2]], i: usize, p: &[f64; 2], k: usize) -> f64 {
        let cx = (((p[0] - self.min[0]) / self.cell) as usize).min(self.cols - 1) as isize;
        let cy = (((p[1] - self.min[1]) / self.cell) as usize).min(self.rows - 1) as isize;
        let mut best: Vec<f64> = Vec::with_capacity(k + 1);
        let max_ring = self.cols.max(self.rows) as isize;
        for ring in 0..=max_ring {
            // Every point outside the rings searched so far is at least this far away.
            let reach = (ring - 1).max(0) as f64 * self.cell;
            if best.len() == k && best[k - 1] <= reach * reach {
                break;
            }
            for y in cy - ring..=cy + ring {
                for x in cx - ring..=cx + ring {
                    let on_ring = (y - cy).abs() == ring || (x - cx).abs() == ring;
                    if !on_ring
                        || x < 0
                        || y < 0
                        || x >= self.cols as isize
                        || y >= self.rows as isize
                    {
                        continue;
                    }
                    let c = y as usize * self.cols + x as usize;
                    for &j in &self.order[self.starts[c]..self.starts[c + 1]] {
                        if j == i {
                            continue;
                        }
                        let d2 = (points[j][0] - p[0]).powi(2) + (points[j][1] - p[1]).powi(2);
                        if best.len() < k || d2 < best[best.len() - 1] {
                            let at = best.partition_point(|&b| b <= d2);
                            best.insert(at, d2);
                            best.truncate(k);
                        }
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
    fn duplicate_and_lonely_points() {
        let same = mean_nearest_dist2(&[[0.5, 0.5]; 5], 3);
        assert!(same.iter().all(|&d| d == 0.0));
        assert_eq!(mean_nearest_dist2(&[[1.0, 2.0]], 3), vec![f64::INFINITY]);
        assert!(mean_nearest_dist2(&[], 3).is_empty());
    }
}
