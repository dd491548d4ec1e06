//! The pre-norm transformer encoder shared by CLIP's two towers (Hugging Face `CLIPEncoder`).

use candle_core::Tensor;

use super::ClipPrecision;

use crate::error::Result;
use crate::matmul::checked_matmul;
use crate::nn::{softmax_last_dim, Activation, LayerNorm, Linear, Mlp};
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
    /// `x` is `[batch, tokens, hidden]`; `mask`, if any, is added to the `[tokens, tokens]`
    /// attention logits (0 or -inf, any float type).
    fn forward(&self, x: &Tensor, mask: Option<&Tensor>) -> Result<Tensor> {
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
        let x = (x + self.attention.forward(&self.ln1.forward(x)?, mask)?)?;
        let h = self.mlp.forward(&self.ln2.forward(&x)?)?;
        Ok((x + h)?)
    }
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
