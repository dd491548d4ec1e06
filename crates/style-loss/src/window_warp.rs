//! The patch warp in the form a GPU runs it: every crop window of one image warped at once on
//! the image's device. A few numbers per window cross to the device (torchvision's
//! coefficients and their inverse), not four taps per pixel, and the backward is a gather too:
//! candle's scatter-add (`index_add`) runs one thread per channel on CUDA.
//!
//! Forward: torchvision's sampling ([`crate::perspective`]) computed on the device in f32, in
//! torchvision's order of operations. Backward: source pixel `(u, v)` of a window receives the
//! gradient of every output pixel whose sample point lies less than one pixel from it. Those
//! outputs lie in a small square around the inverse homography's image of `(u, v)`, whose side
//! comes from a bound on the inverse's Jacobian ([`candidate_reach`]); each candidate's forward
//! taps are read back and the one that lands on `(u, v)`, if any, gives its weight. Every
//! product of the forward is summed again, so the gradient equals the scatter-add's up to the
//! order of the sums.
//!
//! Coordinates: a pixel `k` has its centre at `k + 0.5`; the warp maps output centre `(x, y)`
//! to source centre `(a x + b y + c, d x + e y + f) / (g x + h y + 1)`.

use candle_core::{DType, Tensor};

use crate::custom_grad::attach_input_gradient;
use crate::error::{Result, StyleLossError};

/// One window to warp: where it sits in the source and torchvision's coefficients for it
/// ([`crate::perspective::perspective_coefficients`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WindowWarp {
    /// Column of the window's left edge in the source.
    pub left: usize,
    /// Row of the window's top edge in the source.
    pub top: usize,
    /// `(a, b, c, d, e, f, g, h)`, output point to window point.
    pub coeffs: [f32; 8],
}

/// The largest candidate square side a window's backward gathers. The paper's
/// `distortion_scale` of 0.5 gives 3 to 8; a window that needs more (only strong distortions
/// stretch part of a crop that much, or send it to infinity) is scattered instead.
const MAX_CANDIDATES: usize = 12;

/// Warps the `width x height` windows `warps` of `image` `[channels, rows, cols]`:
/// `[windows, channels, height, width]`, differentiable in `image`. Bilinear, fill 0, as
/// torchvision's `perspective` on each crop.
///
/// Windows are warped in groups of one candidate square side (a window without a useful bound
/// is scattered instead), and the groups' outputs put back in the order of `warps`.
pub fn warp_windows(
    image: &Tensor,
    warps: &[WindowWarp],
    width: usize,
    height: usize,
) -> Result<Tensor> {
    let (channels, rows, cols) = image.dims3()?;
    let invalid = |reason: String| StyleLossError::Input {
        name: "warp windows".into(),
        reason,
    };
    if warps.is_empty() || width == 0 || height == 0 {
        return Err(invalid(format!(
            "{} windows of {width}x{height}: need at least one non-empty window",
            warps.len()
        )));
    }
    for (i, w) in warps.iter().enumerate() {
        if w.left + width > cols || w.top + height > rows {
            return Err(invalid(format!(
                "window {i} at ({}, {}) of {width}x{height} leaves the {rows}x{cols} image",
                w.top, w.left
            )));
        }
    }
    let pixels = width * height;
    let count = warps.len();
    if count
        .checked_mul(pixels * MAX_CANDIDATES * MAX_CANDIDATES)
        .is_none_or(|n| n >= u32::MAX as usize)
    {
        return Err(invalid(format!(
            "{count} windows of {pixels} pixels: too many taps to index with u32"
        )));
    }
    let plans = warps
        .iter()
        .enumerate()
        .map(|(i, w)| WindowPlan::new(i, w, width, height))
        .collect::<Result<Vec<_>>>()?;
    let mut order: Vec<usize> = (0..count).collect();
    order.sort_by_key(|&i| plans[i].backward);
    let uploaded = Uploaded::new(&plans, &order, width, height, image.device())?;
    let mut outputs = Vec::new();
    for group in &uploaded.groups {
        let crops = group
            .windows
            .iter()
            .map(|&i| {
                image
                    .narrow(1, warps[i].top, height)?
                    .narrow(2, warps[i].left, width)
            })
            .collect::<candle_core::Result<Vec<_>>>()?;
        let flat = Tensor::stack(&crops, 1)?.reshape((channels, crops.len() * pixels))?;
        let taps = Taps::compute(group, &uploaded, width, height)?;
        let value = taps.sample(&flat.detach())?;
        let group = group.clone();
        let grid = uploaded.grid.clone();
        outputs.push(attach_input_gradient(&value, &flat, move |g| {
            taps.transpose_gather(g, &group, &grid, width, height)
        })?);
    }
    let sorted = Tensor::cat(&outputs, 1)?
        .reshape((channels, count, height, width))?
        .transpose(0, 1)?
        .contiguous()?;
    if order.iter().enumerate().all(|(at, &i)| at == i) {
        return Ok(sorted);
    }
    Ok(sorted.index_select(&uploaded.unsort, 0)?)
}

