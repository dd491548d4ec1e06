//! Layer norm, quick-GELU and softmax as single-pass CPU kernels with hand-written backward
//! kernels (f32, contiguous). Composed from candle ops (the `nn` module's other path), each of
//! these keeps four to eight full-size temporaries alive until the backward pass; fused, only
//! the input (and for softmax the output) is kept, and each direction is one pass over memory.

use std::sync::Arc;

use candle_core::{CpuStorage, CustomOp1, CustomOp2, Layout, Shape, Tensor};
use rayon::prelude::*;

use crate::cpu_elements::{elements, same_shape_elements};
use gs_core::vector_exp::{exp, sigmoid};

/// Applies `row_fn` to consecutive rows of `len` elements of `inputs` (equal lengths) and the
/// matching rows of the output, in parallel blocks of whole rows; a last partial row is passed
/// as it is (elementwise ops use any `len`).
fn map_rows<const N: usize>(
    len: usize,
    inputs: [&[f32]; N],
    row_fn: impl Fn([&[f32]; N], &mut [f32]) + Sync,
) -> Vec<f32> {
    let len = len.max(1);
    let mut out = vec![0f32; inputs[0].len()];
    let rows_per_task = (16384 / len).max(1);
    out.par_chunks_mut(rows_per_task * len)
        .enumerate()
        .for_each(|(task, block)| {
            let start = task * rows_per_task * len;
            for (r, row) in block.chunks_mut(len).enumerate() {
                let at = start + r * len;
                row_fn(inputs.map(|x| &x[at..at + row.len()]), row);
            }
        });
    out
}

/// Checks that the last dimension of `layout` is `len`.
fn check_rows(op: &str, layout: &Layout, len: usize) -> candle_core::Result<()> {
    match layout.shape().dims().last() {
        Some(&last) if last == len => Ok(()),
        _ => candle_core::bail!("{op}: rows of {len} expected, input {layout:?}"),
    }
}

/// Mean and reciprocal standard deviation (biased variance) of a row.
fn moments(x: &[f32], eps: f32) -> (f32, f32) {
    let n = x.len() as f32;
    let mean = x.iter().sum::<f32>() / n;
    let var = x.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() / n;
    (mean, 1.0 / (var + eps).sqrt())
}

/// Layer norm over the last dimension with affine `gamma`, `beta`, as PyTorch's `layer_norm`
/// (a clone shares the parameters).
#[derive(Clone, Debug)]
pub(crate) struct LayerNormOp {
    /// Scale, one per feature.
    pub gamma: Arc<[f32]>,
    /// Shift, one per feature.
    pub beta: Arc<[f32]>,
    /// Added to the variance.
    pub eps: f32,
}

impl CustomOp1 for LayerNormOp {
    fn name(&self) -> &'static str {
        "layer-norm-fused"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        check_rows("layer norm", l, self.gamma.len())?;
        let x = elements(s, l)?;
        let out = map_rows(self.gamma.len(), [x], |rows, y| {
            let (mean, rstd) = moments(rows[0], self.eps);
            for (((y, &x), &g), &b) in y
                .iter_mut()
                .zip(rows[0])
                .zip(self.gamma.iter())
                .zip(self.beta.iter())
            {
                *y = (x - mean) * rstd * g + b;
            }
        });
        Ok((CpuStorage::F32(out), l.shape().clone()))
    }

    fn bwd(
        &self,
        arg: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> candle_core::Result<Option<Tensor>> {
        let grad = grad.contiguous()?;
        Ok(Some(arg.apply_op2_no_bwd(&grad, self)?))
    }
}

/// `apply_op2(x, g)`: the input gradient `r (dy - mean(dy) - x̂ mean(dy x̂))` with
/// `dy = g gamma`, `x̂ = (x - mean) r`.
impl CustomOp2 for LayerNormOp {
    fn name(&self) -> &'static str {
        "layer-norm-fused-backward"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let (x, g) = same_shape_elements("layer-norm backward", (s1, l1), (s2, l2))?;
        check_rows("layer-norm backward", l1, self.gamma.len())?;
        let n = self.gamma.len();
        let out = map_rows(n, [x, g], |rows, dx| {
            let (x, g) = (rows[0], rows[1]);
            let (mean, rstd) = moments(x, self.eps);
            let (mut mean_dy, mut mean_dy_xhat) = (0f32, 0f32);
            for ((&x, &g), &gamma) in x.iter().zip(g).zip(self.gamma.iter()) {
                let dy = g * gamma;
                mean_dy += dy;
                mean_dy_xhat += dy * (x - mean) * rstd;
            }
            mean_dy /= n as f32;
            mean_dy_xhat /= n as f32;
            for (((dx, &x), &g), &gamma) in dx.iter_mut().zip(x).zip(g).zip(self.gamma.iter()) {
                let xhat = (x - mean) * rstd;
                *dx = rstd * (g * gamma - mean_dy - xhat * mean_dy_xhat);
            }
        });
        Ok((CpuStorage::F32(out), l1.shape().clone()))
    }
}

