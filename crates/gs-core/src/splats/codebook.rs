//! Codebooks of quantised splat formats (SOG): a 256-entry codebook of scalars, chosen as
//! `@playcanvas/splat-transform`'s `quantize1d` chooses it, and a palette of vectors (k-means).

use rayon::prelude::*;

/// Entries of a scalar codebook.
pub const ENTRIES: usize = 256;

/// A codebook of [`ENTRIES`] ascending values and each input value's entry.
pub struct Codebook {
    /// The entries, ascending (the last repeated when the values have fewer distinct ones).
    pub values: Vec<f32>,
    /// The entry of each input value, in input order.
    pub labels: Vec<u8>,
}

/// The codebook of `data` (finite values), as splat-transform 3.7's `quantize1d` (alpha 0.5)
/// builds it: the sorted values binned into `min(1024, N)` bins placed by a blend of rank and
/// value (more by rank the heavier the tails: `beta = clamp(1 - IQR / range, 0.5, 0.999)`),
/// each bin weighted by the square root of its count, and the weighted squared error of
/// cutting the bins into at most 256 runs minimised exactly (dynamic programming); each value
/// takes the nearest entry.
pub fn scalar_codebook(data: &[f32]) -> Codebook {
    let n = data.len();
    if n == 0 {
        return Codebook {
            values: vec![0.0; ENTRIES],
            labels: Vec::new(),
        };
    }
    let mut sorted = data.to_vec();
    sorted.sort_by(f32::total_cmp);
    let (lo, hi) = (f64::from(sorted[0]), f64::from(sorted[n - 1]));
    if hi - lo < 1e-20 {
        return Codebook {
            values: vec![sorted[0]; ENTRIES],
            labels: vec![0; n],
        };
    }
    let mut values = optimal_runs(&sorted, lo, hi);
    let last = *values.last().expect("at least one run");
    values.resize(ENTRIES, last);
    let labels = data.iter().map(|&v| nearest(&values, v)).collect();
    Codebook { values, labels }
}

/// The entry nearest `v` among ascending `values`: the first whose midpoint with the next is
/// above `v` (a value at a midpoint takes the upper entry), as splat-transform's binary search.
fn nearest(values: &[f32], v: f32) -> u8 {
    let (mut lo, mut hi) = (0usize, values.len() - 1);
    while lo < hi {
        let mid = (lo + hi) / 2;
        if f64::from(v) < (f64::from(values[mid]) + f64::from(values[mid + 1])) * 0.5 {
            hi = mid;
        } else {
            lo = mid + 1;
        }
    }
    lo as u8
}

/// The means of the best cut of the histogram of `sorted` (from `lo` to `hi`, `hi > lo`) into
/// at most [`ENTRIES`] runs, ascending.
fn optimal_runs(sorted: &[f32], lo: f64, hi: f64) -> Vec<f32> {
    let n = sorted.len();
    let bins = n.min(1024);
    let range = hi - lo;
    let quartile = |q: f64| f64::from(sorted[(n as f64 * q) as usize]);
    let iqr = quartile(0.75) - quartile(0.25);
    let beta = (1.0 - iqr / range).clamp(0.5, 0.999);
    let mut counts = vec![0.0f64; bins];
    let mut sums = vec![0.0f64; bins];
    for (i, &v) in sorted.iter().enumerate() {
        let v = f64::from(v);
        let by_value = (v - lo) / range;
        let by_rank = i as f64 / n as f64;
        let at = (bins as f64 * (beta * by_rank + (1.0 - beta) * by_value)).floor() as usize;
        let bin = at.min(bins - 1);
        counts[bin] += 1.0;
        sums[bin] += v;
    }
    let centres: Vec<f64> = (0..bins)
        .map(|i| match counts[i] {
            0.0 => lo + (i as f64 + 0.5) / bins as f64 * range,
            c => sums[i] / c,
        })
        .collect();
    // Prefix sums of weight, weight x centre and weight x centre², for O(1) run costs.
    let mut w = vec![0.0f64; bins + 1];
    let mut wx = vec![0.0f64; bins + 1];
    let mut wxx = vec![0.0f64; bins + 1];
    for i in 0..bins {
        let weight = if counts[i] > 0.0 {
            counts[i].powf(0.5)
        } else {
            0.0
        };
        w[i + 1] = w[i] + weight;
        wx[i + 1] = wx[i] + weight * centres[i];
        wxx[i + 1] = wxx[i] + weight * centres[i] * centres[i];
    }
    // The weighted squared error of one run over bins a..=b, and its mean.
    let cost = |a: usize, b: usize| {
        let sw = w[b + 1] - w[a];
        if sw <= 0.0 {
            return 0.0;
        }
        let swx = wx[b + 1] - wx[a];
        (wxx[b + 1] - wxx[a]) - swx * swx / sw
    };
    let mean = |a: usize, b: usize| {
        let sw = w[b + 1] - w[a];
        if sw <= 0.0 {
            (centres[a] + centres[b]) * 0.5
        } else {
            (wx[b + 1] - wx[a]) / sw
        }
    };
    let runs = ENTRIES.min(counts.iter().filter(|&&c| c > 0.0).count());
    const UNREACHED: f64 = 1e30;
    // best[j]: the least error of bins 0..=j in m runs; cut[m][j]: the last bin of run m - 1.
    let mut best: Vec<f64> = (0..bins).map(|j| cost(0, j)).collect();
    let mut cut: Vec<Vec<i32>> = vec![Vec::new(), vec![-1; bins]];
    for m in 2..=runs {
        let previous = best;
        let mut cut_m = vec![0i32; bins];
        best = vec![UNREACHED; bins];
        for j in m - 1..bins {
            let (mut least, mut at) = (UNREACHED, m - 2);
            for s in m - 2..j {
                let c = previous[s] + cost(s + 1, j);
                if c < least {
                    least = c;
                    at = s;
                }
            }
            best[j] = least;
            cut_m[j] = at as i32;
        }
        cut.push(cut_m);
    }
    let mut out = vec![0.0f32; runs];
    let mut j = bins as i32 - 1;
    for m in (1..=runs).rev() {
        let s = if m > 1 { cut[m][j as usize] } else { -1 };
        out[m - 1] = mean((s + 1) as usize, j as usize) as f32;
        j = s;
    }
    out.sort_by(f32::total_cmp);
    out
}

