//! The pre-norm transformer encoder shared by CLIP's two towers (Hugging Face `CLIPEncoder`).

use candle_core::Tensor;

use super::ClipPrecision;

use crate::cpu_elements::is_cpu_f32;
use crate::custom_grad::attach_input_gradient;
use crate::error::Result;
use crate::fused_cpu::SoftmaxOp;
use crate::matmul::checked_matmul;
use crate::nn::{softmax_last_dim, Activation, InputAdjoint, LayerNorm, Linear, Mlp};
use crate::tensor_file::NamedTensors;

/// Sizes of one encoder stack.
#[derive(Clone, Copy, Debug)]
pub(crate) struct EncoderShape {
    pub hidden: usize,
    pub intermediate: usize,
    pub layers: usize,
    pub heads: usize,
    pub activation: Activation,
    pub layer_norm_eps: f64,
    /// The format of the weight matrices and activations (layer norms and softmax compute in
    /// f32 whatever it is).
    pub precision: ClipPrecision,
}

/// Loads `{prefix}.weight` `[out, in]` and `{prefix}.bias` `[out]`, converted to the formats of
/// `precision`'s matrices and activations.
pub(crate) fn load_linear(
    w: &NamedTensors,
    prefix: &str,
    out_features: usize,
    in_features: usize,
    bias: bool,
    precision: ClipPrecision,
) -> Result<Linear> {
    let weight = w
        .get(&format!("{prefix}.weight"), &[out_features, in_features])?
        .to_dtype(precision.matrix_dtype())?;
    let bias = if bias {
        Some(
            w.get(&format!("{prefix}.bias"), &[out_features])?
                .to_dtype(precision.activation_dtype())?,
        )
    } else {
        None
    };
    Ok(Linear::new(weight, bias)?)
}

/// Loads `{prefix}.weight` and `{prefix}.bias`, both `[features]`.
pub(crate) fn load_layer_norm(
    w: &NamedTensors,
    prefix: &str,
    features: usize,
    eps: f64,
) -> Result<LayerNorm> {
    Ok(LayerNorm::new(
        w.get(&format!("{prefix}.weight"), &[features])?,
        w.get(&format!("{prefix}.bias"), &[features])?,
        eps,
    )?)
}

/// Multi-head self-attention.
#[derive(Clone, Debug)]
struct Attention {
    q: Linear,
    k: Linear,
    v: Linear,
    out: Linear,
    heads: usize,
    head_dim: usize,
}

