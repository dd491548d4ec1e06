//! CLIP's vision tower (Hugging Face `CLIPVisionTransformer`) up to the pooled, layer-normed
//! class token.

use candle_core::Tensor;

use super::config::ClipVisionConfig;
use super::transformer::{load_layer_norm, Encoder, EncoderShape};
use super::ClipPrecision;
use crate::error::{Result, StyleLossError};
use crate::nn::{LayerNorm, Linear};
use crate::tensor_file::NamedTensors;

/// The vision transformer; input is CLIP-normalized pixels `[batch, 3, size, size]`.
#[derive(Clone, Debug)]
pub(crate) struct VisionTower {
    config: ClipVisionConfig,
    /// The patch convolution (stride = kernel, no bias) as a linear map of flattened patches.
    patch_embedding: Linear,
    class_embedding: Tensor,
    position_embedding: Tensor,
    pre_layernorm: LayerNorm,
    encoder: Encoder,
    post_layernorm: LayerNorm,
}

impl VisionTower {
    /// Loads `vision_model.*`, the matrices and embeddings converted to `precision`'s formats.
    pub(crate) fn load(
        w: &NamedTensors,
        config: &ClipVisionConfig,
        precision: ClipPrecision,
    ) -> Result<Self> {
        let dtype = precision.activation_dtype();
        let h = config.hidden_size;
        let p = config.patch_size;
        let c = config.num_channels;
        let positions = config.grid_size() * config.grid_size() + 1;
        let eps = config.layer_norm_eps;
        let conv = w.get(
            "vision_model.embeddings.patch_embedding.weight",
            &[h, c, p, p],
        )?;
        Ok(Self {
            patch_embedding: Linear::new(
                conv.reshape((h, c * p * p))?
                    .to_dtype(precision.matrix_dtype())?,
                None,
            )?,
            class_embedding: w
                .get("vision_model.embeddings.class_embedding", &[h])?
                .to_dtype(dtype)?,
            position_embedding: w
                .get(
                    "vision_model.embeddings.position_embedding.weight",
                    &[positions, h],
                )?
                .to_dtype(dtype)?,
            pre_layernorm: load_layer_norm(w, "vision_model.pre_layrnorm", h, eps)?,
            encoder: Encoder::load(
                w,
                "vision_model.encoder",
                EncoderShape {
                    hidden: h,
                    intermediate: config.intermediate_size,
                    layers: config.num_hidden_layers,
                    heads: config.num_attention_heads,
                    activation: config.hidden_act,
                    layer_norm_eps: eps,
                    precision,
                },
            )?,
            post_layernorm: load_layer_norm(w, "vision_model.post_layernorm", h, eps)?,
            config: config.clone(),
        })
    }

    /// Pooled output `[batch, hidden]` of normalized pixels `[batch, 3, size, size]`, in the
    /// tower's format (the pixels are converted to it).
    pub(crate) fn forward(&self, pixels: &Tensor) -> Result<Tensor> {
        let (batch, channels, height, width) = pixels.dims4()?;
        let size = self.config.image_size;
        if channels != self.config.num_channels || height != size || width != size {
            return Err(StyleLossError::Input {
                name: "pixels".into(),
                reason: format!(
                    "shape {:?}, the vision tower takes [batch, {}, {size}, {size}]",
                    pixels.dims(),
                    self.config.num_channels
                ),
            });
        }
        let p = self.config.patch_size;
        let g = self.config.grid_size();
        let hidden = self.config.hidden_size;
        // [b, c, g, p, g, p] -> [b, g, g, c, p, p]: each row is one patch in (c, y, x) order,
        // the order of the flattened convolution kernel.
        let patches = pixels
            .to_dtype(self.class_embedding.dtype())?
            .reshape(vec![batch, channels, g, p, g, p])?
            .permute(vec![0, 2, 4, 1, 3, 5])?
            .reshape((batch * g * g, channels * p * p))?;
        let patch_embeds =
            self.patch_embedding
                .forward(&patches)?
                .reshape((batch, g * g, hidden))?;
        let class = self
            .class_embedding
            .reshape((1, 1, hidden))?
            .broadcast_as((batch, 1, hidden))?;
        let x =
            Tensor::cat(&[&class, &patch_embeds], 1)?.broadcast_add(&self.position_embedding)?;
        let x = self.pre_layernorm.forward(&x)?;
        let pooled = self.encoder.forward_first_token(&x, None)?;
        Ok(self.post_layernorm.forward(&pooled)?)
    }
}