/// One window's numbers for the device and the reach of its backward's candidates.
struct WindowPlan {
    /// torchvision's rescaled forward coefficients (6), `g`, `h`, and the inverse homography
    /// (9, row-major).
    numbers: [f32; 17],
    /// [`candidate_reach`] of the window, in output pixels (0 for a scattered window).
    reach: f64,
    /// How its backward runs.
    backward: Backward,
}

/// How a window's backward runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Backward {
    /// A gather over a square of candidate outputs of this side per source pixel.
    Gather(usize),
    /// A scatter-add of the forward taps (candle's `index_add`: serial per channel on CUDA),
    /// for windows whose stretch has no useful bound.
    Scatter,
}

impl WindowPlan {
    fn new(window: usize, w: &WindowWarp, width: usize, height: usize) -> Result<Self> {
        let c = w.coeffs;
        let invalid = |reason: String| StyleLossError::Input {
            name: format!("warp window {window}"),
            reason,
        };
        let inverse = inverse_homography(&c)
            .ok_or_else(|| invalid(format!("coefficients {c:?} are not invertible")))?;
        let (reach, backward) = match candidate_reach(&inverse, width, height) {
            Some(reach) if candidate_side(reach) <= MAX_CANDIDATES => {
                (reach, Backward::Gather(candidate_side(reach)))
            }
            _ => (0.0, Backward::Scatter),
        };
        // torchvision's rescaled theta, in f32 as torchvision computes it.
        let (half_w, half_h) = (0.5 * width as f32, 0.5 * height as f32);
        let mut numbers = [0f32; 17];
        numbers[..8].copy_from_slice(&[
            c[0] / half_w,
            c[1] / half_w,
            c[2] / half_w,
            c[3] / half_h,
            c[4] / half_h,
            c[5] / half_h,
            c[6],
            c[7],
        ]);
        for (n, v) in numbers[8..].iter_mut().zip(inverse) {
            *n = v as f32;
        }
        Ok(Self {
            numbers,
            reach,
            backward,
        })
    }
}
/// The inverse of the homography `[[a, b, c], [d, e, f], [g, h, 1]]` (row-major), scaled so
/// that its largest entry is 1; `None` when it is singular.
fn inverse_homography(c: &[f32; 8]) -> Option<[f64; 9]> {
    let m: Vec<f64> = c.iter().map(|&v| v as f64).chain([1.0]).collect();
    let cof = |r0: usize, r1: usize, c0: usize, c1: usize| {
        m[r0 * 3 + c0] * m[r1 * 3 + c1] - m[r0 * 3 + c1] * m[r1 * 3 + c0]
    };
    // The adjugate: the transposed cofactors.
    let adj = [
        cof(1, 2, 1, 2),
        -cof(0, 2, 1, 2),
        cof(0, 1, 1, 2),
        -cof(1, 2, 0, 2),
        cof(0, 2, 0, 2),
        -cof(0, 1, 0, 2),
        cof(1, 2, 0, 1),
        -cof(0, 2, 0, 1),
        cof(0, 1, 0, 1),
    ];
    let det = m[0] * adj[0] + m[1] * adj[3] + m[2] * adj[6];
    let size = m.iter().fold(0f64, |s, v| s.max(v.abs()));
    let scale = adj.iter().fold(0f64, |s, v| s.max(v.abs()));
    if !det.is_finite() || det.abs() <= 1e-12 * size.powi(3) || scale == 0.0 {
        return None;
    }
    Some(adj.map(|v| v / scale))
}

