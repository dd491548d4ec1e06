//! CLIP's text tower (Hugging Face `CLIPTextTransformer`) up to the pooled end-of-text token.

use candle_core::{Device, Tensor};

use super::config::ClipTextConfig;
use super::transformer::{load_layer_norm, Encoder, EncoderShape};
use super::ClipPrecision;
use crate::error::{Result, StyleLossError};
use crate::nn::LayerNorm;
use crate::tensor_file::NamedTensors;

/// The eos id of legacy OpenAI configs; transformers then pools at the largest token id.
const LEGACY_EOS_TOKEN_ID: u32 = 2;

/// The causal text transformer.
#[derive(Clone, Debug)]
pub(crate) struct TextTower {
    config: ClipTextConfig,
    token_embedding: Tensor,
    position_embedding: Tensor,
    encoder: Encoder,
    final_layer_norm: LayerNorm,
}

impl TextTower {
    /// Loads `text_model.*`, the matrices and embeddings converted to `precision`'s formats.
    pub(crate) fn load(
        w: &NamedTensors,
        config: &ClipTextConfig,
        precision: ClipPrecision,
    ) -> Result<Self> {
        let dtype = precision.activation_dtype();
        let h = config.hidden_size;
        Ok(Self {
            token_embedding: w
                .get(
                    "text_model.embeddings.token_embedding.weight",
                    &[config.vocab_size, h],
                )?
                .to_dtype(dtype)?,
            position_embedding: w
                .get(
                    "text_model.embeddings.position_embedding.weight",
                    &[config.max_position_embeddings, h],
                )?
                .to_dtype(dtype)?,
            encoder: Encoder::load(
                w,
                "text_model.encoder",
                EncoderShape {
                    hidden: h,
                    intermediate: config.intermediate_size,
                    layers: config.num_hidden_layers,
                    heads: config.num_attention_heads,
                    activation: config.hidden_act,
                    layer_norm_eps: config.layer_norm_eps,
                    precision,
                },
            )?,
            final_layer_norm: load_layer_norm(
                w,
                "text_model.final_layer_norm",
                h,
                config.layer_norm_eps,
            )?,
            config: config.clone(),
        })
    }

    /// The position whose output is pooled, as transformers chooses it.
    fn pool_position(&self, ids: &[u32]) -> usize {
        if self.config.eos_token_id == LEGACY_EOS_TOKEN_ID {
            // argmax; the first maximum on ties, as torch.argmax.
            let max = ids.iter().copied().max().unwrap_or(0);
            ids.iter().position(|&id| id == max).unwrap_or(0)
        } else {
            ids.iter()
                .position(|&id| id == self.config.eos_token_id)
                .unwrap_or(0)
        }
    }

    /// Pooled output `[rows, hidden]` for rows of token ids (each at most the context length).
    ///
    /// Attention is causal, so the pooled token depends only on the tokens up to it: the
    /// sequences are cut after the last pooled position, which changes nothing but the cost.
    pub(crate) fn forward(&self, ids: &[Vec<u32>], device: &Device) -> Result<Tensor> {
        let context = self.config.max_position_embeddings;
        let input_error = |reason: String| StyleLossError::Input {
            name: "token ids".into(),
            reason,
        };
        if ids.is_empty() {
            return Err(input_error("no sequences".into()));
        }
        for (row, seq) in ids.iter().enumerate() {
            if seq.is_empty() || seq.len() > context {
                return Err(input_error(format!(
                    "row {row} has {} tokens, expected 1..={context}",
                    seq.len()
                )));
            }
            if let Some(&bad) = seq
                .iter()
                .find(|&&id| id as usize >= self.config.vocab_size)
            {
                return Err(input_error(format!(
                    "row {row} has token id {bad} >= vocab_size {}",
                    self.config.vocab_size
                )));
            }
        }
        let pooled: Vec<usize> = ids.iter().map(|seq| self.pool_position(seq)).collect();
        let len = pooled.iter().max().copied().unwrap_or(0) + 1;
        let rows = ids.len();
        let flat: Vec<u32> = ids
            .iter()
            .flat_map(|seq| (0..len).map(move |i| seq.get(i).copied().unwrap_or(0)))
            .collect();
        let h = self.config.hidden_size;
        let flat = Tensor::from_vec(flat, rows * len, device)?;
        let x = self
            .token_embedding
            .index_select(&flat, 0)?
            .reshape((rows, len, h))?
            .broadcast_add(&self.position_embedding.narrow(0, 0, len)?)?;
        let mask: Vec<f32> = (0..len * len)
            .map(|i| {
                if i % len > i / len {
                    f32::NEG_INFINITY
                } else {
                    0.0
                }
            })
            .collect();
        let mask = Tensor::from_vec(mask, (len, len), device)?;
        let x = self.encoder.forward(&x, Some(&mask))?;
        let x = self
            .final_layer_norm
            .forward(&x)?
            .reshape((rows * len, h))?;
        let rows_at: Vec<u32> = pooled
            .iter()
            .enumerate()
            .map(|(row, &p)| (row * len + p) as u32)
            .collect();
        Ok(x.index_select(&Tensor::new(rows_at, device)?, 0)?)
    }
}
