//! Adam with parameter groups: one learning-rate schedule per group, frozen groups that cost
//! nothing, and state that can be saved and restored bit for bit.

use rayon::prelude::*;

use crate::GsError;

/// A learning rate as a function of the step.
#[derive(Clone, Debug, PartialEq)]
pub enum LrSchedule {
    /// The same rate at every step.
    Constant(f64),
    /// `lr(t) = exp((1-u) ln start + u ln end)`, `u = clamp(t / steps, 0, 1)`: the schedule of
    /// 3DGS positions and of CLIPGaussian (the paper; docs/fidelity.md).
    Exponential {
        /// Rate at step 0.
        start: f64,
        /// Rate at step `steps` and after.
        end: f64,
        /// Length of the decay, steps.
        steps: u64,
    },
}

impl LrSchedule {
    /// The learning rate at `step` (0-based).
    pub fn at(&self, step: u64) -> f64 {
        match *self {
            LrSchedule::Constant(lr) => lr,
            LrSchedule::Exponential { start, end, steps } => {
                if start <= 0.0 || end <= 0.0 {
                    // ln is undefined: fall back to linear interpolation, which gives 0 at 0.
                    let u = progress(step, steps);
                    return (1.0 - u) * start + u * end;
                }
                let u = progress(step, steps);
                ((1.0 - u) * start.ln() + u * end.ln()).exp()
            }
        }
    }
}

fn progress(step: u64, steps: u64) -> f64 {
    if steps == 0 {
        1.0
    } else {
        (step as f64 / steps as f64).clamp(0.0, 1.0)
    }
}

/// Which point of its schedule a group's `k`-th update (1-based) uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum RateAt {
    /// `lr(k)`: the rate is set from the 1-based iteration before the step, as INRIA 3DGS's
    /// `update_learning_rate(iteration)` and every loop derived from it (CLIPGaussian's 3D,
    /// MiraGe, VeGaS, D-MiSo's triangles).
    #[default]
    Iteration,
    /// `lr(k - 1)`: the rate is updated after the step, so the first update uses the schedule's
    /// start (D-MiSo's deformation network).
    PreviousIteration,
}

/// One parameter group: a name, a schedule, and whether it is trained at all.
#[derive(Clone, Debug, PartialEq)]
pub struct GroupConfig {
    /// Name of the group (e.g. `"means"`); saved state is matched by it.
    pub name: String,
    /// Learning rate per step.
    pub schedule: LrSchedule,
    /// Which point of the schedule each update uses.
    pub rate_at: RateAt,
    /// Adam's epsilon for this group; `None` takes the optimizer's ([`AdamHyper::eps`]).
    pub eps: Option<f64>,
    /// A frozen group is never updated and needs no gradient.
    pub frozen: bool,
}

impl GroupConfig {
    /// A trained group whose `k`-th update uses `schedule.at(k)` ([`RateAt::Iteration`]) and the
    /// optimizer's epsilon.
    pub fn new(name: impl Into<String>, schedule: LrSchedule) -> Self {
        Self {
            name: name.into(),
            schedule,
            rate_at: RateAt::Iteration,
            eps: None,
            frozen: false,
        }
    }

    /// A frozen group.
    pub fn frozen(name: impl Into<String>) -> Self {
        Self {
            frozen: true,
            ..Self::new(name, LrSchedule::Constant(0.0))
        }
    }

    /// The same group with its updates at `rate_at`.
    pub fn with_rate_at(self, rate_at: RateAt) -> Self {
        Self { rate_at, ..self }
    }

    /// The same group with Adam's epsilon `eps`.
    pub fn with_eps(self, eps: f64) -> Self {
        Self {
            eps: Some(eps),
            ..self
        }
    }

    /// The learning rate of update `update` (1-based; 0 for a frozen group).
    pub fn lr_for_update(&self, update: u64) -> f64 {
        if self.frozen {
            return 0.0;
        }
        match self.rate_at {
            RateAt::Iteration => self.schedule.at(update),
            RateAt::PreviousIteration => self.schedule.at(update.saturating_sub(1)),
        }
    }

