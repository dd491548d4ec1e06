//! CLIP model configuration, read from a Hugging Face `config.json` or taken from a preset.

use std::path::Path;

use serde::Deserialize;

use crate::error::{Result, StyleLossError};
use crate::nn::Activation;

/// The text tower's configuration (`text_config` of a Hugging Face `CLIPConfig`). Missing
/// fields take the Hugging Face defaults, which are ViT-B/32's.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default)]
pub struct ClipTextConfig {
    /// Number of token embeddings.
    pub vocab_size: usize,
    /// Width of the transformer.
    pub hidden_size: usize,
    /// Width of the MLP.
    pub intermediate_size: usize,
    /// Number of transformer layers.
    pub num_hidden_layers: usize,
    /// Number of attention heads.
    pub num_attention_heads: usize,
    /// Context length (77 for CLIP).
    pub max_position_embeddings: usize,
    /// MLP activation.
    pub hidden_act: Activation,
    /// Layer norm epsilon.
    pub layer_norm_eps: f64,
    /// End-of-text token id. The legacy value 2 (old OpenAI configs) means "pool at the largest
    /// id", as transformers does; otherwise pooling is at the first occurrence of this id.
    pub eos_token_id: u32,
}

impl Default for ClipTextConfig {
    fn default() -> Self {
        Self {
            vocab_size: 49408,
            hidden_size: 512,
            intermediate_size: 2048,
            num_hidden_layers: 12,
            num_attention_heads: 8,
            max_position_embeddings: 77,
            hidden_act: Activation::QuickGelu,
            layer_norm_eps: 1e-5,
            eos_token_id: 49407,
        }
    }
}

/// The vision tower's configuration (`vision_config` of a Hugging Face `CLIPConfig`). Missing
/// fields take the Hugging Face defaults, which are ViT-B/32's.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default)]
pub struct ClipVisionConfig {
    /// Width of the transformer.
    pub hidden_size: usize,
    /// Width of the MLP.
    pub intermediate_size: usize,
    /// Number of transformer layers.
    pub num_hidden_layers: usize,
    /// Number of attention heads.
    pub num_attention_heads: usize,
    /// Input channels (3).
    pub num_channels: usize,
    /// Input side in pixels; images are resized to `image_size x image_size`.
    pub image_size: usize,
    /// Patch side in pixels.
    pub patch_size: usize,
    /// MLP activation.
    pub hidden_act: Activation,
    /// Layer norm epsilon.
    pub layer_norm_eps: f64,
}

impl Default for ClipVisionConfig {
    fn default() -> Self {
        Self {
            hidden_size: 768,
            intermediate_size: 3072,
            num_hidden_layers: 12,
            num_attention_heads: 12,
            num_channels: 3,
            image_size: 224,
            patch_size: 32,
            hidden_act: Activation::QuickGelu,
            layer_norm_eps: 1e-5,
        }
    }
}

impl ClipVisionConfig {
    /// Patches per image side.
    pub fn grid_size(&self) -> usize {
        self.image_size / self.patch_size
    }
}

/// A whole CLIP model: both towers and the shared embedding width.
#[derive(Clone, Debug, PartialEq)]
pub struct ClipConfig {
    /// Width of the joint embedding space (512 for ViT-B/32, 768 for ViT-L/14).
    pub projection_dim: usize,
    /// The text tower.
    pub text: ClipTextConfig,
    /// The vision tower.
    pub vision: ClipVisionConfig,
}

impl ClipConfig {
    /// OpenAI CLIP ViT-B/32 (`openai/clip-vit-base-patch32`), used for training.
    pub fn vit_b_32() -> Self {
        Self {
            projection_dim: 512,
            text: ClipTextConfig::default(),
            vision: ClipVisionConfig::default(),
        }
    }

