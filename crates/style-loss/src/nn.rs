//! Differentiable building blocks written with candle ops that have a backward.
//!
//! candle's fused `layer_norm` and `softmax_last_dim` have no backward and silently cut the
//! graph, so layer norm and softmax are composed here from elementary ops. Linear layers attach
//! their input gradient by hand (see the `custom_grad` module) so that no weight gradient is ever
//! computed.

use candle_core::{DType, Tensor, D};
use serde::Deserialize;

use crate::bf16_product::bf16_linear_cpu;
use crate::cpu_elements::is_cpu_f32;
use crate::custom_grad::attach_input_gradient;
use crate::fused_cpu::{LayerNormOp, QuickGeluOp, SoftmaxOp};
use crate::matmul::checked_matmul;

/// Floor of the norm in [`l2_normalize`], as in `torch.nn.functional.normalize`.
pub const NORMALIZE_EPS: f64 = 1e-12;

/// A fully connected layer `y = x W^T + b` with constant weights; differentiable in `x` only.
/// `W` may be bf16 under f32 activations (`linear_value`); `b` is in the activations' format.
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
        let value = self.value(&flat.detach().contiguous()?)?;
        let weight = self.weight.clone();
        let y = attach_input_gradient(&value, &flat, move |g| {
            linear_value(&g.contiguous()?, &weight, None)
        })?;
        let mut out_dims = dims;
        if let Some(last) = out_dims.last_mut() {
            *last = self.weight.dim(0)?;
        }
        y.reshape(out_dims)
    }

    /// The layer's value on `[rows, in]` (contiguous), outside the graph.
    pub(crate) fn value(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        linear_value(x, &self.weight_t, self.bias.as_ref())
    }

    /// The input gradient `g · W` of an upstream gradient `g` `[rows, out]` (contiguous).
    pub(crate) fn input_gradient(&self, g: &Tensor) -> candle_core::Result<Tensor> {
        linear_value(g, &self.weight, None)
    }
}

/// `x · w + bias` of a linear layer. bf16 weights with f32 activations (`ClipPrecision::Bf16`)
/// round `x` to bf16 and the product back to f32 (in one fused op on the CPU, the same values);
/// otherwise both are in one format.
fn linear_value(x: &Tensor, w: &Tensor, bias: Option<&Tensor>) -> candle_core::Result<Tensor> {
    if w.dtype() == DType::BF16 && is_cpu_f32(x) {
        return bf16_linear_cpu(x, w, bias);
    }
    let product = if w.dtype() == x.dtype() {
        checked_matmul(x, w)?
    } else {
        checked_matmul(&x.to_dtype(w.dtype())?, w)?.to_dtype(x.dtype())?
    };
    match bias {
        Some(bias) => product.broadcast_add(bias),
        None => Ok(product),
    }
}

/// The input gradient of a map computed outside the graph: the adjoint of its Jacobian at the
/// input, applied to an upstream gradient of the output's shape.
pub(crate) type InputAdjoint =
    Box<dyn Fn(&Tensor) -> candle_core::Result<Tensor> + Send + Sync + 'static>;

/// A transformer's feed-forward block `fc2(activation(fc1(x)))`, differentiable in `x` only.
#[derive(Clone, Debug)]
pub(crate) struct Mlp {
    /// `in -> hidden`.
    pub fc1: Linear,
    /// `hidden -> in`.
    pub fc2: Linear,
    /// Between the two.
    pub activation: Activation,
}

impl Mlp {
    /// For f32 on the CPU with quick-GELU, the block's value on `x` (contiguous, outside the
    /// graph; the block acts on the last dimension) and its input adjoint (`fc2`'s adjoint, the activation's derivative,
    /// `fc1`'s adjoint): the hidden-sized intermediate values are neither copied into the graph
    /// nor given zeroed gradients to add into, as three nodes would be. `None` elsewhere.
    pub(crate) fn value_and_adjoint(
        &self,
        x: &Tensor,
    ) -> candle_core::Result<Option<(Tensor, InputAdjoint)>> {
        if self.activation != Activation::QuickGelu || !is_cpu_f32(x) {
            return Ok(None);
        }
        let dims = x.dims().to_vec();
        let (in_features, rows) = match dims.split_last() {
            Some((last, lead)) => (*last, lead.iter().product::<usize>()),
            None => candle_core::bail!("Mlp: scalar input"),
        };
        let hidden = self.fc1.value(&x.reshape((rows, in_features))?)?;
        let activated = hidden.apply_op1_no_bwd(&QuickGeluOp)?;
        let value = self.fc2.value(&activated)?;
        drop(activated);
        let (fc1, fc2) = (self.fc1.clone(), self.fc2.clone());
        let adjoint: InputAdjoint = Box::new(move |g| {
            let g_activated = fc2.input_gradient(&g.reshape((rows, ()))?.contiguous()?)?;
            let g_hidden = hidden.apply_op2_no_bwd(&g_activated, &QuickGeluOp)?;
            fc1.input_gradient(&g_hidden)?.reshape(dims.as_slice())
        });
        let mut out_dims = x.dims().to_vec();
        if let Some(last) = out_dims.last_mut() {
            *last = value.dim(1)?;
        }
        Ok(Some((value.reshape(out_dims)?, adjoint)))
    }

