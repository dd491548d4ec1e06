//! CLIP (vision and text towers) in candle, from Hugging Face `transformers` checkpoints.
//!
//! Built only from ops whose backward exists, so gradients reach the input image (candle's own
//! CLIP cuts the graph in its fused layer norm and softmax).

mod config;
mod preprocess;
mod text;
mod transformer;
mod vision;

use std::path::Path;

use candle_core::{DType, Device, Tensor};

pub use crate::precision::{cpu_multiplies_bf16, ClipPrecision, CPU_BF16_ENV};
pub use config::{ClipConfig, ClipTextConfig, ClipVisionConfig};
pub(crate) use preprocess::normalize_channels;
pub use preprocess::{clip_preprocess, CLIP_MEAN, CLIP_STD};

use crate::auto_precision::{choose_clip, ClipProducts};
use crate::error::{Result, StyleLossError};
use crate::nn::{l2_normalize, Linear};
use crate::patches::PatchSettings;
use crate::tensor_file::NamedTensors;
use text::TextTower;
use transformer::load_linear;
use vision::VisionTower;

/// A CLIP model: towers and projections into the joint embedding space.
#[derive(Clone, Debug)]
pub struct ClipModel {
    config: ClipConfig,
    vision: VisionTower,
    visual_projection: Linear,
    /// `None` once dropped with [`ClipModel::drop_text_tower`].
    text: Option<(TextTower, Linear)>,
    device: Device,
    precision: ClipPrecision,
}

impl ClipModel {
    /// Loads a `transformers` `CLIPModel` safetensors file (the layout of
    /// `openai/clip-vit-base-patch32` and `openai/clip-vit-large-patch14`) in f32.
    pub fn load(config: &ClipConfig, weights: &Path, device: &Device) -> Result<Self> {
        Self::load_with_precision(config, weights, device, ClipPrecision::F32)
    }

    /// [`ClipModel::load`], running in `precision`.
    pub fn load_with_precision(
        config: &ClipConfig,
        weights: &Path,
        device: &Device,
        precision: ClipPrecision,
    ) -> Result<Self> {
        Self::from_tensors_with_precision(
            config,
            &NamedTensors::load_safetensors(weights, device)?,
            device,
            precision,
        )
    }

    /// Builds the model in f32 from tensors named as in a `transformers` `CLIPModel` checkpoint.
    pub fn from_tensors(config: &ClipConfig, w: &NamedTensors, device: &Device) -> Result<Self> {
        Self::from_tensors_with_precision(config, w, device, ClipPrecision::F32)
    }

    /// [`ClipModel::from_tensors`], running in `precision`.
    pub fn from_tensors_with_precision(
        config: &ClipConfig,
        w: &NamedTensors,
        device: &Device,
        precision: ClipPrecision,
    ) -> Result<Self> {
        config.validate()?;
        let precision = match precision {
            // Timed on a batch of the paper's 64 patches and the whole view.
            ClipPrecision::Auto => {
                let images = PatchSettings::default().num_patches + 1;
                choose_clip(device, ClipProducts::of(&config.vision, images))?.clip()
            }
            other => other,
        };
        let text = TextTower::load(w, &config.text, precision)?;
        let text_projection = load_linear(
            w,
            "text_projection",
            config.projection_dim,
            config.text.hidden_size,
            false,
            precision,
        )?;
        Ok(Self {
            vision: VisionTower::load(w, &config.vision, precision)?,
            visual_projection: load_linear(
                w,
                "visual_projection",
                config.projection_dim,
                config.vision.hidden_size,
                false,
                precision,
            )?,
            text: Some((text, text_projection)),
            config: config.clone(),
            device: device.clone(),
            precision,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &ClipConfig {
        &self.config
    }

    /// The format the model runs in (what `auto` chose, when it was asked for).
    pub fn precision(&self) -> ClipPrecision {
        self.precision
    }

    /// The device the weights live on.
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// Side of the square vision input in pixels (224 for the OpenAI models).
    pub fn image_size(&self) -> usize {
        self.config.vision.image_size
    }

    /// Frees the text tower (once the style direction is computed, training needs no text).
    pub fn drop_text_tower(&mut self) {
        self.text = None;
    }

    /// Projected, unnormalized f32 embeddings `[n, projection_dim]` of CLIP-normalized pixels
    /// `[n, 3, image_size, image_size]` (converted to the model's precision on the way in).
    pub fn encode_pixels(&self, pixels: &Tensor) -> Result<Tensor> {
        let pooled = self.vision.forward(pixels)?;
        Ok(self
            .visual_projection
            .forward(&pooled)?
            .to_dtype(DType::F32)?)
    }

    /// L2-normalized embeddings `[n, projection_dim]` of images `[n, 3, h, w]` in [0, 1]
    /// (any size; see [`clip_preprocess`]). Differentiable in `images`.
    pub fn encode_images(&self, images: &Tensor) -> Result<Tensor> {
        let pixels = clip_preprocess(images, self.image_size())?;
        Ok(l2_normalize(&self.encode_pixels(&pixels)?)?)
    }

    /// Projected, unnormalized f32 text embeddings `[rows, projection_dim]` of token id rows (as
    /// the tokenizer gives them: start token, text, end token, padding).
    pub fn encode_token_ids(&self, ids: &[Vec<u32>]) -> Result<Tensor> {
        let (tower, projection) = self.text.as_ref().ok_or_else(|| StyleLossError::Input {
            name: "text".into(),
            reason: "the text tower was dropped".into(),
        })?;
        let pooled = tower.forward(ids, &self.device)?;
        Ok(projection.forward(&pooled)?.to_dtype(DType::F32)?)
    }
}
