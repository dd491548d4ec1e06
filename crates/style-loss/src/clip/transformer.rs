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
    /// For f32 on the CPU, the attention's value for the first `queries` tokens of `x` `[batch,
    /// tokens, hidden]` (contiguous, outside the graph; keys and values from every token) and its
    /// input adjoint, from `[batch, queries, hidden]` to `x`'s shape: `Wo`'s adjoint, the two
    /// products' and the softmax's derivatives, the three projections' adjoints summed. The
    /// intermediate values (queries, keys, values, the probabilities) are kept once, and none
    /// gets a zeroed gradient to add into, as a node of its own would. `mask` as in
    /// [`Self::forward_with_ops`]. `None` elsewhere.
    fn value_and_adjoint(
        &self,
        x: &Tensor,
        mask: Option<&Tensor>,
        queries: usize,
    ) -> candle_core::Result<Option<(Tensor, InputAdjoint)>> {
        if !is_cpu_f32(x) {
            return Ok(None);
        }
        let (batch, tokens, hidden) = x.dims3()?;
        let (heads, head_dim) = (self.heads, self.head_dim);
        // [batch * rows, hidden] <-> [batch, heads, rows, head_dim].
        let split = move |t: Tensor, rows: usize| -> candle_core::Result<Tensor> {
            t.reshape((batch, rows, heads, head_dim))?
                .transpose(1, 2)?
                .contiguous()
        };
        let merge = move |t: Tensor, rows: usize| -> candle_core::Result<Tensor> {
            t.transpose(1, 2)?
                .contiguous()?
                .reshape((batch * rows, hidden))
        };
        let softmax = SoftmaxOp { len: tokens };
        let scale = 1.0 / (head_dim as f64).sqrt();
        let input = x.reshape((batch * tokens, hidden))?;
        let query_input = leading_tokens(x, queries)?.reshape((batch * queries, hidden))?;
        let q = split((self.q.value(&query_input)? * scale)?, queries)?;
        let k = split(self.k.value(&input)?, tokens)?;
        let v = split(self.v.value(&input)?, tokens)?;
        let mut logits = checked_matmul(&q, &k.t()?.contiguous()?)?;
        if let Some(mask) = mask {
            logits =
                logits.broadcast_add(&mask.narrow(0, 0, queries)?.to_dtype(logits.dtype())?)?;
        }
        let probabilities = logits.apply_op1_no_bwd(&softmax)?;
        drop(logits);
        let value = self
            .out
            .value(&merge(checked_matmul(&probabilities, &v)?, queries)?)?
            .reshape((batch, queries, hidden))?;
        let (q_layer, k_layer, v_layer, out) = (
            self.q.clone(),
            self.k.clone(),
            self.v.clone(),
            self.out.clone(),
        );
        let adjoint: InputAdjoint = Box::new(move |g| {
            let g = g.reshape((batch * queries, hidden))?.contiguous()?;
            let g_context = split(out.input_gradient(&g)?, queries)?;
            let g_probabilities = checked_matmul(&g_context, &v.t()?.contiguous()?)?;
            let g_v = checked_matmul(&probabilities.t()?.contiguous()?, &g_context)?;
            let g_logits = probabilities.apply_op2_no_bwd(&g_probabilities, &softmax)?;
            let g_q = (checked_matmul(&g_logits, &k)? * scale)?;
            let g_k = checked_matmul(&g_logits.t()?.contiguous()?, &q)?;
            let g_query_input = q_layer
                .input_gradient(&merge(g_q, queries)?)?
                .reshape((batch, queries, hidden))?;
            let g_x = (k_layer.input_gradient(&merge(g_k, tokens)?)?
                + v_layer.input_gradient(&merge(g_v, tokens)?)?)?
            .reshape((batch, tokens, hidden))?;
            g_x + pad_tokens(&g_query_input, tokens)?
        });
        Ok(Some((value, adjoint)))
    }

    /// The attention's value for the first `queries` tokens of `x` `[batch, tokens, hidden]`
    /// (keys and values from every token), `[batch, queries, hidden]`; `mask`, if any, is added
    /// to the `[tokens, tokens]` attention logits (0 or -inf, any float type; its first
    /// `queries` rows). Candle ops with a backward (any device and format).
    fn forward_with_ops(
        &self,
        x: &Tensor,
        mask: Option<&Tensor>,
        queries: usize,
    ) -> Result<Tensor> {
        let (batch, tokens, hidden) = x.dims3()?;
        let split = |t: Tensor, rows: usize| -> candle_core::Result<Tensor> {
            t.reshape((batch, rows, self.heads, self.head_dim))?
                .transpose(1, 2)?
                .contiguous()
        };
        let scale = 1.0 / (self.head_dim as f64).sqrt();
        let q = split(
            (self.q.forward(&x.narrow(1, 0, queries)?)? * scale)?,
            queries,
        )?;
        let k = split(self.k.forward(x)?, tokens)?;
        let v = split(self.v.forward(x)?, tokens)?;
        let mut logits = checked_matmul(&q, &k.t()?.contiguous()?)?;
        if let Some(mask) = mask {
            logits =
                logits.broadcast_add(&mask.narrow(0, 0, queries)?.to_dtype(logits.dtype())?)?;
        }
        let context = checked_matmul(&softmax_last_dim(&logits)?, &v)?;
        let context = context.transpose(1, 2)?.reshape((batch, queries, hidden))?;
        Ok(self.out.forward(&context)?)
    }
}