impl Attention {
    /// For f32 on the CPU, the attention's value on `x` `[batch, tokens, hidden]` (contiguous,
    /// outside the graph) and its input adjoint: `Wo`'s adjoint, the two products' and the
    /// softmax's derivatives, the three projections' adjoints summed. The intermediate values
    /// (queries, keys, values, the probabilities) are kept once, and none gets a zeroed
    /// gradient to add into, as a node of its own would. `mask` as in [`Self::forward_with_ops`].
    /// `None` elsewhere.
    fn value_and_adjoint(
        &self,
        x: &Tensor,
        mask: Option<&Tensor>,
    ) -> candle_core::Result<Option<(Tensor, InputAdjoint)>> {
        if !is_cpu_f32(x) {
            return Ok(None);
        }
        let (batch, tokens, hidden) = x.dims3()?;
        let (heads, head_dim) = (self.heads, self.head_dim);
        // [batch * tokens, hidden] <-> [batch, heads, tokens, head_dim].
        let split = move |t: Tensor| -> candle_core::Result<Tensor> {
            t.reshape((batch, tokens, heads, head_dim))?
                .transpose(1, 2)?
                .contiguous()
        };
        let merge = move |t: Tensor| -> candle_core::Result<Tensor> {
            t.transpose(1, 2)?
                .contiguous()?
                .reshape((batch * tokens, hidden))
        };
        let softmax = SoftmaxOp { len: tokens };
        let scale = 1.0 / (head_dim as f64).sqrt();
        let input = x.reshape((batch * tokens, hidden))?;
        let q = split((self.q.value(&input)? * scale)?)?;
        let k = split(self.k.value(&input)?)?;
        let v = split(self.v.value(&input)?)?;
        let mut logits = checked_matmul(&q, &k.t()?.contiguous()?)?;
        if let Some(mask) = mask {
            logits = logits.broadcast_add(&mask.to_dtype(logits.dtype())?)?;
        }
        let probabilities = logits.apply_op1_no_bwd(&softmax)?;
        drop(logits);
        let value = self
            .out
            .value(&merge(checked_matmul(&probabilities, &v)?)?)?
            .reshape((batch, tokens, hidden))?;
        let (q_layer, k_layer, v_layer, out) = (
            self.q.clone(),
            self.k.clone(),
            self.v.clone(),
            self.out.clone(),
        );
        let adjoint: InputAdjoint = Box::new(move |g| {
            let g = g.reshape((batch * tokens, hidden))?.contiguous()?;
            let g_context = split(out.input_gradient(&g)?)?;
            let g_probabilities = checked_matmul(&g_context, &v.t()?.contiguous()?)?;
            let g_v = checked_matmul(&probabilities.t()?.contiguous()?, &g_context)?;
            let g_logits = probabilities.apply_op2_no_bwd(&g_probabilities, &softmax)?;
            let g_q = (checked_matmul(&g_logits, &k)? * scale)?;
            let g_k = checked_matmul(&g_logits.t()?.contiguous()?, &q)?;
            let g_x =
                (q_layer.input_gradient(&merge(g_q)?)? + k_layer.input_gradient(&merge(g_k)?)?)?;
            (g_x + v_layer.input_gradient(&merge(g_v)?)?)?.reshape((batch, tokens, hidden))
        });
        Ok(Some((value, adjoint)))
    }

    /// `x` is `[batch, tokens, hidden]`; `mask`, if any, is added to the `[tokens, tokens]`
    /// attention logits (0 or -inf, any float type). Candle ops with a backward (any device and
    /// format).
    fn forward_with_ops(&self, x: &Tensor, mask: Option<&Tensor>) -> Result<Tensor> {
        let (batch, tokens, hidden) = x.dims3()?;
        let split = |t: Tensor| -> candle_core::Result<Tensor> {
            t.reshape((batch, tokens, self.heads, self.head_dim))?
                .transpose(1, 2)?
                .contiguous()
        };
        let scale = 1.0 / (self.head_dim as f64).sqrt();
        let q = split((self.q.forward(x)? * scale)?)?;
        let k = split(self.k.forward(x)?)?;
        let v = split(self.v.forward(x)?)?;
        let mut logits = checked_matmul(&q, &k.t()?.contiguous()?)?;
        if let Some(mask) = mask {
            logits = logits.broadcast_add(&mask.to_dtype(logits.dtype())?)?;
        }
        let context = checked_matmul(&softmax_last_dim(&logits)?, &v)?;
        let context = context.transpose(1, 2)?.reshape((batch, tokens, hidden))?;
        Ok(self.out.forward(&context)?)
    }
}

/// One pre-norm layer: `x + attn(ln1(x))`, then `x + mlp(ln2(x))`.
#[derive(Clone, Debug)]
struct EncoderLayer {
    ln1: LayerNorm,
    attention: Attention,
    ln2: LayerNorm,
    mlp: Mlp,
}

impl EncoderLayer {
    fn forward(&self, x: &Tensor, mask: Option<&Tensor>) -> Result<Tensor> {
        let x = pre_norm_residual(
            x,
            &self.ln1,
            |normed| self.attention.value_and_adjoint(normed, mask),
            |normed| self.attention.forward_with_ops(normed, mask),
        )?;
        pre_norm_residual(
            &x,
            &self.ln2,
            |normed| self.mlp.value_and_adjoint(normed),
            |normed| Ok(self.mlp.forward_with_layers(normed)?),
        )
    }
}