    /// OpenAI CLIP ViT-L/14 (`openai/clip-vit-large-patch14`), used for evaluation.
    pub fn vit_l_14() -> Self {
        Self {
            projection_dim: 768,
            text: ClipTextConfig {
                hidden_size: 768,
                intermediate_size: 3072,
                num_attention_heads: 12,
                ..ClipTextConfig::default()
            },
            vision: ClipVisionConfig {
                hidden_size: 1024,
                intermediate_size: 4096,
                num_hidden_layers: 24,
                num_attention_heads: 16,
                patch_size: 14,
                ..ClipVisionConfig::default()
            },
        }
    }

    /// Reads a Hugging Face `config.json` of a `CLIPModel` (`text_config` / `vision_config`, or
    /// the older `text_config_dict` / `vision_config_dict`) and validates it.
    pub fn from_json_file(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|source| StyleLossError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_json_str(&text).map_err(|e| match e {
            StyleLossError::Parse { message, .. } => StyleLossError::Parse {
                path: path.to_path_buf(),
                message,
            },
            other => other,
        })
    }

    /// Parses the text of a Hugging Face `config.json` (see [`Self::from_json_file`]).
    pub fn from_json_str(json: &str) -> Result<Self> {
        let parse_error = |message: String| StyleLossError::Parse {
            path: "<config.json>".into(),
            message,
        };
        let root: serde_json::Value =
            serde_json::from_str(json).map_err(|e| parse_error(e.to_string()))?;
        let section = |names: [&str; 2]| -> serde_json::Value {
            names
                .iter()
                .find_map(|n| root.get(*n).filter(|v| v.is_object()).cloned())
                .unwrap_or_else(|| serde_json::Value::Object(Default::default()))
        };
        let text: ClipTextConfig =
            serde_json::from_value(section(["text_config", "text_config_dict"]))
                .map_err(|e| parse_error(format!("text_config: {e}")))?;
        let vision: ClipVisionConfig =
            serde_json::from_value(section(["vision_config", "vision_config_dict"]))
                .map_err(|e| parse_error(format!("vision_config: {e}")))?;
        let projection_dim = match root.get("projection_dim") {
            None | Some(serde_json::Value::Null) => 512,
            Some(v) => v
                .as_u64()
                .ok_or_else(|| parse_error(format!("projection_dim: not an integer: {v}")))?
                as usize,
        };
        let config = Self {
            projection_dim,
            text,
            vision,
        };
        config.validate()?;
        Ok(config)
    }

    /// Checks the divisibility and positivity constraints the towers rely on.
    pub fn validate(&self) -> Result<()> {
        let bad = |field: &str, value: usize, reason: &str| StyleLossError::Config {
            field: field.to_string(),
            value: value.to_string(),
            reason: reason.to_string(),
        };
        let v = &self.vision;
        let t = &self.text;
        if v.patch_size == 0 || !v.image_size.is_multiple_of(v.patch_size) {
            return Err(bad(
                "vision_config.image_size",
                v.image_size,
                &format!("must be a positive multiple of patch_size {}", v.patch_size),
            ));
        }
        if v.num_attention_heads == 0 || !v.hidden_size.is_multiple_of(v.num_attention_heads) {
            return Err(bad(
                "vision_config.hidden_size",
                v.hidden_size,
                &format!(
                    "must be divisible by num_attention_heads {}",
                    v.num_attention_heads
                ),
            ));
        }
        if t.num_attention_heads == 0 || !t.hidden_size.is_multiple_of(t.num_attention_heads) {
            return Err(bad(
                "text_config.hidden_size",
                t.hidden_size,
                &format!(
                    "must be divisible by num_attention_heads {}",
                    t.num_attention_heads
                ),
            ));
        }
        if v.num_channels != 3 {
            return Err(bad(
                "vision_config.num_channels",
                v.num_channels,
                "must be 3 (RGB)",
            ));
        }
        if self.projection_dim == 0 {
            return Err(bad("projection_dim", 0, "must be positive"));
        }
        if t.max_position_embeddings == 0 {
            return Err(bad(
                "text_config.max_position_embeddings",
                0,
                "must be positive",
            ));
        }
        Ok(())
    }
}
