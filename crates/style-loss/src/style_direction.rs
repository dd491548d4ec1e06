//! The style direction `s = normalize(E_style - E_source)` in CLIP space, from a style prompt or
//! a style image and a source prompt.

use candle_core::{Tensor, D};

use crate::clip::ClipModel;
use crate::error::Result;
use crate::nn::l2_normalize;
use crate::templates::format_templates;
use crate::tokenizer::ClipTokenizer;

/// The paper's default source prompt (literally this string).
pub const DEFAULT_SOURCE_PROMPT: &str = "a Photo";

/// `normalize(mean of the unnormalized text embeddings of the rows)`: `[projection_dim]`.
pub fn mean_text_embedding(clip: &ClipModel, ids: &[Vec<u32>]) -> Result<Tensor> {
    let embeddings = clip.encode_token_ids(ids)?;
    Ok(l2_normalize(&embeddings.mean(0)?)?.detach())
}

/// The text embedding of a prompt: every ImageNet template formatted with it, encoded,
/// averaged, normalized: `[projection_dim]`.
pub fn prompt_embedding(
    clip: &ClipModel,
    tokenizer: &ClipTokenizer,
    prompt: &str,
) -> Result<Tensor> {
    let ids = tokenizer.encode_all(&format_templates(prompt))?;
    mean_text_embedding(clip, &ids)
}

/// The embedding of a style image `[3, h, w]` or `[1, 3, h, w]` in [0, 1] (only the first three
/// channels are used, no augmentation): `[projection_dim]`, normalized.
pub fn image_embedding(clip: &ClipModel, image: &Tensor) -> Result<Tensor> {
    let image = match image.rank() {
        3 => image.unsqueeze(0)?,
        _ => image.clone(),
    };
    let rgb = image.narrow(1, 0, 3)?;
    Ok(clip.encode_images(&rgb)?.squeeze(0)?.detach())
}

/// A unit vector in CLIP space pointing from the source to the style.
#[derive(Clone, Debug)]
pub struct StyleDirection {
    direction: Tensor,
}

impl StyleDirection {
    /// `normalize(style - source)` of two normalized embeddings `[projection_dim]`.
    pub fn from_embeddings(style: &Tensor, source: &Tensor) -> Result<Self> {
        let direction = l2_normalize(&(style - source)?.unsqueeze(0)?)?.squeeze(0)?;
        Ok(Self {
            direction: direction.detach(),
        })
    }

    /// From a style prompt and a source prompt (see [`DEFAULT_SOURCE_PROMPT`]).
    pub fn from_text(
        clip: &ClipModel,
        tokenizer: &ClipTokenizer,
        style_prompt: &str,
        source_prompt: &str,
    ) -> Result<Self> {
        Self::from_embeddings(
            &prompt_embedding(clip, tokenizer, style_prompt)?,
            &prompt_embedding(clip, tokenizer, source_prompt)?,
        )
    }

    /// From a style image (see [`image_embedding`]) and a source prompt.
    pub fn from_image(
        clip: &ClipModel,
        tokenizer: &ClipTokenizer,
        style_image: &Tensor,
        source_prompt: &str,
    ) -> Result<Self> {
        Self::from_embeddings(
            &image_embedding(clip, style_image)?,
            &prompt_embedding(clip, tokenizer, source_prompt)?,
        )
    }

    /// The unit vector `[projection_dim]`.
    pub fn as_tensor(&self) -> &Tensor {
        &self.direction
    }

    /// `1 - cos(normalize(embeddings - reference), s)` per row of `embeddings` `[n, dim]`
    /// (normalized image embeddings; `reference` `[1, dim]` or `[dim]`): `[n]`.
    pub fn directional_loss(&self, embeddings: &Tensor, reference: &Tensor) -> Result<Tensor> {
        let d = l2_normalize(&embeddings.broadcast_sub(reference)?)?;
        let cos = d.broadcast_mul(&self.direction)?.sum(D::Minus1)?;
        Ok(cos.affine(-1.0, 1.0)?)
    }
}
