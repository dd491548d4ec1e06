//! 3DGS's adaptive density control on a [`GaussianSet`], as INRIA's `train.py` and
//! `gaussian_model.py` do it (commit 54c035f; docs/fidelity.md):
//!
//! - [`ScreenStats`]: each Gaussian's view-space positional gradient norm summed over the views
//!   that saw it (`xyz_gradient_accum`, `denom`);
//! - [`densify`]: clone the small Gaussians and split the large ones whose mean gradient reaches
//!   the threshold, then prune the nearly transparent ones (and, late, the world-large ones);
//! - [`reset_opacity`]: lower every opacity to at most 0.01;
//! - [`raise_sh_degree`]: one more SH degree, its coefficients zero.
//!
//! Each returns how every parameter group's rows changed ([`RowChange`], in [`PARAM_NAMES`]
//! order), so that the optimizer's moments follow them as PyTorch's do: kept for surviving
//! Gaussians, zero for new ones and for replaced values.

use rand::Rng;

use crate::adam::RowChange;
use crate::gaussians::{row_widths, sh_coeff_count, GaussianSet, MAX_SH_DEGREE, PARAM_NAMES};
use crate::mat::quat_to_rotation;
use crate::raster::Rendered;
use crate::real::Real;

/// When and how 3DGS densifies (INRIA's `OptimizationParams` defaults), in 1-based steps.
#[derive(Clone, Debug, PartialEq)]
pub struct DensifySettings {
    /// Densification runs at steps after this one (`densify_from_iter`, 500).
    pub from: u64,
    /// ... and before this one (`densify_until_iter`, 15,000); the statistics are gathered and
    /// the opacity reset only before it too.
    pub until: u64,
    /// Steps between densifications (`densification_interval`, 100).
    pub every: u64,
    /// Mean view-space gradient norm from which a Gaussian is cloned or split
    /// (`densify_grad_threshold`, 0.0002).
    pub grad_threshold: f32,
    /// Gaussians whose largest scale is above this fraction of the scene extent are split, the
    /// others cloned (`percent_dense`, 0.01).
    pub percent_dense: f32,
    /// Gaussians below this opacity are pruned (0.005, fixed in `train.py`).
    pub min_opacity: f32,
    /// Steps between opacity resets (`opacity_reset_interval`, 3,000); after the first, the
    /// world-large Gaussians are pruned too.
    pub opacity_reset_every: u64,
    /// From the first reset on, Gaussians whose largest scale is above this fraction of the
    /// extent are pruned (0.1, fixed in `densify_and_prune`).
    pub max_world_fraction: f32,
    /// The most Gaussians a densification may leave before its prune (`None`: no cap, as
    /// INRIA): when the clones and splits would pass it, those of the largest mean gradient
    /// are made, one more Gaussian each, until it is reached.
    pub max_len: Option<usize>,
}

impl Default for DensifySettings {
    fn default() -> Self {
        Self {
            from: 500,
            until: 15_000,
            every: 100,
            grad_threshold: 2e-4,
            percent_dense: 0.01,
            min_opacity: 0.005,
            opacity_reset_every: 3000,
            max_world_fraction: 0.1,
            max_len: None,
        }
    }
}

impl DensifySettings {
    /// Whether step `step` gathers statistics (`iteration < densify_until_iter`).
    pub fn gathers_at(&self, step: u64) -> bool {
        step < self.until
    }

    /// Whether the Gaussians are densified after step `step`.
    pub fn densifies_at(&self, step: u64) -> bool {
        self.gathers_at(step) && step > self.from && step.is_multiple_of(self.every.max(1))
    }

    /// Whether the world-large Gaussians are pruned at a densification after step `step`
    /// (`size_threshold` is set once `iteration > opacity_reset_interval`).
    pub fn prunes_large_at(&self, step: u64) -> bool {
        step > self.opacity_reset_every
    }