/// The first `count` tokens of `x` `[batch, tokens, hidden]`, contiguous (`x` itself when that
/// is all of them).
fn leading_tokens(x: &Tensor, count: usize) -> candle_core::Result<Tensor> {
    if count == x.dim(1)? {
        return Ok(x.clone());
    }
    x.narrow(1, 0, count)?.contiguous()
}

/// `g` `[batch, queries, hidden]` followed by zeros up to `tokens` tokens: the gradient of
/// [`leading_tokens`]'s input.
fn pad_tokens(g: &Tensor, tokens: usize) -> candle_core::Result<Tensor> {
    let (batch, queries, hidden) = g.dims3()?;
    if queries == tokens {
        return Ok(g.clone());
    }
    let zeros = Tensor::zeros((batch, tokens - queries, hidden), g.dtype(), g.device())?;
    Tensor::cat(&[g, &zeros], 1)
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
    /// The layer's output for the first `queries` tokens of `x` `[batch, tokens, hidden]`:
    /// every token is a key and a value of the attention, but only those rows go on through
    /// the residual and the MLP.
    fn forward(&self, x: &Tensor, mask: Option<&Tensor>, queries: usize) -> Result<Tensor> {
        let x = pre_norm_residual(
            x,
            queries,
            &self.ln1,
            |normed| self.attention.value_and_adjoint(normed, mask, queries),
            |normed| self.attention.forward_with_ops(normed, mask, queries),
        )?;
        pre_norm_residual(
            &x,
            queries,
            &self.ln2,
            |normed| self.mlp.value_and_adjoint(normed),
            |normed| Ok(self.mlp.forward_with_layers(normed)?),
        )
    }
}