    /// The block as three nodes of the graph (any device and activation).
    pub(crate) fn forward_with_layers(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        self.fc2
            .forward(&self.activation.forward(&self.fc1.forward(x)?)?)
    }
}

/// Layer normalization over the last dimension with affine parameters, built from ops with a
/// backward: `(x - mean) / sqrt(var + eps) * gamma + beta` (biased variance, as PyTorch).
#[derive(Clone, Debug)]
pub(crate) struct LayerNorm {
    gamma: Tensor,
    beta: Tensor,
    eps: f64,
    /// The fused CPU kernel with the parameters read out once, when they are f32 on the CPU.
    fused: Option<LayerNormOp>,
}

impl LayerNorm {
    /// `gamma` and `beta` are `[features]`.
    pub(crate) fn new(gamma: Tensor, beta: Tensor, eps: f64) -> candle_core::Result<Self> {
        let fused = if is_cpu_f32(&gamma) && is_cpu_f32(&beta) {
            Some(LayerNormOp {
                gamma: gamma.to_vec1::<f32>()?.into(),
                beta: beta.to_vec1::<f32>()?.into(),
                eps: eps as f32,
            })
        } else {
            None
        };
        Ok(Self {
            gamma,
            beta,
            eps,
            fused,
        })
    }

    /// Normalizes the last dimension of `x`: one fused pass each way for f32 on the CPU,
    /// candle ops elsewhere. Other float types are normalized in f32 and converted back (the
    /// parameters stay f32), as OpenAI's fp16 CLIP does.
    pub(crate) fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        if x.dtype() != DType::F32 {
            return self.forward(&x.to_dtype(DType::F32)?)?.to_dtype(x.dtype());
        }
        match &self.fused {
            Some(op) if is_cpu_f32(x) => x.contiguous()?.apply_op1(op.clone()),
            _ => self.forward_with_ops(x),
        }
    }

    /// For f32 on the CPU, the normalized value of `x` (contiguous, outside the graph) and its
    /// input adjoint (one fused pass each); `None` elsewhere.
    pub(crate) fn value_and_adjoint(
        &self,
        x: &Tensor,
    ) -> candle_core::Result<Option<(Tensor, InputAdjoint)>> {
        let Some(op) = self.fused.clone().filter(|_| is_cpu_f32(x)) else {
            return Ok(None);
        };
        let value = x.apply_op1_no_bwd(&op)?;
        let x = x.clone();
        let adjoint: InputAdjoint = Box::new(move |g| x.apply_op2_no_bwd(&g.contiguous()?, &op));
        Ok(Some((value, adjoint)))
    }

    /// [`Self::forward`] composed from candle ops with a backward (any device).
    pub(crate) fn forward_with_ops(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let mean = x.mean_keepdim(D::Minus1)?;
        let centered = x.broadcast_sub(&mean)?;
        let var = centered.sqr()?.mean_keepdim(D::Minus1)?;
        let normed = centered.broadcast_div(&(var + self.eps)?.sqrt()?)?;
        normed.broadcast_mul(&self.gamma)?.broadcast_add(&self.beta)
    }
}

/// Softmax over the last dimension: one fused pass each way for f32 on the CPU, candle ops
/// elsewhere. Other float types are computed in f32 and converted back.
pub(crate) fn softmax_last_dim(x: &Tensor) -> candle_core::Result<Tensor> {
    if x.dtype() != DType::F32 {
        return softmax_last_dim(&x.to_dtype(DType::F32)?)?.to_dtype(x.dtype());
    }
    if is_cpu_f32(x) {
        let len = x.dim(D::Minus1)?;
        return x.contiguous()?.apply_op1(SoftmaxOp { len });
    }
    softmax_last_dim_with_ops(x)
}

/// [`softmax_last_dim`] built from ops with a backward. The row maximum is subtracted for
/// stability and detached (softmax does not depend on it).
pub(crate) fn softmax_last_dim_with_ops(x: &Tensor) -> candle_core::Result<Tensor> {
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
    /// Applies the activation element-wise (quick-GELU fused for f32 on the CPU).
    pub(crate) fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        if *self == Activation::QuickGelu && is_cpu_f32(x) {
            return x.contiguous()?.apply_op1(QuickGeluOp);
        }
        self.forward_with_ops(x)
    }

    /// [`Self::forward`] composed from candle ops with a backward (any device).
    pub(crate) fn forward_with_ops(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        match self {
            // sigmoid(z) = (1 + tanh(z / 2)) / 2: no overflow, tanh has a backward.
            Activation::QuickGelu => x.mul(&(x * (1.702 / 2.0))?.tanh()?.affine(0.5, 0.5)?),
            Activation::Gelu => x.gelu_erf(),
        }
    }
}