/// `x + inner(norm(x))`. Where the norm and `inner` give their values and input adjoints (f32
/// on the CPU: `fused`), one node of the graph whose input gradient is
/// `g + norm'(inner'(g))`; elsewhere the norm, `ops` and the sum as nodes in turn.
fn pre_norm_residual(
    x: &Tensor,
    norm: &LayerNorm,
    fused: impl FnOnce(&Tensor) -> candle_core::Result<Option<(Tensor, InputAdjoint)>>,
    ops: impl FnOnce(&Tensor) -> Result<Tensor>,
) -> Result<Tensor> {
    let input = x.detach().contiguous()?;
    if let Some((normed, norm_adjoint)) = norm.value_and_adjoint(&input)? {
        if let Some((inner, inner_adjoint)) = fused(&normed)? {
            let value = (&input + inner)?;
            return Ok(attach_input_gradient(&value, x, move |g| {
                g + norm_adjoint(&inner_adjoint(g)?)?
            })?);
        }
    }
    Ok((x + ops(&norm.forward(x)?)?)?)
}

/// A stack of encoder layers (`{prefix}.layers.{i}.*` in the checkpoint).
#[derive(Clone, Debug)]
pub(crate) struct Encoder {
    layers: Vec<EncoderLayer>,
}

impl Encoder {
    /// Loads `{prefix}.layers.0 ..` with the Hugging Face CLIP names.
    pub(crate) fn load(w: &NamedTensors, prefix: &str, shape: EncoderShape) -> Result<Self> {
        let (h, dtype) = (shape.hidden, shape.precision);
        let layers = (0..shape.layers)
            .map(|i| {
                let p = format!("{prefix}.layers.{i}");
                Ok(EncoderLayer {
                    ln1: load_layer_norm(w, &format!("{p}.layer_norm1"), h, shape.layer_norm_eps)?,
                    attention: Attention {
                        q: load_linear(w, &format!("{p}.self_attn.q_proj"), h, h, true, dtype)?,
                        k: load_linear(w, &format!("{p}.self_attn.k_proj"), h, h, true, dtype)?,
                        v: load_linear(w, &format!("{p}.self_attn.v_proj"), h, h, true, dtype)?,
                        out: load_linear(w, &format!("{p}.self_attn.out_proj"), h, h, true, dtype)?,
                        heads: shape.heads,
                        head_dim: h / shape.heads,
                    },
                    ln2: load_layer_norm(w, &format!("{p}.layer_norm2"), h, shape.layer_norm_eps)?,
                    mlp: Mlp {
                        fc1: load_linear(
                            w,
                            &format!("{p}.mlp.fc1"),
                            shape.intermediate,
                            h,
                            true,
                            dtype,
                        )?,
                        fc2: load_linear(
                            w,
                            &format!("{p}.mlp.fc2"),
                            h,
                            shape.intermediate,
                            true,
                            dtype,
                        )?,
                        activation: shape.activation,
                    },
                })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Self { layers })
    }

    /// Runs all layers on `[batch, tokens, hidden]`.
    pub(crate) fn forward(&self, x: &Tensor, mask: Option<&Tensor>) -> Result<Tensor> {
        self.layers
            .iter()
            .try_fold(x.clone(), |x, layer| layer.forward(&x, mask))
    }
}

#[cfg(test)]
mod tests {
    use candle_core::{DType, Device, Tensor, Var};

    use super::*;

    /// `f(x)` and `d sum(f(x) * probe) / dx`.
    fn value_and_grad(x: &Tensor, probe: &Tensor, f: impl Fn(&Tensor) -> Tensor) -> [Tensor; 2] {
        let var = Var::from_tensor(x).unwrap();
        let y = f(var.as_tensor());
        let grads = (&y * probe).unwrap().sum_all().unwrap().backward().unwrap();
        [y, grads.get(var.as_tensor()).unwrap().clone()]
    }