/// `x[:, ..queries] + inner(norm(x))`, where `inner` maps `[batch, tokens, hidden]` to the first
/// `queries` tokens' rows. Where the norm and `inner` give their values and input adjoints (f32
/// on the CPU: `fused`), one node of the graph whose input gradient is
/// `pad(g) + norm'(inner'(g))`; elsewhere the norm, `ops` and the sum as nodes in turn.
fn pre_norm_residual(
    x: &Tensor,
    queries: usize,
    norm: &LayerNorm,
    fused: impl FnOnce(&Tensor) -> candle_core::Result<Option<(Tensor, InputAdjoint)>>,
    ops: impl FnOnce(&Tensor) -> Result<Tensor>,
) -> Result<Tensor> {
    let input = x.detach().contiguous()?;
    if let Some((normed, norm_adjoint)) = norm.value_and_adjoint(&input)? {
        if let Some((inner, inner_adjoint)) = fused(&normed)? {
            let tokens = input.dim(1)?;
            let value = (leading_tokens(&input, queries)? + inner)?;
            return Ok(attach_input_gradient(&value, x, move |g| {
                pad_tokens(g, tokens)? + norm_adjoint(&inner_adjoint(g)?)?
            })?);
        }
    }
    Ok((x.narrow(1, 0, queries)? + ops(&norm.forward(x)?)?)?)
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
        let tokens = x.dim(1)?;
        self.layers
            .iter()
            .try_fold(x.clone(), |x, layer| layer.forward(&x, mask, tokens))
    }

    /// The last layer's output for the first token of `[batch, tokens, hidden]`, `[batch,
    /// hidden]`: the same value as `forward(x)`'s first token, with the last layer's query,
    /// output projection and MLP computed for that token alone (a pooled CLS token needs no
    /// other row, so about a twelfth of ViT-B/32's products is skipped, forward and backward).
    pub(crate) fn forward_first_token(&self, x: &Tensor, mask: Option<&Tensor>) -> Result<Tensor> {
        let tokens = x.dim(1)?;
        let Some((last, first)) = self.layers.split_last() else {
            return Ok(x.narrow(1, 0, 1)?.squeeze(1)?);
        };
        let x = first
            .iter()
            .try_fold(x.clone(), |x, layer| layer.forward(&x, mask, tokens))?;
        Ok(last.forward(&x, mask, 1)?.squeeze(1)?)
    }
}

#[cfg(test)]
mod tests {
    use candle_core::{DType, Device, Tensor};

    use crate::test_grad::{assert_close, max_abs};

    use super::*;

    /// `f(x)` and `d sum(f(x) * probe) / dx`, as an array.
    fn value_and_grad(x: &Tensor, probe: &Tensor, f: impl Fn(&Tensor) -> Tensor) -> [Tensor; 2] {
        let (y, g) = crate::test_grad::value_and_grad(x, probe, f);
        [y, g]
    }

    /// A random layer, its weight matrices in `dtype` and its biases in `bias_dtype` (layer
    /// norms in f32).
    fn random_layer(
        dtype: DType,
        bias_dtype: DType,
        hidden: usize,
        heads: usize,
        intermediate: usize,
    ) -> EncoderLayer {
        let device = Device::Cpu;
        let norm = || {
            LayerNorm::new(
                Tensor::rand(0.5f32, 1.5, hidden, &device).unwrap(),
                Tensor::rand(-0.5f32, 0.5, hidden, &device).unwrap(),
                1e-5,
            )
            .unwrap()
        };
        let linear = |out: usize, inp: usize| {
            Linear::new(
                (Tensor::rand(-1f32, 1.0, (out, inp), &device).unwrap() / (inp as f64).sqrt())
                    .unwrap()
                    .to_dtype(dtype)
                    .unwrap(),
                Some(
                    Tensor::rand(-0.5f32, 0.5, out, &device)
                        .unwrap()
                        .to_dtype(bias_dtype)
                        .unwrap(),
                ),
            )
            .unwrap()
        };
        EncoderLayer {
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
        }
    }

    /// A `[tokens, tokens]` causal mask: 0 on and below the diagonal, -inf above.
    fn causal_mask(tokens: usize) -> Tensor {
        let causal: Vec<f32> = (0..tokens * tokens)
            .map(|k| {
                if k % tokens > k / tokens {
                    f32::NEG_INFINITY
                } else {
                    0.0
                }
            })
            .collect();
        Tensor::from_vec(causal, (tokens, tokens), &Device::Cpu).unwrap()
    }