#[cfg(test)]
mod fused_tests {
    use candle_core::{Device, Tensor};

    use crate::test_grad::{assert_close, value_and_grad};

    use super::*;

    /// The fused CPU kernel against the candle ops, value and gradient, on rows of `len`
    /// values drawn in `[-range, range]` (a strided view as input, as the encoder passes).
    fn check(
        len: usize,
        range: f32,
        fused: impl Fn(&Tensor) -> Tensor,
        ops: impl Fn(&Tensor) -> Tensor,
    ) {
        let device = Device::Cpu;
        let x = Tensor::rand(-range, range, (len, 6, 5), &device)
            .unwrap()
            .transpose(0, 2)
            .unwrap();
        let probe = Tensor::rand(-1f32, 1f32, (5, 6, len), &device).unwrap();
        let (y_fused, g_fused) = value_and_grad(&x, &probe, &fused);
        let (y_ops, g_ops) = value_and_grad(&x, &probe, &ops);
        assert_close(&y_fused, &y_ops, 2e-6, "value");
        assert_close(&g_fused, &g_ops, 2e-5, "gradient");
    }

    #[test]
    fn fused_layer_norm_matches_the_composed_one() {
        let device = Device::Cpu;
        for (len, range) in [(1, 1.0), (7, 1.0), (768, 30.0)] {
            let norm = LayerNorm::new(
                Tensor::rand(0.5f32, 1.5, len, &device).unwrap(),
                Tensor::rand(-0.5f32, 0.5, len, &device).unwrap(),
                1e-5,
            )
            .unwrap();
            check(
                len,
                range,
                |x| norm.forward(x).unwrap(),
                |x| norm.forward_with_ops(x).unwrap(),
            );
        }
    }

    #[test]
    fn fused_quick_gelu_matches_the_composed_one_far_out() {
        // Large |x|: exp overflows in a naive sigmoid.
        for range in [3.0, 200.0] {
            check(
                9,
                range,
                |x| Activation::QuickGelu.forward(x).unwrap(),
                |x| Activation::QuickGelu.forward_with_ops(x).unwrap(),
            );
        }
    }

    /// The feed-forward block as one node against its three layers, f32 and bf16 weights.
    #[test]
    fn fused_mlp_matches_its_three_layers() {
        let device = Device::Cpu;
        for dtype in [DType::F32, DType::BF16] {
            let layer = |out: usize, inp: usize| {
                Linear::new(
                    (Tensor::rand(-1f32, 1.0, (out, inp), &device).unwrap() / (inp as f64).sqrt())
                        .unwrap()
                        .to_dtype(dtype)
                        .unwrap(),
                    Some(Tensor::rand(-0.5f32, 0.5, out, &device).unwrap()),
                )
                .unwrap()
            };
            let mlp = Mlp {
                fc1: layer(24, 5),
                fc2: layer(5, 24),
                activation: Activation::QuickGelu,
            };
            check(
                5,
                3.0,
                |x| {
                    let input = x.detach().contiguous().unwrap();
                    let (value, adjoint) = mlp.value_and_adjoint(&input).unwrap().unwrap();
                    attach_input_gradient(&value, x, adjoint).unwrap()
                },
                |x| mlp.forward_with_layers(x).unwrap(),
            );
        }
    }

    #[test]
    fn fused_softmax_matches_the_composed_one() {
        for (len, range) in [(1, 1.0), (50, 4.0), (77, 80.0)] {
            check(
                len,
                range,
                |x| softmax_last_dim(x).unwrap(),
                |x| softmax_last_dim_with_ops(x).unwrap(),
            );
        }
        // A causal mask: -inf logits get probability 0 and no gradient.
        let device = Device::Cpu;
        let mask = Tensor::new(&[[0f32, f32::NEG_INFINITY], [0.0, 0.0]], &device).unwrap();
        let x = (Tensor::rand(-1f32, 1f32, (2, 2), &device).unwrap() + &mask).unwrap();
        let probe = Tensor::rand(-1f32, 1f32, (2, 2), &device).unwrap();
        let (y, g) = value_and_grad(&x, &probe, |x| softmax_last_dim(x).unwrap());
        assert_eq!(y.to_vec2::<f32>().unwrap()[0], [1.0, 0.0]);
        assert_eq!(g.to_vec2::<f32>().unwrap()[0], [0.0, 0.0]);
    }
}