/// A palette of vectors: entries of `dim` values each, and each input vector's entry.
pub struct Palette {
    /// The entries, `dim` values each, one after another.
    pub entries: Vec<f32>,
    /// The entry of each input vector, in input order.
    pub labels: Vec<u32>,
}

/// Lloyd iterations a palette's k-means runs (splat-transform's default).
const ITERATIONS: usize = 10;

/// Entries of the first level of a two-level palette.
const COARSE: usize = 256;

/// A palette of at most `size` entries for the `points` (`dim` values each), deterministic:
/// each point its own entry when there are no more points than `size`; k-means (10 Lloyd
/// iterations from evenly spaced points) up to 256 entries; above that two levels (256
/// clusters, each split by k-means into entries in proportion to its points), so the work
/// grows as `points x (256 + entries / 256)` rather than `points x entries`.
pub fn palette(points: &[f32], dim: usize, size: usize) -> Palette {
    let n = points.len() / dim;
    if n <= size {
        return Palette {
            entries: points.to_vec(),
            labels: (0..n as u32).collect(),
        };
    }
    let all: Vec<u32> = (0..n as u32).collect();
    if size <= COARSE {
        return kmeans(points, dim, &all, size);
    }
    let coarse = kmeans(points, dim, &all, COARSE);
    let mut members = vec![Vec::new(); COARSE];
    for (i, &label) in coarse.labels.iter().enumerate() {
        members[label as usize].push(i as u32);
    }
    // Every non-empty cluster has an entry; the rest are shared in proportion to size.
    let spare = size - COARSE;
    let mut entries = Vec::new();
    let mut labels = vec![0u32; n];
    for group in members.iter().filter(|g| !g.is_empty()) {
        let k = (1 + spare * group.len() / n).min(group.len());
        let part = kmeans(points, dim, group, k);
        let first = (entries.len() / dim) as u32;
        entries.extend(part.entries);
        for (&i, &label) in group.iter().zip(&part.labels) {
            labels[i as usize] = first + label;
        }
    }
    Palette { entries, labels }
}

/// k-means of the points `members` (indices of `dim`-value vectors in `points`) into `k`
/// entries (`k <= members.len()`), seeded with evenly spaced members; an entry left without
/// points keeps its place. Labels are indices into the `k` entries, in `members` order.
fn kmeans(points: &[f32], dim: usize, members: &[u32], k: usize) -> Palette {
    let point = |i: u32| &points[i as usize * dim..(i as usize + 1) * dim];
    let mut entries: Vec<f32> = (0..k)
        .flat_map(|c| point(members[c * members.len() / k]).iter().copied())
        .collect();
    let mut labels = vec![0u32; members.len()];
    for _ in 0..ITERATIONS {
        labels = members
            .par_iter()
            .map(|&i| nearest_entry(&entries, dim, point(i)))
            .collect();
        let mut sums = vec![0.0f64; k * dim];
        let mut counts = vec![0usize; k];
        for (&i, &label) in members.iter().zip(&labels) {
            let c = label as usize;
            counts[c] += 1;
            for (s, &v) in sums[c * dim..(c + 1) * dim].iter_mut().zip(point(i)) {
                *s += f64::from(v);
            }
        }
        for c in (0..k).filter(|&c| counts[c] > 0) {
            for d in 0..dim {
                entries[c * dim + d] = (sums[c * dim + d] / counts[c] as f64) as f32;
            }
        }
    }
    Palette { entries, labels }
}