/// How far (in output pixels, per axis) an output pixel whose sample point lies less than one
/// pixel from a source pixel's centre can be from that centre's inverse image: a bound on the
/// inverse homography's Jacobian (the largest row sum of absolute values) over the window grown
/// by one pixel, sampled every pixel, with 5 % and 0.05 px to spare for the rounding of the f32
/// forward. `None` when the inverse's denominator changes sign over the window.
pub fn candidate_reach(inverse: &[f64; 9], width: usize, height: usize) -> Option<f64> {
    let g = inverse;
    let mut bound = 0f64;
    let mut sign = 0f64;
    // Source centres range over [0.5, size - 0.5]; their neighbours within one pixel over
    // [-0.5, size + 0.5].
    for j in 0..=height + 1 {
        for i in 0..=width + 1 {
            let (sx, sy) = (i as f64 - 0.5, j as f64 - 0.5);
            let den = g[6] * sx + g[7] * sy + g[8];
            if den == 0.0 || sign * den < 0.0 {
                return None;
            }
            sign = den.signum();
            let nx = g[0] * sx + g[1] * sy + g[2];
            let ny = g[3] * sx + g[4] * sy + g[5];
            let d2 = den * den;
            let row_x = ((g[0] * den - nx * g[6]).abs() + (g[1] * den - nx * g[7]).abs()) / d2;
            let row_y = ((g[3] * den - ny * g[6]).abs() + (g[4] * den - ny * g[7]).abs()) / d2;
            bound = bound.max(row_x).max(row_y);
        }
    }
    bound.is_finite().then_some(bound * 1.05 + 0.05)
}

/// The side of the square of candidate outputs that covers every output within `reach` of a
/// point, one to spare for an integer end.
fn candidate_side(reach: f64) -> usize {
    (2.0 * reach).floor() as usize + 2
}

/// What the forward and backward read on the device, from one upload per call.
struct Uploaded {
    /// `[1, pixels]` each: output pixel centres `x + 0.5` and `y + 0.5` (row-major).
    grid: (Tensor, Tensor),
    /// The windows of one [`Backward`] each, in its order.
    groups: Vec<Group>,
    /// `[windows]` u32: where each window of the caller's order sits in the groups' order.
    unsort: Tensor,
}

/// Windows warped together: their numbers on the device and the candidate square of their
/// backward.
#[derive(Clone)]
struct Group {
    /// The windows, as positions in the caller's list.
    windows: Vec<usize>,
    /// `[windows, NUMBERS]`: each window's [`WindowPlan::numbers`] and its index in the group.
    numbers: Tensor,
    /// The largest [`candidate_reach`] of the group.
    reach: f64,
    /// How the group's backward runs.
    backward: Backward,
    /// `[1, 1, side^2]` each: candidate column and row offsets (empty for a scatter).
    offsets: (Tensor, Tensor),
}

/// Numbers per window on the device: [`WindowPlan::numbers`] and the window's index in its
/// group.
const NUMBERS: usize = 18;

