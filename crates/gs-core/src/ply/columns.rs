//! Access to the parameter arrays by [`Slot`]: runs of vertices filled in parallel when reading,
//! values looked up when writing.

use crate::GaussianSet;

use super::layout::Slot;
use super::PlyGaussians;

/// Mutable views of the arrays of a run of consecutive vertices.
pub(crate) struct ColumnsMut<'a> {
    means: &'a mut [f32],
    sh_dc: &'a mut [f32],
    sh_rest: &'a mut [f32],
    opacity: &'a mut [f32],
    log_scales: &'a mut [f32],
    quats: &'a mut [f32],
    /// `sh_rest` values per vertex, `3 (K-1)`.
    rest: usize,
    extras: Vec<&'a mut [f64]>,
}

impl ColumnsMut<'_> {
    /// Stores `value` for vertex `v` (relative to the run) in `slot`.
    #[inline]
    pub fn set(&mut self, v: usize, slot: Slot, value: f64) {
        let x = value as f32;
        match slot {
            Slot::Mean(k) => self.means[3 * v + k] = x,
            Slot::ShDc(c) => self.sh_dc[3 * v + c] = x,
            Slot::ShRest(o) => self.sh_rest[self.rest * v + o] = x,
            Slot::Opacity => self.opacity[v] = x,
            Slot::LogScale(k) => self.log_scales[3 * v + k] = x,
            Slot::Quat(k) => self.quats[4 * v + k] = x,
            Slot::Extra(e) => self.extras[e][v] = value,
            Slot::Zero => {}
        }
    }
}

/// `v` cut into runs of `run` vertices of `width` values each; `runs` empty slices when `width`
/// is 0 (an absent array, e.g. `sh_rest` at degree 0).
fn runs<T>(v: &mut [T], width: usize, run: usize, runs: usize) -> Vec<&mut [T]> {
    if width == 0 {
        (0..runs).map(|_| <&mut [T]>::default()).collect()
    } else {
        v.chunks_mut(width * run).collect()
    }
}

/// The arrays of `set` and `extras` cut into runs of `run` vertices (`run > 0`).
pub(crate) fn split<'a>(
    set: &'a mut GaussianSet,
    extras: &'a mut [Vec<f64>],
    run: usize,
) -> Vec<ColumnsMut<'a>> {
    let n = set.len();
    let count = n.div_ceil(run);
    let rest = 3 * (set.sh_coeffs() - 1);
    let mut means = runs(&mut set.means, 3, run, count).into_iter();
    let mut sh_dc = runs(&mut set.sh_dc, 3, run, count).into_iter();
    let mut sh_rest = runs(&mut set.sh_rest, rest, run, count).into_iter();
    let mut opacity = runs(&mut set.opacity_logits, 1, run, count).into_iter();
    let mut log_scales = runs(&mut set.log_scales, 3, run, count).into_iter();
    let mut quats = runs(&mut set.quats, 4, run, count).into_iter();
    let mut extras: Vec<_> = extras
        .iter_mut()
        .map(|e| runs(e, 1, run, count).into_iter())
        .collect();
    (0..count)
        .map(|_| {
            let next = |it: &mut std::vec::IntoIter<&'a mut [f32]>| {
                it.next().expect("every array has one run per vertex run")
            };
            ColumnsMut {
                means: next(&mut means),
                sh_dc: next(&mut sh_dc),
                sh_rest: next(&mut sh_rest),
                opacity: next(&mut opacity),
                log_scales: next(&mut log_scales),
                quats: next(&mut quats),
                rest,
                extras: extras
                    .iter_mut()
                    .map(|e| e.next().expect("every extra has one run per vertex run"))
                    .collect(),
            }
        })
        .collect()
}

/// The value of vertex `i` in `slot`.
#[inline]
pub(crate) fn get(ply: &PlyGaussians, rest: usize, i: usize, slot: Slot) -> f64 {
    let g = &ply.gaussians;
    match slot {
        Slot::Mean(k) => g.means[3 * i + k] as f64,
        Slot::ShDc(c) => g.sh_dc[3 * i + c] as f64,
        Slot::ShRest(o) => g.sh_rest[rest * i + o] as f64,
        Slot::Opacity => g.opacity_logits[i] as f64,
        Slot::LogScale(k) => g.log_scales[3 * i + k] as f64,
        Slot::Quat(k) => g.quats[4 * i + k] as f64,
        Slot::Extra(e) => ply.extras[e].values[i],
        Slot::Zero => 0.0,
    }
}