    /// The encoder layer as two nodes (each pre-norm residual block computed outside the graph
    /// with its adjoint) against the ops in turn, and both for the first 1 or 2 tokens against
    /// the whole layer's first rows, value and gradient: f32 and bf16 weights, with and without
    /// a causal mask, three heads over a hidden size of 12.
    #[test]
    fn the_layer_as_two_nodes_matches_its_ops() {
        let device = Device::Cpu;
        let (batch, tokens, hidden, heads, intermediate) = (2, 5, 12, 3, 20);
        let causal = causal_mask(tokens);
        // With bf16 weights an activation that the two paths round to f32 one unit apart can
        // round to bf16 one bf16 unit apart (2^-8 of it), as happened in about 1 run in 40 of
        // these random inputs (4e-4 of the largest value): a bound of a few such units.
        for (dtype, tol) in [(DType::F32, 1e-5), (DType::BF16, 2e-3)] {
            let layer = random_layer(dtype, DType::F32, hidden, heads, intermediate);
            let x = Tensor::rand(-1f32, 1.0, (batch, tokens, hidden), &device).unwrap();
            for queries in [tokens, 1, 2] {
                let probe = Tensor::rand(-1f32, 1.0, (batch, queries, hidden), &device).unwrap();
                for mask in [None, Some(&causal)] {
                    let what = format!("{dtype:?}, {queries} queries, mask {}", mask.is_some());
                    // The fused path is the one taken.
                    let normed = layer.ln1.forward(&x).unwrap();
                    assert!(layer
                        .attention
                        .value_and_adjoint(&normed, mask, queries)
                        .unwrap()
                        .is_some());
                    assert!(layer.mlp.value_and_adjoint(&normed).unwrap().is_some());
                    let two_nodes =
                        value_and_grad(&x, &probe, |x| layer.forward(x, mask, queries).unwrap());
                    let ops = value_and_grad(&x, &probe, |x| {
                        let attended = layer
                            .attention
                            .forward_with_ops(
                                &layer.ln1.forward_with_ops(x).unwrap(),
                                mask,
                                queries,
                            )
                            .unwrap();
                        let x = (x.narrow(1, 0, queries).unwrap() + attended).unwrap();
                        let fed = layer
                            .mlp
                            .forward_with_layers(&layer.ln2.forward_with_ops(&x).unwrap())
                            .unwrap();
                        (x + fed).unwrap()
                    });
                    let whole = value_and_grad(&x, &probe, |x| {
                        layer
                            .forward(x, mask, tokens)
                            .unwrap()
                            .narrow(1, 0, queries)
                            .unwrap()
                    });
                    for (k, name) in ["value", "gradient"].iter().enumerate() {
                        let what = format!("{what}, {name}");
                        assert_close(&two_nodes[k], &ops[k], tol, &what);
                        assert_close(&two_nodes[k], &whole[k], tol, &what);
                    }
                }
            }
        }
    }

    /// The encoder's first token computed alone in the last layer against the whole encoder's
    /// first token, value and gradient, on the fused path (f32) and the ops' (f64, which every
    /// device and format but the CPU's f32 takes), with and without a causal mask; the gradient
    /// reaches every token of the input but under the mask.
    #[test]
    fn the_first_token_alone_matches_the_whole_encoders() {
        let device = Device::Cpu;
        let (batch, tokens, hidden, heads, intermediate) = (3, 6, 12, 3, 20);
        let causal = causal_mask(tokens);
        for dtype in [DType::F32, DType::F64] {
            let encoder = Encoder {
                layers: (0..3)
                    .map(|_| random_layer(dtype, dtype, hidden, heads, intermediate))
                    .collect(),
            };
            let x = Tensor::rand(-1f32, 1.0, (batch, tokens, hidden), &device)
                .unwrap()
                .to_dtype(dtype)
                .unwrap();
            let probe = Tensor::rand(-1f32, 1.0, (batch, hidden), &device)
                .unwrap()
                .to_dtype(dtype)
                .unwrap();
            for mask in [None, Some(&causal)] {
                let what = format!("{dtype:?}, mask {}", mask.is_some());
                let f32_of = |t: &Tensor| t.to_dtype(DType::F32).unwrap();
                let alone = value_and_grad(&x, &probe, |x| {
                    encoder.forward_first_token(x, mask).unwrap()
                });
                let whole = value_and_grad(&x, &probe, |x| {
                    let y = encoder.forward(x, mask).unwrap();
                    y.narrow(1, 0, 1).unwrap().squeeze(1).unwrap()
                });
                for k in 0..2 {
                    assert_close(&f32_of(&alone[k]), &f32_of(&whole[k]), 1e-5, &what);
                }
                // Under the causal mask the first token sees only itself: the other tokens'
                // gradients are zero there and not elsewhere.
                let rest = max_abs(&f32_of(&alone[1].narrow(1, 1, tokens - 1).unwrap()));
                assert_eq!(rest == 0.0, mask.is_some(), "{what}: {rest}");
            }
        }
    }
}