/// The index of the entry of `entries` (`dim` values each) nearest `v` in squared distance,
/// the first on a tie.
fn nearest_entry(entries: &[f32], dim: usize, v: &[f32]) -> u32 {
    let mut best = (f32::INFINITY, 0u32);
    for (c, e) in entries.chunks_exact(dim).enumerate() {
        let d: f32 = e.iter().zip(v).map(|(a, b)| (a - b) * (a - b)).sum();
        if d < best.0 {
            best = (d, c as u32);
        }
    }
    best.1
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn few_distinct_values_are_kept_exactly() {
        let data = [3.0f32, -1.0, 3.0, 0.5, -1.0, 0.5, 0.5];
        let book = scalar_codebook(&data);
        assert_eq!(book.values.len(), ENTRIES);
        // Entries ascend, the last repeated; a value may hold two (its rank spans two bins).
        let mut distinct = book.values.clone();
        distinct.dedup();
        assert_eq!(distinct, [-1.0, 0.5, 3.0]);
        assert!(book.values.windows(2).all(|w| w[0] <= w[1]));
        for (&v, &label) in data.iter().zip(&book.labels) {
            assert_eq!(book.values[usize::from(label)], v);
        }
    }

    #[test]
    fn one_value_gives_one_entry_and_label_zero() {
        let book = scalar_codebook(&[2.5; 9]);
        assert!(book.values.iter().all(|&v| v == 2.5));
        assert!(book.labels.iter().all(|&l| l == 0));
    }

    #[test]
    fn many_values_are_within_a_small_step_of_their_entry() {
        // 3000 values spread over [-4, 4] with a long tail: no value is far from its entry,
        // and the entries are ascending and distinct.
        let data: Vec<f32> = (0..3000)
            .map(|i| {
                let t = i as f32 / 2999.0 * 2.0 - 1.0;
                4.0 * t * t * t
            })
            .collect();
        let book = scalar_codebook(&data);
        assert!(book.values.windows(2).all(|w| w[0] < w[1]));
        let worst = data
            .iter()
            .zip(&book.labels)
            .map(|(&v, &l)| (v - book.values[usize::from(l)]).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 0.08, "worst quantisation error {worst}");
    }

    #[test]
    fn a_value_at_a_midpoint_takes_the_upper_entry() {
        let values = [0.0f32, 1.0, 2.0];
        assert_eq!(nearest(&values, 0.5), 1);
        assert_eq!(nearest(&values, 0.49), 0);
        assert_eq!(nearest(&values, 1.5), 2);
        assert_eq!(nearest(&values, -7.0), 0);
        assert_eq!(nearest(&values, 9.0), 2);
    }

    #[test]
    fn a_palette_labels_each_point_with_a_near_entry() {
        // Points around 600 distinct centres in 3 dimensions, 4 each: a palette of 1024 entries
        // (two levels) puts every point within its cluster's spread of its entry.
        let dim = 3;
        let mut points = Vec::new();
        for c in 0..600 {
            let centre = [(c % 10) as f32, (c / 10 % 10) as f32, (c / 100) as f32];
            for j in 0..4 {
                for d in 0..dim {
                    points.push(centre[d] + 0.01 * ((j * 3 + d) % 5) as f32);
                }
            }
        }
        for size in [64, 1024] {
            let p = palette(&points, dim, size);
            assert!(p.entries.len() / dim <= size);
            let worst = points
                .chunks_exact(dim)
                .zip(&p.labels)
                .map(|(v, &l)| {
                    let e = &p.entries[l as usize * dim..(l as usize + 1) * dim];
                    e.iter()
                        .zip(v)
                        .map(|(a, b)| (a - b).abs())
                        .fold(0.0, f32::max)
                })
                .fold(0.0f32, f32::max);
            // 64 entries for 600 clusters cannot be exact; 1024 can nearly be.
            let bound = if size == 64 { 2.0 } else { 0.05 };
            assert!(worst < bound, "size {size}: worst {worst}");
        }
        let few = palette(&points[..12], dim, 8);
        assert_eq!(few.entries, points[..12]);
        assert_eq!(few.labels, [0, 1, 2, 3]);
    }
}