    /// Adam's epsilon for this group, `default` unless it has its own.
    pub fn eps_or(&self, default: f64) -> f64 {
        self.eps.unwrap_or(default)
    }
}

/// Adam hyper-parameters shared by all groups.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamHyper {
    /// First-moment decay.
    pub beta1: f64,
    /// Second-moment decay.
    pub beta2: f64,
    /// Added to the root of the second moment; 1e-15 as in 3DGS and CLIPGaussian (a group may
    /// have its own, [`GroupConfig::eps`]).
    pub eps: f64,
}

impl Default for AdamHyper {
    fn default() -> Self {
        Self {
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-15,
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
struct Moments {
    m: Vec<f32>,
    v: Vec<f32>,
}

/// The Adam optimizer over a fixed list of parameter groups (PyTorch's update rule with bias
/// correction).
#[derive(Clone, Debug, PartialEq)]
pub struct Adam {
    hyper: AdamHyper,
    groups: Vec<GroupConfig>,
    moments: Vec<Option<Moments>>,
    step: u64,
}

const STATE_MAGIC: &[u8; 8] = b"CGADAM01";

/// `groups` in the order of `names` (a model's [`crate::model::BaseModel::group_names`]),
/// matched by name: each group configured once, none unknown, none missing. An error names the
/// groups at fault and the model's, so that a list in another order trains the groups it names,
/// and a misspelt or forgotten one stops the run instead of training the wrong group.
pub fn groups_in_model_order(
    groups: Vec<GroupConfig>,
    names: &[String],
) -> Result<Vec<GroupConfig>, String> {
    let listed = names.join(", ");
    let mut slots: Vec<Option<GroupConfig>> = names.iter().map(|_| None).collect();
    for group in groups {
        let Some(at) = names.iter().position(|n| *n == group.name) else {
            return Err(format!(
                "no parameter group {:?} in this model (its groups: {listed})",
                group.name
            ));
        };
        if slots[at].is_some() {
            return Err(format!(
                "parameter group {:?} is configured twice",
                group.name
            ));
        }
        slots[at] = Some(group);
    }
    let missing: Vec<&str> = names
        .iter()
        .zip(&slots)
        .filter(|(_, s)| s.is_none())
        .map(|(n, _)| n.as_str())
        .collect();
    if !missing.is_empty() {
        return Err(format!(
            "no configuration for parameter group(s) {} (the model's: {listed})",
            missing.join(", ")
        ));
    }
    Ok(slots.into_iter().flatten().collect())
}

impl Adam {
    /// An optimizer for `groups` whose sizes are `lens` (moments are allocated for trained groups
    /// only).
    ///
    /// # Panics
    /// If `groups` and `lens` differ in length.
    pub fn new(groups: Vec<GroupConfig>, lens: &[usize], hyper: AdamHyper) -> Self {
        assert_eq!(groups.len(), lens.len(), "one length per group");
        let moments = groups
            .iter()
            .zip(lens)
            .map(|(g, &n)| {
                (!g.frozen).then(|| Moments {
                    m: vec![0.0; n],
                    v: vec![0.0; n],
                })
            })
            .collect();
        Self {
            hyper,
            groups,
            moments,
            step: 0,
        }
    }

    /// The group configurations.
    pub fn groups(&self) -> &[GroupConfig] {
        &self.groups
    }

    /// Steps taken so far.
    pub fn step_count(&self) -> u64 {
        self.step
    }

    /// The learning rate each group uses at the next step (0 for frozen groups).
    pub fn current_lrs(&self) -> Vec<f64> {
        self.groups
            .iter()
            .map(|g| g.lr_for_update(self.step + 1))
            .collect()
    }

    /// One Adam step: `params[i]` is group `i`, `grads[i]` its gradient (ignored for frozen
    /// groups, which may pass an empty slice).
    ///
    /// # Panics
    /// If the number of groups or a trained group's length differs from construction.
    pub fn step(&mut self, params: &mut [&mut [f32]], grads: &[&[f32]]) {
        assert_eq!(
            params.len(),
            self.groups.len(),
            "one parameter slice per group"
        );
        assert_eq!(
            grads.len(),
            self.groups.len(),
            "one gradient slice per group"
        );
        let t = self.step + 1;
        let AdamHyper { beta1, beta2, eps } = self.hyper;
        let bc1 = 1.0 - beta1.powf(t as f64);
        let bc2 = 1.0 - beta2.powf(t as f64);
        for (i, (p, g)) in params.iter_mut().zip(grads).enumerate() {
            let Some(mom) = self.moments[i].as_mut() else {
                continue;
            };
            assert_eq!(
                p.len(),
                mom.m.len(),
                "group {} changed size",
                self.groups[i].name
            );
            assert_eq!(
                g.len(),
                p.len(),
                "gradient of group {} has the wrong size",
                self.groups[i].name
            );
            let lr = self.groups[i].lr_for_update(t);
            let eps = self.groups[i].eps_or(eps);
            let step_size = (lr / bc1) as f32;
            let inv_bc2_sqrt = (1.0 / bc2.sqrt()) as f32;
            let (b1, b2, eps) = (beta1 as f32, beta2 as f32, eps as f32);
            p.par_iter_mut()
                .zip(g.par_iter())
                .zip(mom.m.par_iter_mut().zip(mom.v.par_iter_mut()))
                .with_min_len(4096)
                .for_each(|((p, &g), (m, v))| {
                    *m = b1 * *m + (1.0 - b1) * g;
                    *v = b2 * *v + (1.0 - b2) * g * g;
                    *p -= step_size * *m / (v.sqrt() * inv_bc2_sqrt + eps);
                });
        }
        self.step = t;
    }

    /// The state (step count and every moment) as bytes, for checkpoints (the format of
    /// `encode_state`, shared with the GPU optimizer).
    pub fn save_state(&self) -> Vec<u8> {
        encode_state(
            self.step,
            &self.groups,
            self.moments
                .iter()
                .map(|m| m.as_ref().map(|m| (m.m.as_slice(), m.v.as_slice()))),
        )
    }

    /// Restores state saved by [`Adam::save_state`] (or by the GPU optimizer) from an optimizer
    /// with the same groups (names, sizes and frozen flags); anything else is an error that
    /// names the difference.
    pub fn restore_state(&mut self, bytes: &[u8]) -> Result<(), GsError> {
        let lens: Vec<Option<usize>> = self
            .moments
            .iter()
            .map(|m| m.as_ref().map(|m| m.m.len()))
            .collect();
        let (step, moments) = decode_state(bytes, &self.groups, &lens)?;
        self.step = step;
        self.moments = moments
            .into_iter()
            .map(|m| m.map(|(m, v)| Moments { m, v }))
            .collect();
        Ok(())
    }
}

/// How one parameter group's Adam moments follow its values when a model adds, copies or drops
/// rows (a densification: a row is a Gaussian's or a core's values).
#[derive(Clone, Debug, PartialEq)]
pub enum RowChange {
    /// The group is unchanged.
    Keep,
    /// New row `r` (of `width` values) takes the moments of old row `from[r]`, or zeros for a
    /// new row (`None`), as PyTorch's optimizer state after 3DGS's densification.
    Rows {
        /// Values per row.
        width: usize,
        /// The old row of each new row.
        from: Vec<Option<usize>>,
    },
    /// The values were replaced: the moments restart at zero (3DGS's opacity reset).
    Reset,
    /// Each row of `old` values grew to `new` (more SH coefficients): the old moments lead each
    /// row, the new values' moments are zero.
    Widen {
        /// Rows of the group.
        rows: usize,
        /// Values per row before.
        old: usize,
        /// Values per row after.
        new: usize,
    },
}

/// The optimizer state `bytes` (saved by an optimizer of `groups`, whose trained groups held
/// `lens[i]` values, `None` when frozen) with each group's moments changed as `changes` says
/// ([`RowChange`]), to restore into the optimizer of the changed model; the step count is kept.
pub fn rearrange_state(
    bytes: &[u8],
    groups: &[GroupConfig],
    lens: &[Option<usize>],
    changes: &[RowChange],
) -> Result<Vec<u8>, GsError> {
    let (step, moments) = decode_state(bytes, groups, lens)?;
    let moments: Vec<Option<SavedMoments>> = moments
        .into_iter()
        .zip(changes)
        .map(|(m, change)| {
            m.map(|(m, v)| match change {
                RowChange::Keep => (m, v),
                RowChange::Reset => (vec![0.0; m.len()], vec![0.0; v.len()]),
                RowChange::Rows { width, from } => {
                    let gather = |old: &[f32]| -> Vec<f32> {
                        from.iter()
                            .flat_map(|r| match r {
                                Some(r) => old[r * width..(r + 1) * width].to_vec(),
                                None => vec![0.0; *width],
                            })
                            .collect()
                    };
                    (gather(&m), gather(&v))
                }
                RowChange::Widen { rows, old, new } => {
                    let widen = |values: &[f32]| -> Vec<f32> {
                        let mut out = vec![0.0; rows * new];
                        for (r, to) in out.chunks_exact_mut(*new).enumerate() {
                            to[..*old].copy_from_slice(&values[r * old..(r + 1) * old]);
                        }
                        out
                    };
                    (widen(&m), widen(&v))
                }
            })
        })
        .collect();
    Ok(encode_state(
        step,
        groups,
        moments
            .iter()
            .map(|m| m.as_ref().map(|(m, v)| (m.as_slice(), v.as_slice()))),
    ))
}

/// The first and second moments of one trained group, as saved.
pub type SavedMoments = (Vec<f32>, Vec<f32>);

/// Optimizer state as bytes, little-endian: the magic `CGADAM01`, the `u64` step count and
/// group count, then per group a `u64` name length, the UTF-8 name, a `u64` value count
/// (`u64::MAX` for a frozen group, which has no moments) and the `f32` first then second moments.
pub fn encode_state<'a>(
    step: u64,
    groups: &[GroupConfig],
    moments: impl Iterator<Item = Option<(&'a [f32], &'a [f32])>>,
) -> Vec<u8> {
    let mut out = Vec::new();
    out.extend_from_slice(STATE_MAGIC);
    out.extend_from_slice(&step.to_le_bytes());
    out.extend_from_slice(&(groups.len() as u64).to_le_bytes());
    for (g, m) in groups.iter().zip(moments) {
        out.extend_from_slice(&(g.name.len() as u64).to_le_bytes());
        out.extend_from_slice(g.name.as_bytes());
        let len = m.map_or(u64::MAX, |(m, _)| m.len() as u64);
        out.extend_from_slice(&len.to_le_bytes());
        if let Some((m, v)) = m {
            for x in m.iter().chain(v) {
                out.extend_from_slice(&x.to_le_bytes());
            }
        }
    }
    out
}

/// Reads state written by [`encode_state`] for an optimizer of `groups` whose trained groups
/// have `lens[i]` values (`None`: frozen): the step count and the moments of each group.
pub fn decode_state(
    bytes: &[u8],
    groups: &[GroupConfig],
    lens: &[Option<usize>],
) -> Result<(u64, Vec<Option<SavedMoments>>), GsError> {
    let err = |m: String| GsError::OptimizerState(m);
    let mut r = ByteReader { bytes, pos: 0 };
    if r.take(8).ok_or_else(|| err("truncated header".into()))? != STATE_MAGIC {
        return Err(err("not an optimizer state (bad magic)".into()));
    }
    let step = r.u64().ok_or_else(|| err("truncated step".into()))?;
    let n = r.u64().ok_or_else(|| err("truncated group count".into()))?;
    if n != groups.len() as u64 {
        return Err(err(format!("{n} groups saved, {} expected", groups.len())));
    }
    let mut restored = Vec::with_capacity(groups.len());
    for (g, mine) in groups.iter().zip(lens) {
        let name_len = r.u64().ok_or_else(|| err("truncated name".into()))? as usize;
        let name = r
            .take(name_len)
            .ok_or_else(|| err("truncated name".into()))?;
        if name != g.name.as_bytes() {
            return Err(err(format!(
                "group '{}' saved where '{}' was expected",
                String::from_utf8_lossy(name),
                g.name
            )));
        }
        let len = r
            .u64()
            .ok_or_else(|| err(format!("truncated group '{}'", g.name)))?;
        let expected = mine.map_or(u64::MAX, |n| n as u64);
        if len != expected {
            return Err(err(format!(
                "group '{}' was saved with {} values, {} expected",
                g.name,
                describe_len(len),
                describe_len(expected)
            )));
        }
        if len == u64::MAX {
            restored.push(None);
            continue;
        }
        let mut read = || -> Option<Vec<f32>> {
            let raw = r.take(4 * len as usize)?;
            Some(
                raw.chunks_exact(4)
                    .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                    .collect(),
            )
        };
        let m = read().ok_or_else(|| err(format!("truncated moments of '{}'", g.name)))?;
        let v = read().ok_or_else(|| err(format!("truncated moments of '{}'", g.name)))?;
        restored.push(Some((m, v)));
    }
    if r.pos != bytes.len() {
        return Err(err(format!("{} trailing bytes", bytes.len() - r.pos)));
    }
    Ok((step, restored))
}

fn describe_len(len: u64) -> String {
    if len == u64::MAX {
        "no (frozen)".into()
    } else {
        len.to_string()
    }
}

struct ByteReader<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> ByteReader<'a> {
    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        let end = self.pos.checked_add(n)?;
        let s = self.bytes.get(self.pos..end)?;
        self.pos = end;
        Some(s)
    }