    /// Whether the opacities are reset after step `step`: every `opacity_reset_every` steps,
    /// and at `from` over a white background.
    pub fn resets_opacity_at(&self, step: u64, white_background: bool) -> bool {
        self.gathers_at(step)
            && (step.is_multiple_of(self.opacity_reset_every.max(1))
                || (white_background && step == self.from))
    }

    /// A setting that cannot run, named.
    pub fn check(&self) -> Result<(), String> {
        let positive = [
            ("densify_every", self.every as f64),
            ("opacity_reset_every", self.opacity_reset_every as f64),
            ("densify_grad_threshold", self.grad_threshold as f64),
            ("percent_dense", self.percent_dense as f64),
            ("max_world_fraction", self.max_world_fraction as f64),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{name} = {v}: must be a positive number"));
            }
        }
        if self.max_len == Some(0) {
            return Err("max_gaussians = 0: must be at least 1 (--max-gaussians)".into());
        }
        if !(0.0..1.0).contains(&self.min_opacity) {
            return Err(format!(
                "min_opacity = {}: must be in [0, 1)",
                self.min_opacity
            ));
        }
        Ok(())
    }
}

/// Each Gaussian's view-space positional gradient norm summed over the views that saw it, and
/// their count: INRIA's `xyz_gradient_accum` and `denom`. The view-space gradient is the
/// gradient with respect to the projected centre in normalized device coordinates, `W / 2`
/// (`H / 2`) pixels a unit: the pixel gradient times `W / 2` and `H / 2`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ScreenStats {
    /// Sum of the norms, one per Gaussian.
    pub grad_sum: Vec<f32>,
    /// Views that saw each Gaussian (`radii > 0`).
    pub count: Vec<u32>,
}

impl ScreenStats {
    /// Empty statistics of `len` Gaussians.
    pub fn new(len: usize) -> Self {
        Self {
            grad_sum: vec![0.0; len],
            count: vec![0; len],
        }
    }

    /// The number of Gaussians.
    pub fn len(&self) -> usize {
        self.count.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.count.is_empty()
    }

    /// Adds one view: `screen_grads` (dL/d(projected centre) in pixels, as
    /// [`crate::raster::backward_with_screen_grads`] gives them) of the Gaussians `rendered`
    /// shows, in a picture `width` x `height`.
    ///
    /// # Panics
    /// If the lengths differ from the statistics'.
    pub fn add_view(
        &mut self,
        rendered: &Rendered<f32>,
        screen_grads: &[[f32; 2]],
        (width, height): (u32, u32),
    ) {
        assert_eq!(screen_grads.len(), self.len(), "one gradient per Gaussian");
        let (sx, sy) = (0.5 * width as f32, 0.5 * height as f32);
        for (i, g) in screen_grads.iter().enumerate() {
            if rendered.is_visible(i) {
                self.grad_sum[i] += (g[0] * sx).hypot(g[1] * sy);
                self.count[i] += 1;
            }
        }
    }

    /// An error when statistics of `len` Gaussians meet a view of `rendered` Gaussians (checked
    /// by each backend's trainer before it renders).
    pub fn check_rendered(len: usize, rendered: usize) -> Result<(), String> {
        if len == rendered {
            Ok(())
        } else {
            Err(format!(
                "densification statistics of {len} Gaussians, {rendered} rendered"
            ))
        }
    }

    /// The mean norm of Gaussian `i` (0 when no view saw it, as INRIA's `grads[grads.isnan()]
    /// = 0`).
    pub fn mean(&self, i: usize) -> f32 {
        if self.count[i] == 0 {
            0.0
        } else {
            self.grad_sum[i] / self.count[i] as f32
        }
    }
}

/// The largest of Gaussian `i`'s three scales (world units).
fn max_scale(set: &GaussianSet, i: usize) -> f32 {
    let s = &set.log_scales[3 * i..3 * i + 3];
    s[0].max(s[1]).max(s[2]).exp()
}