    /// The encoder layer as two nodes (each pre-norm residual block computed outside the graph
    /// with its adjoint) against the ops in turn, value and gradient: f32 and bf16 weights, with
    /// and without a causal mask, three heads over a hidden size of 12.
    #[test]
    fn the_layer_as_two_nodes_matches_its_ops() {
        let device = Device::Cpu;
        let (batch, tokens, hidden, heads, intermediate) = (2, 5, 12, 3, 20);
        let causal: Vec<f32> = (0..tokens * tokens)
            .map(|k| {
                if k % tokens > k / tokens {
                    f32::NEG_INFINITY
                } else {
                    0.0
                }
            })
            .collect();
        let causal = Tensor::from_vec(causal, (tokens, tokens), &device).unwrap();
        let norm = || {
            LayerNorm::new(
                Tensor::rand(0.5f32, 1.5, hidden, &device).unwrap(),
                Tensor::rand(-0.5f32, 0.5, hidden, &device).unwrap(),
                1e-5,
            )
            .unwrap()
        };
        for dtype in [DType::F32, DType::BF16] {
            let linear = |out: usize, inp: usize| {
                Linear::new(
                    (Tensor::rand(-1f32, 1.0, (out, inp), &device).unwrap() / (inp as f64).sqrt())
                        .unwrap()
                        .to_dtype(dtype)
                        .unwrap(),
                    Some(Tensor::rand(-0.5f32, 0.5, out, &device).unwrap()),
                )
                .unwrap()
            };
            let layer = EncoderLayer {
                ln1: norm(),
                attention: Attention {
                    q: linear(hidden, hidden),
                    k: linear(hidden, hidden),
                    v: linear(hidden, hidden),
                    out: linear(hidden, hidden),
                    heads,
                    head_dim: hidden / heads,
                },
                ln2: norm(),
                mlp: Mlp {
                    fc1: linear(intermediate, hidden),
                    fc2: linear(hidden, intermediate),
                    activation: Activation::QuickGelu,
                },
            };
            let x = Tensor::rand(-1f32, 1.0, (batch, tokens, hidden), &device).unwrap();
            let probe = Tensor::rand(-1f32, 1.0, (batch, tokens, hidden), &device).unwrap();
            for mask in [None, Some(&causal)] {
                // The fused path is the one taken.
                let normed = layer.ln1.forward(&x).unwrap();
                assert!(layer
                    .attention
                    .value_and_adjoint(&normed, mask)
                    .unwrap()
                    .is_some());
                assert!(layer.mlp.value_and_adjoint(&normed).unwrap().is_some());
                let two_nodes = value_and_grad(&x, &probe, |x| layer.forward(x, mask).unwrap());
                let ops = value_and_grad(&x, &probe, |x| {
                    let attended = layer
                        .attention
                        .forward_with_ops(&layer.ln1.forward_with_ops(x).unwrap(), mask)
                        .unwrap();
                    let x = (x + attended).unwrap();
                    let fed = layer
                        .mlp
                        .forward_with_layers(&layer.ln2.forward_with_ops(&x).unwrap())
                        .unwrap();
                    (x + fed).unwrap()
                });
                for (a, b) in two_nodes.iter().zip(&ops) {
                    let diff = (a - b)
                        .unwrap()
                        .abs()
                        .unwrap()
                        .max_all()
                        .unwrap()
                        .to_scalar::<f32>()
                        .unwrap();
                    let scale = b
                        .abs()
                        .unwrap()
                        .max_all()
                        .unwrap()
                        .to_scalar::<f32>()
                        .unwrap();
                    assert!(
                        diff <= 1e-5 * scale.max(1.0),
                        "{dtype:?}, mask {}: {diff} of {scale}",
                        mask.is_some()
                    );
                }
            }
        }
    }
}