    fn u64(&mut self) -> Option<u64> {
        self.take(8)
            .map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rearranged_moments_follow_their_rows() {
        let groups = vec![
            GroupConfig::new("rows", LrSchedule::Constant(0.1)),
            GroupConfig::new("reset", LrSchedule::Constant(0.1)),
            GroupConfig::frozen("frozen"),
            GroupConfig::new("kept", LrSchedule::Constant(0.1)),
        ];
        let mut adam = Adam::new(groups.clone(), &[6, 2, 3, 1], AdamHyper::default());
        let mut p: Vec<Vec<f32>> = vec![vec![0.0; 6], vec![0.0; 2], vec![0.0; 3], vec![0.0]];
        let g: Vec<Vec<f32>> = vec![
            vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
            vec![1.0, 1.0],
            vec![],
            vec![7.0],
        ];
        let mut refs: Vec<&mut [f32]> = p.iter_mut().map(|v| v.as_mut_slice()).collect();
        let grads: Vec<&[f32]> = g.iter().map(|v| v.as_slice()).collect();
        adam.step(&mut refs, &grads);
        let saved = adam.save_state();
        let changes = [
            RowChange::Rows {
                width: 2,
                from: vec![Some(2), None, Some(0), Some(2)],
            },
            RowChange::Reset,
            RowChange::Keep,
            RowChange::Keep,
        ];
        let lens = [Some(6), Some(2), None, Some(1)];
        let bytes = rearrange_state(&saved, &groups, &lens, &changes).unwrap();
        let mut after = Adam::new(groups.clone(), &[8, 2, 3, 1], AdamHyper::default());
        after.restore_state(&bytes).unwrap();
        assert_eq!(after.step_count(), 1);
        let m = |a: &Adam, i: usize| a.moments[i].as_ref().unwrap().m.clone();
        let first = m(&adam, 0);
        assert_eq!(
            m(&after, 0),
            [&first[4..6], &[0.0, 0.0], &first[0..2], &first[4..6]].concat()
        );
        assert_eq!(m(&after, 1), vec![0.0; 2]);
        assert_eq!(m(&after, 3), m(&adam, 3));
        let e = rearrange_state(
            &saved,
            &groups,
            &[Some(5), Some(2), None, Some(1)],
            &changes,
        );
        assert!(e.is_err(), "the saved lengths are checked");
        // Rows of 2 widened to 3 (more SH coefficients): old moments first, zeros after; a
        // group of no values (degree 0) widens to its row count's zeros.
        let widened = [
            RowChange::Widen {
                rows: 3,
                old: 2,
                new: 3,
            },
            RowChange::Widen {
                rows: 2,
                old: 1,
                new: 2,
            },
            RowChange::Keep,
            RowChange::Keep,
        ];
        let bytes = rearrange_state(&saved, &groups, &lens, &widened).unwrap();
        let mut wide = Adam::new(groups.clone(), &[9, 4, 3, 1], AdamHyper::default());
        wide.restore_state(&bytes).unwrap();
        let f = &first;
        assert_eq!(
            m(&wide, 0),
            [f[0], f[1], 0.0, f[2], f[3], 0.0, f[4], f[5], 0.0]
        );
        let r = m(&adam, 1);
        assert_eq!(m(&wide, 1), [r[0], 0.0, r[1], 0.0]);
        let from_nothing = [RowChange::Widen {
            rows: 2,
            old: 0,
            new: 9,
        }];
        let one = [GroupConfig::new("sh_rest", LrSchedule::Constant(0.1))];
        let empty = Adam::new(one.to_vec(), &[0], AdamHyper::default()).save_state();
        let bytes = rearrange_state(&empty, &one, &[Some(0)], &from_nothing).unwrap();
        let mut nine = Adam::new(one.to_vec(), &[18], AdamHyper::default());
        nine.restore_state(&bytes).unwrap();
        assert_eq!(m(&nine, 0), vec![0.0; 18]);
    }

    #[test]
    fn exponential_schedule_hits_both_ends_and_the_geometric_middle() {
        let s = LrSchedule::Exponential {
            start: 1e-4,
            end: 1e-6,
            steps: 100,
        };
        assert!((s.at(0) - 1e-4).abs() < 1e-18);
        assert!((s.at(50) - 1e-5).abs() < 1e-15);
        assert!((s.at(100) - 1e-6).abs() < 1e-18);
        assert!((s.at(1000) - 1e-6).abs() < 1e-18);
    }

    #[test]
    fn the_first_update_uses_iteration_one_of_the_schedule_or_its_start_when_asked() {
        let schedule = LrSchedule::Exponential {
            start: 1e-2,
            end: 1e-4,
            steps: 2,
        };
        let groups = vec![
            GroupConfig::new("iteration", schedule.clone()),
            GroupConfig::new("previous", schedule.clone()).with_rate_at(RateAt::PreviousIteration),
        ];
        let mut adam = Adam::new(groups, &[1, 1], AdamHyper::default());
        assert_eq!(adam.current_lrs(), vec![schedule.at(1), schedule.at(0)]);
        let (mut a, mut b) = (vec![0.0f32], vec![0.0f32]);
        // Adam's first update is lr * sign(g) (up to eps): it shows the rate used.
        adam.step(&mut [&mut a, &mut b], &[&[1.0], &[1.0]]);
        assert!(
            (f64::from(a[0]) + 1e-3).abs() < 1e-7,
            "lr(1) = 1e-3, got {}",
            a[0]
        );
        assert!(
            (f64::from(b[0]) + 1e-2).abs() < 1e-7,
            "lr(0) = 1e-2, got {}",
            b[0]
        );
        assert_eq!(adam.current_lrs(), vec![schedule.at(2), schedule.at(1)]);
    }

    #[test]
    fn a_group_may_have_its_own_epsilon() {
        let groups = vec![
            GroupConfig::new("default", LrSchedule::Constant(1.0)),
            GroupConfig::new("torch default", LrSchedule::Constant(1.0)).with_eps(1e-8),
        ];
        let mut adam = Adam::new(groups, &[1, 1], AdamHyper::default());
        let (mut a, mut b) = (vec![0.0f32], vec![0.0f32]);
        adam.step(&mut [&mut a, &mut b], &[&[1e-9], &[1e-9]]);
        // |update| = lr * |g| / (|g| + eps): 1 with eps 1e-15, 1/11 with eps 1e-8.
        assert!((a[0] + 1.0).abs() < 1e-5, "{}", a[0]);
        assert!((b[0] + 1.0 / 11.0).abs() < 1e-5, "{}", b[0]);
    }

    /// Adam as PyTorch writes it, in f64, for one scalar.
    fn reference(grads: &[f64], lr: f64) -> f64 {
        let (b1, b2, eps) = (0.9f64, 0.999f64, 1e-15f64);
        let (mut p, mut m, mut v) = (1.0f64, 0.0f64, 0.0f64);
        for (t, g) in grads.iter().enumerate() {
            let t = t as i32 + 1;
            m = b1 * m + (1.0 - b1) * g;
            v = b2 * v + (1.0 - b2) * g * g;
            let mh = m / (1.0 - b1.powi(t));
            let vh = v / (1.0 - b2.powi(t));
            p -= lr * mh / (vh.sqrt() + eps);
        }
        p
    }

    #[test]
    fn matches_the_pytorch_update_and_skips_frozen_groups() {
        let groups = vec![
            GroupConfig::new("a", LrSchedule::Constant(0.01)),
            GroupConfig::frozen("b"),
        ];
        let mut adam = Adam::new(groups, &[1, 2], AdamHyper::default());
        let mut a = vec![1.0f32];
        let mut b = vec![5.0f32, 6.0];
        let gs = [0.3, -0.2, 0.05, 1.5, -0.7];
        for g in gs {
            adam.step(&mut [&mut a, &mut b], &[&[g as f32], &[]]);
        }
        let want = reference(&gs, 0.01);
        assert!((a[0] as f64 - want).abs() < 1e-6, "{} vs {want}", a[0]);
        assert_eq!(b, vec![5.0, 6.0]);
        assert_eq!(adam.step_count(), 5);
    }

    #[test]
    fn saved_state_restores_exactly_and_mismatches_are_named() {
        let groups = vec![
            GroupConfig::new("means", LrSchedule::Constant(0.1)),
            GroupConfig::frozen("scales"),
        ];
        let mut adam = Adam::new(groups.clone(), &[3, 3], AdamHyper::default());
        let mut p = vec![0.5f32, -0.5, 2.0];
        adam.step(&mut [&mut p, &mut []], &[&[0.1, 0.2, -0.3], &[]]);
        let bytes = adam.save_state();
        let mut copy = Adam::new(groups, &[3, 3], AdamHyper::default());
        copy.restore_state(&bytes).unwrap();
        assert_eq!(copy, adam);
        let (mut p1, mut p2) = (p.clone(), p.clone());
        adam.step(&mut [&mut p1, &mut []], &[&[0.4, 0.0, 0.1], &[]]);
        copy.step(&mut [&mut p2, &mut []], &[&[0.4, 0.0, 0.1], &[]]);
        assert_eq!(p1, p2);

        let mut other = Adam::new(
            vec![
                GroupConfig::new("means", LrSchedule::Constant(0.1)),
                GroupConfig::frozen("scales"),
            ],
            &[4, 3],
            AdamHyper::default(),
        );
        let e = other.restore_state(&bytes).unwrap_err().to_string();
        assert!(
            e.contains("means") && e.contains('3') && e.contains('4'),
            "{e}"
        );
        assert!(copy.restore_state(&bytes[..bytes.len() - 1]).is_err());
        assert!(copy.restore_state(b"garbage!").is_err());
    }
}