/// One standard normal value (Box-Muller), for the split samples (3DGS's here, D-MiSo's on
/// its triangles).
pub fn standard_normal(rng: &mut impl Rng) -> f64 {
    let u1: f64 = rng.random_range(f64::MIN_POSITIVE..1.0);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// `set` densified after `stats` in a scene of camera extent `extent` (`cameras_extent`), as
/// INRIA's `densify_and_prune`: with `g` a Gaussian's [`ScreenStats::mean`] and `s` its largest
/// scale,
///
/// 1. clone: `g >= grad_threshold` and `s <= percent_dense * extent`: a copy is appended;
/// 2. split: `g >= grad_threshold` and `s > percent_dense * extent`: two children are
///    appended (all first children, then all second ones), each centred at a sample of the
///    Gaussian's own normal distribution, with its scales divided by 1.6, and the original
///    removed;
/// 3. prune: the Gaussians (clones and children included) of opacity below `min_opacity` and,
///    with `prune_large` ([`DensifySettings::prunes_large_at`]), those of `s` above
///    `max_world_fraction * extent` are removed.
///
/// The order of the rows is INRIA's: the kept originals, then the clones, then the children.
/// INRIA's screen-size prune (`max_radii2D > 20`) is not done: `densification_postfix` zeroes
/// `max_radii2D` before it is read, so it never removes anything there either. Returns the
/// new set and each group's [`RowChange`]; an error when nothing would remain.
pub fn densify(
    set: &GaussianSet,
    stats: &ScreenStats,
    extent: f32,
    settings: &DensifySettings,
    prune_large: bool,
    rng: &mut impl Rng,
) -> Result<(GaussianSet, Vec<RowChange>), String> {
    let n = set.len();
    if stats.len() != n {
        return Err(format!(
            "statistics of {} Gaussians for a set of {n}",
            stats.len()
        ));
    }
    let dense_limit = settings.percent_dense * extent;
    let reaches = |i: usize| stats.mean(i) >= settings.grad_threshold;
    let cloned: Vec<usize> = (0..n)
        .filter(|&i| reaches(i) && max_scale(set, i) <= dense_limit)
        .collect();
    let split: Vec<usize> = (0..n)
        .filter(|&i| reaches(i) && max_scale(set, i) > dense_limit)
        .collect();
    let (cloned, split) = match settings.max_len {
        Some(max) if n + cloned.len() + split.len() > max => {
            let mut by_gradient: Vec<usize> = cloned.iter().chain(&split).copied().collect();
            by_gradient.sort_by(|&a, &b| stats.mean(b).total_cmp(&stats.mean(a)).then(a.cmp(&b)));
            let mut chosen = vec![false; n];
            for &i in by_gradient.iter().take(max.saturating_sub(n)) {
                chosen[i] = true;
            }
            let keep = |list: Vec<usize>| list.into_iter().filter(|&i| chosen[i]).collect();
            (keep(cloned), keep(split))
        }
        _ => (cloned, split),
    };
    // Every candidate row: the kept originals, the clones, the children; with the source of
    // each (for the moments: `None` for the new rows).
    let mut is_split = vec![false; n];
    for &i in &split {
        is_split[i] = true;
    }
    let kept: Vec<usize> = (0..n).filter(|&i| !is_split[i]).collect();
    let mut rows = kept.clone();
    rows.extend(&cloned);
    rows.extend(&split);
    rows.extend(&split);
    let mut from: Vec<Option<usize>> = kept.iter().map(|&i| Some(i)).collect();
    from.resize(rows.len(), None);
    let mut grown = set.gather(&rows);
    let children = kept.len() + cloned.len();
    for (row, &i) in (children..rows.len()).zip(&rows[children..]) {
        let s = [0, 1, 2].map(|a| set.log_scales[3 * i + a].exp());
        let z = [0, 1, 2].map(|a| s[a] * standard_normal(rng) as f32);
        let q = &set.quats[4 * i..4 * i + 4];
        let norm = q
            .iter()
            .map(|x| x * x)
            .sum::<f32>()
            .sqrt()
            .max(f32::MIN_POSITIVE);
        let r = quat_to_rotation([q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm]);
        for a in 0..3 {
            let offset: f32 = (0..3).map(|b| r[a][b] * z[b]).sum();
            grown.means[3 * row + a] += offset;
            grown.log_scales[3 * row + a] = (s[a] / 1.6).ln();
        }
    }
    // The prune, over every candidate.
    let world_limit = settings.max_world_fraction * extent;
    let survivors: Vec<usize> = (0..rows.len())
        .filter(|&row| {
            let transparent = grown.opacity_logits[row].sigmoid() < settings.min_opacity;
            let large = prune_large && max_scale(&grown, row) > world_limit;
            !(transparent || large)
        })
        .collect();
    let kept_from: Vec<Option<usize>> = survivors.iter().map(|&row| from[row]).collect();
    let dense = grown.gather(&survivors);
    if kept_from.is_empty() {
        return Err(format!(
            "densification would remove all {n} Gaussians (every one below opacity {} or \
             larger than {} of the scene)",
            settings.min_opacity, settings.max_world_fraction
        ));
    }
    let changes = row_widths(set.sh_degree())
        .into_iter()
        .map(|width| RowChange::Rows {
            width,
            from: kept_from.clone(),
        })
        .collect();
    Ok((dense, changes))
}

/// INRIA's `reset_opacity`: every opacity above 0.01 lowered to 0.01; the opacities' moments
/// restart ([`RowChange::Reset`]), the other groups' are kept.
pub fn reset_opacity(set: &mut GaussianSet) -> Vec<RowChange> {
    let cap = (0.01f64 / 0.99).ln() as f32;
    for o in &mut set.opacity_logits {
        *o = o.min(cap);
    }
    PARAM_NAMES
        .iter()
        .map(|&name| {
            if name == "opacities" {
                RowChange::Reset
            } else {
                RowChange::Keep
            }
        })
        .collect()
}

/// `set` with one more SH degree (INRIA's `oneupSHdegree`), the new coefficients zero, and how
/// the groups' rows changed (the new coefficients' moments zero); `None` at
/// [`MAX_SH_DEGREE`]. INRIA holds every degree from the start and renders the active ones
/// only; the coefficients above them get no gradient, so their values and moments stay zero,
/// as these do.
pub fn raise_sh_degree(set: &GaussianSet) -> Option<(GaussianSet, Vec<RowChange>)> {
    let degree = set.sh_degree();
    if degree >= MAX_SH_DEGREE {
        return None;
    }
    let (old, new) = (
        3 * (sh_coeff_count(degree) - 1),
        3 * (sh_coeff_count(degree + 1) - 1),
    );
    let mut wider = GaussianSet::zeros(set.len(), degree + 1);
    for (to, from) in wider.arrays_mut().into_iter().zip(set.arrays()).take(5) {
        to.copy_from_slice(from);
    }
    for (i, to) in wider.sh_rest.chunks_exact_mut(new).enumerate() {
        to[..old].copy_from_slice(&set.sh_rest[i * old..(i + 1) * old]);
    }
    let changes = PARAM_NAMES
        .iter()
        .map(|&name| {
            if name == "sh_rest" {
                RowChange::Widen {
                    rows: set.len(),
                    old,
                    new,
                }
            } else {
                RowChange::Keep
            }
        })
        .collect();
    Some((wider, changes))
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::camera::Camera;
    use crate::raster::{backward_with_screen_grads, render, GradMask, OutputGrads};

    /// `sigmoid^-1(p)`.
    fn logit(p: f32) -> f32 {
        (p / (1.0 - p)).ln()
    }

    /// Seven Gaussians of degree 1, each marked by its DC red (= its index), at extent 2 with
    /// `percent_dense` 0.5 (so the clone/split limit is exactly 1.0, a log-scale of 0):
    /// 0 reaches the gradient and is small (clone); 1 reaches it and is large (split); 2 stays
    /// under it; 3 has exactly the threshold (clone: `>=`); 4 reaches it at exactly the limit
    /// (clone: `<=`); 5 reaches it, small but nearly transparent (cloned, then both pruned);
    /// 6 was never seen (mean 0).
    fn case() -> (GaussianSet, ScreenStats, DensifySettings) {
        let mut set = GaussianSet::zeros(7, 1);
        let log_scale = [-2.0, 0.5, -2.0, -2.0, 0.0, -2.0, -2.0];
        for i in 0..7 {
            set.means[3 * i] = i as f32;
            set.log_scales[3 * i..3 * i + 3].copy_from_slice(&[log_scale[i], -3.0, -3.0]);
            set.opacity_logits[i] = logit(0.5);
            set.sh_dc[3 * i] = i as f32;
            set.sh_rest[9 * i] = 10.0 + i as f32;
        }
        set.opacity_logits[5] = logit(0.004);
        let settings = DensifySettings {
            percent_dense: 0.5,
            ..DensifySettings::default()
        };
        let t = settings.grad_threshold;
        let stats = ScreenStats {
            grad_sum: vec![3.0 * t, 2.0 * t, 0.5 * t, t, 4.0 * t, 9.0 * t, 0.0],
            count: vec![1, 1, 1, 1, 2, 1, 0],
        };
        (set, stats, settings)
    }

    fn reds(set: &GaussianSet) -> Vec<f32> {
        set.sh_dc.chunks_exact(3).map(|c| c[0]).collect()
    }

    #[test]
    fn clones_splits_and_prunes_as_inria_in_its_order() {
        let (set, stats, settings) = case();
        assert_eq!(stats.mean(3), settings.grad_threshold);
        assert_eq!(max_scale(&set, 4), 2.0 * settings.percent_dense);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let (dense, changes) = densify(&set, &stats, 2.0, &settings, false, &mut rng).unwrap();
        // Kept originals (1 split away, 5 pruned), clones (5's pruned), then both children of 1.
        assert_eq!(
            reds(&dense),
            [0.0, 2.0, 3.0, 4.0, 6.0, 0.0, 3.0, 4.0, 1.0, 1.0]
        );
        let from = vec![
            Some(0),
            Some(2),
            Some(3),
            Some(4),
            Some(6),
            None,
            None,
            None,
            None,
            None,
        ];
        let widths = [3, 3, 4, 1, 3, 9];
        assert_eq!(changes.len(), 6);
        for (change, width) in changes.iter().zip(widths) {
            assert_eq!(
                change,
                &RowChange::Rows {
                    width,
                    from: from.clone()
                }
            );
        }
        // A clone is its source exactly, higher SH included.
        assert_eq!(dense.gather(&[5]), set.gather(&[0]));
        // The children: scales / 1.6 in log space, everything but the centre copied, the
        // centres offset along the axes by at most a few of the parent's scales.
        for child in [8, 9] {
            let s = &dense.log_scales[3 * child..3 * child + 3];
            for (a, parent) in [0.5f32, -3.0, -3.0].iter().enumerate() {
                assert!((s[a] - (parent.exp() / 1.6).ln()).abs() < 1e-6, "{s:?}");
            }
            assert_eq!(dense.sh_rest[9 * child], 11.0);
            assert_eq!(dense.opacity_logits[child], set.opacity_logits[1]);
            let m = &dense.means[3 * child..3 * child + 3];
            assert!((m[0] - 1.0).abs() < 5.0 * 0.5f32.exp(), "{m:?}");
            assert!(
                m[1].abs() < 5.0 * (-3.0f32).exp() && m[2].abs() < 0.3,
                "{m:?}"
            );
        }
        assert_ne!(dense.means[24], dense.means[27], "two samples");
    }

    #[test]
    fn after_the_first_reset_the_world_large_are_pruned_too() {
        let (set, stats, settings) = case();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        // World limit 0.1 * 2 = 0.2: the scale-1.0 Gaussian (4) and its clone go, and the
        // children of 1 (e^0.5 / 1.6 = 1.03) too; the small ones stay.
        let (dense, _) = densify(&set, &stats, 2.0, &settings, true, &mut rng).unwrap();
        assert_eq!(reds(&dense), [0.0, 2.0, 3.0, 6.0, 0.0, 3.0]);
        assert!(!settings.prunes_large_at(3000) && settings.prunes_large_at(3001));
    }

    #[test]
    fn a_cap_grows_the_largest_gradients_first_and_nothing_past_it() {
        let (set, stats, mut settings) = case();
        // 7 Gaussians, room for 2 more: the two largest means that reach the threshold are
        // 5 (9t) and 0 (3t); 4 (2t a view), 1 (2t) and 3 (t) wait.
        settings.max_len = Some(9);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let (dense, _) = densify(&set, &stats, 2.0, &settings, false, &mut rng).unwrap();
        assert_eq!(reds(&dense), [0.0, 1.0, 2.0, 3.0, 4.0, 6.0, 0.0]);
        settings.max_len = Some(3);
        let (dense, _) = densify(&set, &stats, 2.0, &settings, false, &mut rng).unwrap();
        assert_eq!(
            reds(&dense),
            [0.0, 1.0, 2.0, 3.0, 4.0, 6.0],
            "only the prune"
        );
    }

    #[test]
    fn nothing_left_is_an_error_and_the_statistics_must_fit() {
        let (mut set, stats, settings) = case();
        set.opacity_logits.fill(logit(0.001));
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let e = densify(&set, &stats, 2.0, &settings, false, &mut rng).unwrap_err();
        assert!(e.contains("remove all 7"), "{e}");
        let e = densify(&set, &ScreenStats::new(3), 2.0, &settings, false, &mut rng).unwrap_err();
        assert!(e.contains("3 Gaussians for a set of 7"), "{e}");
    }

    #[test]
    fn the_schedule_is_inrias() {
        let d = DensifySettings::default();
        let densified: Vec<u64> = (1..=30_000).filter(|&s| d.densifies_at(s)).collect();
        assert_eq!(densified.first(), Some(&600));
        assert_eq!(densified.last(), Some(&14_900));
        assert_eq!(densified.len(), 144);
        let reset: Vec<u64> = (1..=30_000)
            .filter(|&s| d.resets_opacity_at(s, false))
            .collect();
        assert_eq!(reset, [3000, 6000, 9000, 12_000]);
        assert!(d.resets_opacity_at(500, true) && !d.resets_opacity_at(500, false));
        assert!(d.gathers_at(14_999) && !d.gathers_at(15_000));
    }

    #[test]
    fn the_opacity_reset_caps_at_one_percent_and_restarts_its_moments() {
        let (mut set, _, _) = case();
        let changes = reset_opacity(&mut set);
        assert!((set.opacity_logits[0].sigmoid() - 0.01).abs() < 1e-6);
        assert_eq!(set.opacity_logits[5], logit(0.004), "lower ones stay");
        assert_eq!(changes[3], RowChange::Reset);
        assert!(changes
            .iter()
            .enumerate()
            .all(|(i, c)| i == 3 || *c == RowChange::Keep));
    }

    #[test]
    fn a_raised_degree_keeps_the_lower_coefficients_and_adds_zeros() {
        let (set, _, _) = case();
        let (wider, changes) = raise_sh_degree(&set).unwrap();
        assert_eq!(wider.sh_degree(), 2);
        for i in 0..7 {
            assert_eq!(
                wider.sh_rest[24 * i..24 * i + 9],
                set.sh_rest[9 * i..9 * i + 9]
            );
            assert!(wider.sh_rest[24 * i + 9..24 * (i + 1)]
                .iter()
                .all(|&v| v == 0.0));
        }
        assert_eq!(wider.sh_dc, set.sh_dc);
        assert_eq!(
            changes[5],
            RowChange::Widen {
                rows: 7,
                old: 9,
                new: 24
            }
        );
        let flat = GaussianSet::zeros(2, 0);
        let (one, _) = raise_sh_degree(&flat).unwrap();
        assert_eq!(one.sh_rest, vec![0.0; 18]);
        assert!(raise_sh_degree(&GaussianSet::zeros(2, 3)).is_none());
    }

    /// The pixel gradient of the projected centre against f64 central differences: a
    /// Gaussian on the optical axis, isotropic, moved across the line of sight, moves its
    /// projection by `fx / z` pixels a unit and its footprint only to second order.
    #[test]
    fn screen_gradients_match_finite_differences_of_the_projected_centre() {
        for (seed, (sigma, depth, w, h)) in
            [(0.3, 4.0, 24, 20), (0.15, 2.5, 31, 17), (0.5, 6.0, 16, 16)]
                .into_iter()
                .enumerate()
        {
            let (fx, fy) = (w as f64 * 1.1, h as f64 * 0.9);
            let camera = Camera::new(
                [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                [0.0; 3],
                [fx, fy, w as f64 / 2.0, h as f64 / 2.0],
                w,
                h,
            )
            .unwrap();
            let mut set = GaussianSet::<f64>::zeros(1, 0);
            set.means[2] = depth;
            set.log_scales.fill(f64::ln(sigma));
            set.opacity_logits[0] = 0.7;
            set.sh_dc.copy_from_slice(&[0.4, -0.2, 0.9]);
            let mut rng = ChaCha8Rng::seed_from_u64(seed as u64);
            let weights: Vec<f64> = (0..3 * w as usize * h as usize)
                .map(|_| rng.random_range(-1.0..1.0))
                .collect();
            let loss = |s: &GaussianSet<f64>| -> f64 {
                let r = render(s, &camera, [0.1, 0.2, 0.3]);
                r.image.data.iter().zip(&weights).map(|(x, w)| x * w).sum()
            };
            let rendered = render(&set, &camera, [0.1, 0.2, 0.3]);
            let out = OutputGrads {
                rgb: &weights,
                alpha: None,
                depth: None,
            };
            let (_, screen) =
                backward_with_screen_grads(&set, &camera, &rendered, &out, GradMask::ALL);
            let eps = 1e-6;
            for (axis, focal) in [(0, fx), (1, fy)] {
                let moved = |d: f64| {
                    let mut s = set.clone();
                    s.means[axis] += d;
                    loss(&s)
                };
                let along_mean = (moved(eps) - moved(-eps)) / (2.0 * eps);
                let expected = along_mean * depth / focal;
                let got = screen[0][axis];
                assert!(
                    (got - expected).abs() <= 1e-5 * expected.abs().max(1e-3),
                    "case {seed} axis {axis}: {got} against {expected}"
                );
            }
        }
    }

    /// The statistic is the norm of the pixel gradient scaled to normalized device
    /// coordinates, counted for the views that see the Gaussian only.
    #[test]
    fn the_statistic_scales_to_ndc_and_counts_only_visible_gaussians() {
        let camera = Camera::new(
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            [0.0; 3],
            [20.0, 20.0, 10.0, 6.0],
            20,
            12,
        )
        .unwrap();
        let mut set = GaussianSet::zeros(2, 0);
        set.means.copy_from_slice(&[0.0, 0.0, 3.0, 0.0, 0.0, -3.0]);
        set.log_scales.fill(-1.0);
        let rendered = render(&set, &camera, [0.0; 3]);
        assert!(rendered.is_visible(0) && !rendered.is_visible(1));
        let mut stats = ScreenStats::new(2);
        stats.add_view(&rendered, &[[3e-5, -4e-5], [1.0, 1.0]], (20, 12));
        stats.add_view(&rendered, &[[0.0, 1e-5], [1.0, 1.0]], (20, 12));
        let first = (3e-5f32 * 10.0).hypot(-4e-5 * 6.0);
        assert!((stats.grad_sum[0] - (first + 6e-5)).abs() < 1e-9);
        assert_eq!(stats.count, [2, 0]);
        assert_eq!(stats.mean(1), 0.0);
        assert!(ScreenStats::check_rendered(2, 2).is_ok());
        let e = ScreenStats::check_rendered(2, 3).unwrap_err();
        assert_eq!(e, "densification statistics of 2 Gaussians, 3 rendered");
    }
}