impl Uploaded {
    fn new(
        plans: &[WindowPlan],
        order: &[usize],
        width: usize,
        height: usize,
        device: &candle_core::Device,
    ) -> Result<Self> {
        let pixels = width * height;
        let mut host = Vec::new();
        host.extend((0..pixels).map(|p| (p % width) as f32 + 0.5));
        host.extend((0..pixels).map(|p| (p / width) as f32 + 0.5));
        let mut unsort = vec![0f32; order.len()];
        for (at, &i) in order.iter().enumerate() {
            unsort[i] = at as f32;
        }
        host.extend(&unsort);
        // (start of the numbers, windows, backward, reach) of each group.
        let mut layout: Vec<(usize, Vec<usize>, Backward, f64)> = Vec::new();
        for &i in order {
            let plan = &plans[i];
            match layout.last_mut() {
                Some((_, windows, backward, reach)) if *backward == plan.backward => {
                    windows.push(i);
                    *reach = reach.max(plan.reach);
                }
                _ => layout.push((0, vec![i], plan.backward, plan.reach)),
            }
        }
        for (start, windows, backward, _) in &mut layout {
            *start = host.len();
            for (at, &i) in windows.iter().enumerate() {
                host.extend(&plans[i].numbers);
                host.push(at as f32);
            }
            let side = backward.side();
            host.extend((0..side * side).map(|k| (k % side) as f32));
            host.extend((0..side * side).map(|k| (k / side) as f32));
        }
        let bytes = std::mem::size_of_val(host.as_slice());
        let len = host.len();
        let all = Tensor::from_vec(host, len, device)?;
        crate::transfers::record_upload(bytes);
        let groups = layout
            .into_iter()
            .map(|(start, windows, backward, reach)| {
                let n = windows.len();
                let cells = backward.side() * backward.side();
                let at = start + n * NUMBERS;
                Ok(Group {
                    numbers: all.narrow(0, start, n * NUMBERS)?.reshape((n, NUMBERS))?,
                    offsets: (
                        all.narrow(0, at, cells)?.reshape((1, 1, cells))?,
                        all.narrow(0, at + cells, cells)?.reshape((1, 1, cells))?,
                    ),
                    windows,
                    reach,
                    backward,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Self {
            grid: (
                all.narrow(0, 0, pixels)?.reshape((1, pixels))?,
                all.narrow(0, pixels, pixels)?.reshape((1, pixels))?,
            ),
            unsort: all
                .narrow(0, 2 * pixels, order.len())?
                .to_dtype(DType::U32)?,
            groups,
        })
    }
}

impl Backward {
    /// The candidate square's side (0 for a scatter).
    fn side(self) -> usize {
        match self {
            Self::Gather(side) => side,
            Self::Scatter => 0,
        }
    }
}

impl Group {
    /// Column `k` of the per-window numbers: `[windows, 1]`.
    fn number(&self, k: usize) -> Result<Tensor> {
        Ok(self.numbers.narrow(1, k, 1)?)
    }

    /// Each window's first index in the group's flattened windows (`per_pixel` entries per
    /// pixel), as u32 `[windows, 1, 1]`.
    fn window_base(&self, pixels: usize, per_pixel: usize) -> Result<Tensor> {
        Ok(self
            .number(NUMBERS - 1)?
            .to_dtype(DType::U32)?
            .affine((pixels * per_pixel) as f64, 0.0)?
            .reshape((self.windows.len(), 1, 1))?)
    }

    /// `x * numbers[a] + y * numbers[b] + numbers[c]` for `x, y` `[1, pixels]`:
    /// `[windows, pixels]`.
    fn affine_map(&self, x: &Tensor, y: &Tensor, a: usize, b: usize, c: usize) -> Result<Tensor> {
        Ok(x.broadcast_mul(&self.number(a)?)?
            .broadcast_add(&y.broadcast_mul(&self.number(b)?)?)?
            .broadcast_add(&self.number(c)?)?)
    }
}

/// `[t >= a]` for an integer-valued `t`, as 0 or 1 (built from `relu`: no scalar crosses to
/// the device).
fn at_least(t: &Tensor, a: f64) -> Result<Tensor> {
    Ok((t.affine(1.0, 1.0 - a)?.relu()? - t.affine(1.0, -a)?.relu()?)?)
}

/// `[lo <= t <= hi]` for an integer-valued `t`, as 0 or 1.
fn within(t: &Tensor, lo: f64, hi: f64) -> Result<Tensor> {
    Ok((at_least(t, lo)? - at_least(t, hi + 1.0)?)?)
}

/// `t` clamped to `[lo, hi]` (built from `relu`).
fn clamped(t: &Tensor, lo: f64, hi: f64) -> Result<Tensor> {
    Ok((t.affine(1.0, -lo)?.relu()? - t.affine(1.0, -hi)?.relu()?)?.affine(1.0, lo)?)
}

/// The forward taps of every output pixel of every window, on the device.
struct Taps {
    /// `[windows * pixels * 4]` u32: flat indices into the windows' pixels, corners in the
    /// order `(x0, y0), (x0 + 1, y0), (x0, y0 + 1), (x0 + 1, y0 + 1)`.
    index: Tensor,
    /// `[windows * pixels * 4]` f32: their weights (torchvision's bilinear weight times its
    /// fill mask; 0 outside the window).
    weight: Tensor,
    /// `[windows * pixels, 2]` f32: each output's sample cell `(x0, y0)`.
    cell: Tensor,
}

impl Taps {
    fn compute(group: &Group, uploaded: &Uploaded, width: usize, height: usize) -> Result<Self> {
        let (x, y) = (&uploaded.grid.0, &uploaded.grid.1);
        let windows = group.windows.len();
        let pixels = width * height;
        let den = x
            .broadcast_mul(&group.number(6)?)?
            .broadcast_add(&y.broadcast_mul(&group.number(7)?)?)?
            .affine(1.0, 1.0)?;
        // torchvision's grid, then grid_sample's unnormalisation (align_corners=False).
        let sample = |num: Tensor, size: usize| -> Result<Tensor> {
            Ok(((num / &den)?.affine(1.0, -1.0)?)
                .affine(1.0, 1.0)?
                .affine(size as f64, -1.0)?
                .affine(0.5, 0.0)?)
        };
        let ix = sample(group.affine_map(x, y, 0, 1, 2)?, width)?;
        let iy = sample(group.affine_map(x, y, 3, 4, 5)?, height)?;
        let (x0, y0) = (ix.floor()?, iy.floor()?);
        let fx = (&ix - &x0)?;
        let fy = (&iy - &y0)?;
        let (gx, gy) = (fx.affine(-1.0, 1.0)?, fy.affine(-1.0, 1.0)?);
        let (w_last, h_last) = ((width - 1) as f64, (height - 1) as f64);
        let (x0_in, x1_in) = (within(&x0, 0.0, w_last)?, within(&x0, -1.0, w_last - 1.0)?);
        let (y0_in, y1_in) = (within(&y0, 0.0, h_last)?, within(&y0, -1.0, h_last - 1.0)?);
        let corners = [
            (&gx, &gy, &x0_in, &y0_in),
            (&fx, &gy, &x1_in, &y0_in),
            (&gx, &fy, &x0_in, &y1_in),
            (&fx, &fy, &x1_in, &y1_in),
        ];
        let kept = corners
            .iter()
            .map(|(wx, wy, ax, ay)| Ok(((*wx * *wy)? * (*ax * *ay)?)?))
            .collect::<Result<Vec<_>>>()?;
        // torchvision warps an all-ones mask alongside and multiplies the sample by it.
        let mask = kept[1..].iter().try_fold(kept[0].clone(), |m, w| m + w)?;
        let weight = kept
            .iter()
            .map(|w| w * &mask)
            .collect::<candle_core::Result<Vec<_>>>()?;
        let (x1, y1) = (x0.affine(1.0, 1.0)?, y0.affine(1.0, 1.0)?);
        let local = |cx: &Tensor, cy: &Tensor| -> Result<Tensor> {
            Ok((clamped(cy, 0.0, h_last)?.affine(width as f64, 0.0)? + clamped(cx, 0.0, w_last)?)?)
        };
        let local = Tensor::stack(
            &[
                local(&x0, &y0)?,
                local(&x1, &y0)?,
                local(&x0, &y1)?,
                local(&x1, &y1)?,
            ],
            2,
        )?;
        let index = local
            .to_dtype(DType::U32)?
            .broadcast_add(&group.window_base(pixels, 1)?)?
            .flatten_all()?;
        Ok(Self {
            index,
            weight: Tensor::stack(&weight, 2)?.flatten_all()?,
            cell: Tensor::stack(&[x0, y0], 2)?.reshape((windows * pixels, 2))?,
        })
    }

    /// `[channels, windows * pixels]` samples of `flat` `[channels, windows * pixels]`.
    fn sample(&self, flat: &Tensor) -> candle_core::Result<Tensor> {
        let (channels, outputs) = flat.dims2()?;
        let weight = self.weight.to_dtype(flat.dtype())?.unsqueeze(0)?;
        flat.index_select(&self.index, 1)?
            .broadcast_mul(&weight)?
            .reshape((channels, outputs, 4))?
            .sum(2)
    }

    /// The gradient of the windows' pixels from the gradient `grad` of the outputs (both
    /// `[channels, windows * pixels]`), as gathers over each pixel's candidate outputs.
    fn transpose_gather(
        &self,
        grad: &Tensor,
        group: &Group,
        grid: &(Tensor, Tensor),
        width: usize,
        height: usize,
    ) -> candle_core::Result<Tensor> {
        let grad = grad.contiguous()?;
        let gradient = match group.backward {
            Backward::Gather(_) => self.gather_gradient(&grad, group, grid, width, height),
            Backward::Scatter => self.scatter_gradient(&grad),
        };
        gradient.map_err(|e| candle_core::Error::Msg(format!("window warp backward: {e}")))
    }

    /// The scatter-add of the forward taps' products, for windows without a candidate bound.
    fn scatter_gradient(&self, grad: &Tensor) -> Result<Tensor> {
        let (channels, outputs) = grad.dims2()?;
        let weight = self.weight.to_dtype(grad.dtype())?.unsqueeze(0)?;
        let products = grad
            .unsqueeze(2)?
            .broadcast_as((channels, outputs, 4))?
            .reshape((channels, outputs * 4))?
            .broadcast_mul(&weight)?;
        Ok(grad.zeros_like()?.index_add(&self.index, &products, 1)?)
    }

    fn gather_gradient(
        &self,
        grad: &Tensor,
        group: &Group,
        grid: &(Tensor, Tensor),
        width: usize,
        height: usize,
    ) -> Result<Tensor> {
        let (channels, outputs) = grad.dims2()?;
        let windows = group.windows.len();
        let pixels = width * height;
        let candidates = group.offsets.0.dim(2)?;
        let (sx, sy) = (&grid.0, &grid.1);
        // The inverse image of each source centre, as an output pixel position.
        let den = group.affine_map(sx, sy, 14, 15, 16)?;
        let out_x = (group.affine_map(sx, sy, 8, 9, 10)? / &den)?.affine(1.0, -0.5)?;
        let out_y = (group.affine_map(sx, sy, 11, 12, 13)? / &den)?.affine(1.0, -0.5)?;
        let first = |t: &Tensor| -> Result<Tensor> {
            Ok(t.affine(1.0, -group.reach)?.ceil()?.unsqueeze(2)?)
        };
        let cand_x = first(&out_x)?.broadcast_add(&group.offsets.0)?;
        let cand_y = first(&out_y)?.broadcast_add(&group.offsets.1)?;
        let (w_last, h_last) = ((width - 1) as f64, (height - 1) as f64);
        let valid = (within(&cand_x, 0.0, w_last)? * within(&cand_y, 0.0, h_last)?)?;
        let local = (clamped(&cand_y, 0.0, h_last)?.affine(width as f64, 0.0)?
            + clamped(&cand_x, 0.0, w_last)?)?;
        let ids = local
            .to_dtype(DType::U32)?
            .broadcast_add(&group.window_base(pixels, 1)?)?
            .flatten_all()?;
        let cell = self
            .cell
            .index_select(&ids, 0)?
            .reshape((windows, pixels, candidates, 2))?;
        let source_x = sx.affine(1.0, -0.5)?.unsqueeze(2)?;
        let source_y = sy.affine(1.0, -0.5)?.unsqueeze(2)?;
        let dx = source_x.broadcast_sub(&cell.narrow(3, 0, 1)?.squeeze(3)?)?;
        let dy = source_y.broadcast_sub(&cell.narrow(3, 1, 1)?.squeeze(3)?)?;
        let hit = ((valid * within(&dx, 0.0, 1.0)?)? * within(&dy, 0.0, 1.0)?)?;
        let corner = (clamped(&dx, 0.0, 1.0)? + clamped(&dy, 0.0, 1.0)?.affine(2.0, 0.0)?)?;
        let weight_ids = (local.affine(4.0, 0.0)? + corner)?
            .to_dtype(DType::U32)?
            .broadcast_add(&group.window_base(pixels, 4)?)?
            .flatten_all()?;
        let weight = (self.weight.index_select(&weight_ids, 0)? * hit.flatten_all()?)?
            .to_dtype(grad.dtype())?
            .unsqueeze(0)?;
        Ok(grad
            .index_select(&ids, 1)?
            .broadcast_mul(&weight)?
            .reshape((channels, outputs, candidates))?
            .sum(2)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::patches::{style_rng, PatchSettings};
    use crate::perspective::{
        gather_taps, image_corners, perspective_coefficients, SourceWindow, Taps,
    };
    use candle_core::{Device, Var};

    /// Output and image gradient of `sum(warp(image) * upstream)`.
    fn value_and_grad(
        image: &Tensor,
        upstream: &Tensor,
        warp: impl Fn(&Tensor) -> Tensor,
    ) -> (Vec<f32>, Vec<f32>) {
        let var = Var::from_tensor(image).unwrap();
        let out = warp(var.as_tensor());
        let grads = (&out * upstream)
            .unwrap()
            .sum_all()
            .unwrap()
            .backward()
            .unwrap();
        let flat = |t: &Tensor| t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        (flat(&out), flat(grads.get(var.as_tensor()).unwrap()))
    }

    fn max_abs(a: &[f32], b: &[f32]) -> f32 {
        a.iter().zip(b).fold(0f32, |m, (x, y)| m.max((x - y).abs()))
    }

    /// The largest output and relative gradient differences between the device form and the
    /// host taps with candle's scatter-add backward, for `warps` of `size` windows of a random
    /// `[3, rows, cols]` image.
    fn device_against_host(
        rows: usize,
        cols: usize,
        warps: &[WindowWarp],
        size: usize,
    ) -> (f32, f32) {
        let device = Device::Cpu;
        let windows = warps.len();
        let image = Tensor::rand(0f32, 1f32, (3, rows, cols), &device).unwrap();
        let upstream = Tensor::randn(0f32, 1f32, (windows, 3, size, size), &device).unwrap();
        let (device_out, device_grad) = value_and_grad(&image, &upstream, |x| {
            warp_windows(x, warps, size, size).unwrap()
        });
        let mut taps = Taps::default();
        for w in warps {
            let window = SourceWindow {
                width: size,
                height: size,
                left: w.left,
                top: w.top,
                source_width: cols,
            };
            taps.push_perspective(&w.coeffs, window);
        }
        let (host_out, host_grad) = value_and_grad(&image, &upstream, |x| {
            gather_taps(&x.reshape((3, rows * cols)).unwrap(), &taps)
                .unwrap()
                .reshape((3, windows, size, size))
                .unwrap()
                .transpose(0, 1)
                .unwrap()
        });
        let grad_scale = host_grad.iter().fold(0f32, |m, v| m.max(v.abs()));
        (
            max_abs(&device_out, &host_out),
            max_abs(&device_grad, &host_grad) / grad_scale,
        )
    }

    /// The device form against the host taps and candle's scatter-add backward, on overlapping
    /// windows of odd and even sizes in a non-square image, mild and strong distortions.
    #[test]
    fn device_warp_equals_host_taps_and_scatter_add() {
        let (rows, cols) = (53, 71);
        for (seed, size, windows, distortion) in [
            (1u64, 24usize, 12usize, 0.5),
            (2, 17, 9, 0.5),
            (3, 32, 6, 0.9),
            (4, 53, 4, 0.7),
            (5, 16, 20, 0.95),
        ] {
            let mut rng = style_rng(seed);
            let settings = PatchSettings {
                patch_size: size,
                num_patches: windows,
                distortion_scale: distortion,
            };
            let start = image_corners(size, size);
            let warps: Vec<WindowWarp> = settings
                .sample(&mut rng, rows, cols)
                .unwrap()
                .iter()
                .map(|p| WindowWarp {
                    left: p.left,
                    top: p.top,
                    coeffs: perspective_coefficients(&start, &p.corners).unwrap(),
                })
                .collect();
            let (out_err, grad_err) = device_against_host(rows, cols, &warps, size);
            assert!(out_err < 2e-5, "seed {seed}: output error {out_err}");
            assert!(grad_err < 2e-5, "seed {seed}: gradient error {grad_err}");
        }
    }

    /// A crossed quadrilateral (torchvision draws them at `distortion_scale` near 1) has no
    /// candidate bound: its window is scattered, beside gathered ones, and both match.
    #[test]
    fn crossed_windows_are_scattered_and_match() {
        let size = 8;
        let start = image_corners(size, size);
        let crossed = perspective_coefficients(&start, &[[4, 0], [3, 0], [7, 7], [0, 7]]).unwrap();
        let plain = perspective_coefficients(&start, &[[1, 0], [7, 2], [6, 7], [0, 6]]).unwrap();
        let plan = |c| {
            WindowPlan::new(
                0,
                &WindowWarp {
                    left: 0,
                    top: 0,
                    coeffs: c,
                },
                size,
                size,
            )
            .unwrap()
        };
        assert_eq!(plan(crossed).backward, Backward::Scatter);
        assert!(matches!(plan(plain).backward, Backward::Gather(_)));
        let warps = [
            WindowWarp {
                left: 3,
                top: 1,
                coeffs: crossed,
            },
            WindowWarp {
                left: 0,
                top: 0,
                coeffs: plain,
            },
            WindowWarp {
                left: 2,
                top: 4,
                coeffs: crossed,
            },
        ];
        let (out_err, grad_err) = device_against_host(13, 11, &warps, size);
        assert!(out_err < 2e-5, "output error {out_err}");
        assert!(grad_err < 2e-5, "gradient error {grad_err}");
    }

    /// Every output that reads a source pixel lies within the candidate reach of that pixel's
    /// inverse image, over many of torchvision's random perspectives at the paper's size.
    #[test]
    fn candidate_reach_covers_every_tap() {
        let size = 128;
        let mut rng = style_rng(11);
        for distortion in [0.5, 1.0] {
            let settings = PatchSettings {
                patch_size: size,
                num_patches: 40,
                distortion_scale: distortion,
            };
            let start = image_corners(size, size);
            for p in settings.sample(&mut rng, size, size).unwrap() {
                let coeffs = perspective_coefficients(&start, &p.corners).unwrap();
                let inverse = inverse_homography(&coeffs).unwrap();
                let Some(reach) = candidate_reach(&inverse, size, size) else {
                    assert!(
                        distortion > 0.5,
                        "{p:?}: no reach at distortion {distortion}"
                    );
                    continue;
                };
                if distortion <= 0.5 {
                    assert!(candidate_side(reach) <= 8, "{p:?}: reach {reach}");
                }
                let mut taps = Taps::default();
                let window = SourceWindow {
                    width: size,
                    height: size,
                    left: 0,
                    top: 0,
                    source_width: size,
                };
                taps.push_perspective(&coeffs, window);
                for (t, (&index, &weight)) in taps.index.iter().zip(&taps.weight).enumerate() {
                    if weight == 0.0 {
                        continue;
                    }
                    let output = t / 4;
                    let (ox, oy) = ((output % size) as f64, (output / size) as f64);
                    let (sx, sy) = (
                        (index as usize % size) as f64 + 0.5,
                        (index as usize / size) as f64 + 0.5,
                    );
                    let g = &inverse;
                    let den = g[6] * sx + g[7] * sy + g[8];
                    let bx = (g[0] * sx + g[1] * sy + g[2]) / den - 0.5;
                    let by = (g[3] * sx + g[4] * sy + g[5]) / den - 0.5;
                    let slack = reach - (ox - bx).abs().max((oy - by).abs());
                    assert!(slack > 0.0, "{:?}: output ({ox}, {oy}) off by {slack}", p);
                }
            }
        }
    }

    #[test]
    fn windows_outside_the_image_and_singular_warps_are_errors() {
        let image = Tensor::zeros((3, 10, 12), DType::F32, &Device::Cpu).unwrap();
        let identity = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
        let outside = WindowWarp {
            left: 5,
            top: 0,
            coeffs: identity,
        };
        let err = warp_windows(&image, &[outside], 8, 8)
            .unwrap_err()
            .to_string();
        assert!(err.contains("leaves the 10x12 image"), "{err}");
        let flat = WindowWarp {
            left: 0,
            top: 0,
            coeffs: [1.0, 1.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0],
        };
        let err = warp_windows(&image, &[flat], 8, 8).unwrap_err().to_string();
        assert!(err.contains("not invertible"), "{err}");
        assert!(warp_windows(&image, &[], 8, 8).is_err());
    }

    /// One upload per call, of the per-window numbers, the pixel centres and the candidate
    /// offsets: no taps.
    #[test]
    fn a_warp_uploads_its_windows_numbers_once() {
        let image = Tensor::rand(0f32, 1f32, (3, 40, 40), &Device::Cpu).unwrap();
        let start = image_corners(16, 16);
        let warps: Vec<WindowWarp> = [[[2, 1], [15, 0], [13, 14], [0, 15]]; 5]
            .iter()
            .enumerate()
            .map(|(i, corners)| WindowWarp {
                left: 3 * i,
                top: 2 * i,
                coeffs: perspective_coefficients(&start, corners).unwrap(),
            })
            .collect();
        let before = crate::transfers::snapshot();
        warp_windows(&image, &warps, 16, 16).unwrap();
        let moved = crate::transfers::snapshot() - before;
        assert_eq!(moved.uploads, 1);
        assert!(moved.uploaded_bytes < 4 * (5 * NUMBERS as u64 + 5 + 2 * 256 + 2 * 64) + 1);
        assert_eq!(moved.reads, 0);
    }
}
