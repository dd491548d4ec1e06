//! Differentiable building blocks written with candle ops that have a backward.
//!
//! candle's fused `layer_norm` and `softmax_last_dim` have no backward and silently cut the
//! graph, so layer norm and softmax are composed here from elementary ops. Linear layers attach
//! their input gradient by hand (see the `custom_grad` module) so that no weight gradient is ever
//! computed.

use candle_core::{Tensor, D};
use serde::Deserialize;

use crate::custom_grad::attach_input_gradient;

/// Floor of the norm in [`l2_normalize`], as in `torch.nn.functional.normalize`.
pub const NORMALIZE_EPS: f64 = 1e-12;

/// A fully connected layer `y = x W^T + b` with constant weights; differentiable in `x` only.
#[derive(Clone, Debug)]
pub(crate) struct Linear {
    /// `[out, in]`, used by the backward pass.
    weight: Tensor,
    /// `[in, out]` contiguous, used by the forward pass.
    weight_t: Tensor,
    bias: Option<Tensor>,
}

impl Linear {
    /// `weight` is `[out, in]` (PyTorch layout), `bias` is `[out]`.
    pub(crate) fn new(weight: Tensor, bias: Option<Tensor>) -> candle_core::Result<Self> {
        let weight_t = weight.t()?.contiguous()?;
        Ok(Self {
            weight,
            weight_t,
            bias,
        })
    }

    /// Applies the layer to the last dimension of `x` (any leading dimensions).
    pub(crate) fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let dims = x.dims().to_vec();
        let (in_features, rows) = match dims.split_last() {
            Some((last, lead)) => (*last, lead.iter().product::<usize>()),
            None => candle_core::bail!("Linear: scalar input"),
        };
        let flat = x.reshape((rows, in_features))?;
        let mut value = flat.detach().contiguous()?.matmul(&self.weight_t)?;
        if let Some(bias) = &self.bias {
            value = value.broadcast_add(bias)?;
        }
        let weight = self.weight.clone();
        let y = attach_input_gradient(&value, &flat, move |g| g.matmul(&weight))?;
        let mut out_dims = dims;
        if let Some(last) = out_dims.last_mut() {
            *last = self.weight.dim(0)?;
        }
        y.reshape(out_dims)
    }
}

/// Layer normalization over the last dimension with affine parameters, built from ops with a
/// backward: `(x - mean) / sqrt(var + eps) * gamma + beta` (biased variance, as PyTorch).
#[derive(Clone, Debug)]
pub(crate) struct LayerNorm {
    gamma: Tensor,
    beta: Tensor,
    eps: f64,
}

impl LayerNorm {
    /// `gamma` and `beta` are `[features]`.
    pub(crate) fn new(gamma: Tensor, beta: Tensor, eps: f64) -> Self {
        Self { gamma, beta, eps }
    }

    /// Normalizes the last dimension of `x`.
    pub(crate) fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let mean = x.mean_keepdim(D::Minus1)?;
        let centered = x.broadcast_sub(&mean)?;
        let var = centered.sqr()?.mean_keepdim(D::Minus1)?;
        let normed = centered.broadcast_div(&(var + self.eps)?.sqrt()?)?;
        normed.broadcast_mul(&self.gamma)?.broadcast_add(&self.beta)
    }
}

/// Softmax over the last dimension, built from ops with a backward. The row maximum is
/// subtracted for stability and detached (softmax does not depend on it).
pub(crate) fn softmax_last_dim(x: &Tensor) -> candle_core::Result<Tensor> {
    let max = x.max_keepdim(D::Minus1)?.detach();
    let e = x.broadcast_sub(&max)?.exp()?;
    e.broadcast_div(&e.sum_keepdim(D::Minus1)?)
}

/// `x / max(||x||, NORMALIZE_EPS)` over the last dimension, as `torch.nn.functional.normalize`.
/// A zero row gives zeros and a finite gradient. At a norm of exactly `NORMALIZE_EPS` the
/// gradient flows through the norm, as PyTorch's `clamp_min` (candle's `maximum` would halve it).
pub fn l2_normalize(x: &Tensor) -> candle_core::Result<Tensor> {
    let floor = NORMALIZE_EPS * NORMALIZE_EPS;
    let sum_sq = x.sqr()?.sum_keepdim(D::Minus1)?;
    let floored = sum_sq
        .ge(floor)?
        .where_cond(&sum_sq, &sum_sq.ones_like()?.affine(floor, 0.0)?)?;
    x.broadcast_div(&floored.sqrt()?)
}

/// The MLP activation named by `hidden_act` in a Hugging Face CLIP config.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Activation {
    /// `x * sigmoid(1.702 x)`, OpenAI CLIP's activation.
    QuickGelu,
    /// The exact (erf) GELU.
    Gelu,
}

impl Activation {
    /// Applies the activation element-wise.
    pub(crate) fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        match self {
            // sigmoid(z) = (1 + tanh(z / 2)) / 2: no overflow, tanh has a backward.
            Activation::QuickGelu => x.mul(&(x * (1.702 / 2.0))?.tanh()?.affine(0.5, 0.5)?),
            Activation::Gelu => x.gelu_erf(),
        }
    }
}