/// OpenAI CLIP's `x * sigmoid(1.702 x)`.
pub(crate) struct QuickGeluOp;

/// The slope inside quick-GELU's sigmoid.
const QUICK_GELU_SLOPE: f32 = 1.702;

impl CustomOp1 for QuickGeluOp {
    fn name(&self) -> &'static str {
        "quick-gelu-fused"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let x = elements(s, l)?;
        let out = map_rows(4096, [x], |rows, y| {
            for (y, &x) in y.iter_mut().zip(rows[0]) {
                *y = x * sigmoid(QUICK_GELU_SLOPE * x);
            }
        });
        Ok((CpuStorage::F32(out), l.shape().clone()))
    }

    fn bwd(
        &self,
        arg: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> candle_core::Result<Option<Tensor>> {
        Ok(Some(arg.apply_op2_no_bwd(&grad.contiguous()?, self)?))
    }
}

/// `apply_op2(x, g)`: `g (s + 1.702 x s (1 - s))`, `s = sigmoid(1.702 x)`.
impl CustomOp2 for QuickGeluOp {
    fn name(&self) -> &'static str {
        "quick-gelu-fused-backward"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let (x, g) = same_shape_elements("quick-gelu backward", (s1, l1), (s2, l2))?;
        let out = map_rows(4096, [x, g], |rows, dx| {
            for ((dx, &x), &g) in dx.iter_mut().zip(rows[0]).zip(rows[1]) {
                let s = sigmoid(QUICK_GELU_SLOPE * x);
                *dx = g * (s + QUICK_GELU_SLOPE * x * s * (1.0 - s));
            }
        });
        Ok((CpuStorage::F32(out), l1.shape().clone()))
    }
}

/// Softmax over the last dimension (the row maximum subtracted first).
pub(crate) struct SoftmaxOp {
    /// Length of the last dimension.
    pub len: usize,
}

impl CustomOp1 for SoftmaxOp {
    fn name(&self) -> &'static str {
        "softmax-fused"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        check_rows("softmax", l, self.len)?;
        let x = elements(s, l)?;
        let out = map_rows(self.len, [x], |rows, y| {
            let max = rows[0].iter().fold(f32::NEG_INFINITY, |m, &v| m.max(v));
            for (y, &x) in y.iter_mut().zip(rows[0]) {
                *y = exp(x - max);
            }
            let sum: f32 = y.iter().sum();
            for y in y.iter_mut() {
                *y /= sum;
            }
        });
        Ok((CpuStorage::F32(out), l.shape().clone()))
    }

    fn bwd(
        &self,
        _arg: &Tensor,
        res: &Tensor,
        grad: &Tensor,
    ) -> candle_core::Result<Option<Tensor>> {
        Ok(Some(res.apply_op2_no_bwd(&grad.contiguous()?, self)?))
    }
}

/// `apply_op2(y, g)` with `y` the softmax: `y (g - sum(g y))` per row.
impl CustomOp2 for SoftmaxOp {
    fn name(&self) -> &'static str {
        "softmax-fused-backward"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let (y, g) = same_shape_elements("softmax backward", (s1, l1), (s2, l2))?;
        check_rows("softmax backward", l1, self.len)?;
        let out = map_rows(self.len, [y, g], |rows, dx| {
            let (y, g) = (rows[0], rows[1]);
            let dot: f32 = y.iter().zip(g).map(|(y, g)| y * g).sum();
            for ((dx, &y), &g) in dx.iter_mut().zip(y).zip(g) {
                *dx = y * (g - dot);
            }
        });
        Ok((CpuStorage::F32(out), l1.shape().clone()))
    }
}
