//! The run configuration of a 3D stylization: a JSON file (`configs/3d.json`), edited by
//! `field=value` overrides, deserialized with unknown fields refused, then checked.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::StylizeError;

/// Everything a 3D stylization run needs. The defaults are the paper's (method.md): lambdas
/// 5 / 90 / 0.8 / 1000 (the background term only applies to datasets with masks), feature_lr
/// 0.01, 5000 steps, 64 patches of 128 x 128.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StylizeConfig {
    /// The trained 3DGS scene (INRIA PLY).
    pub ply: Option<PathBuf>,
    /// The dataset folder: NeRF-synthetic when it has `transforms_train.json`, else COLMAP.
    pub data: Option<PathBuf>,
    /// The output folder.
    pub out: Option<PathBuf>,
    /// The style as text (exactly one of `style_prompt` and `style_image`).
    pub style_prompt: Option<String>,
    /// The style as a picture (exactly one of `style_prompt` and `style_image`).
    pub style_image: Option<PathBuf>,
    /// The source prompt the style direction starts from.
    pub source_prompt: String,
    /// Optimizer steps.
    pub steps: u64,
    /// Seed of the view order and of the patch sampling.
    pub seed: u64,
    /// Resolution divisor of the dataset images (3DGS's `-r`).
    pub resolution: u32,
    /// Composite transparent pixels over white (else black) and render over it.
    pub white_background: bool,
    /// Weight of the directional CLIP loss.
    pub lambda_directional: f64,
    /// Weight of the patch CLIP loss.
    pub lambda_patch: f64,
    /// Weight of the VGG content loss (0 skips VGG).
    pub lambda_content: f64,
    /// Weight of the background loss, used only when every view has a mask.
    pub lambda_background: f64,
    /// Learning rate of the SH DC coefficients; the rest use `feature_lr / 20`.
    pub feature_lr: f64,
    /// Means learning rate at step 0, times the scene extent.
    pub means_lr_start: f64,
    /// Means learning rate at the end of its decay, times the scene extent.
    pub means_lr_end: f64,
    /// Length of the means learning-rate decay, steps.
    pub means_lr_steps: u64,
    /// Learning rate of the opacity logits.
    pub opacity_lr: f64,
    /// Learning rate of the log-scales.
    pub scales_lr: f64,
    /// Learning rate of the quaternions.
    pub rotations_lr: f64,
    /// Side of the square patches of the patch loss, pixels.
    pub patch_size: usize,
    /// Patches per step.
    pub num_patches: usize,
    /// Perspective distortion of the patches (torchvision's `distortion_scale`).
    pub distortion_scale: f64,
    /// Views rendered before and after into the preview pictures.
    pub preview_views: Vec<usize>,
    /// Save a checkpoint every this many steps (0: never).
    pub checkpoint_every: u64,
    /// CLIP's `config.json` (`transformers` layout); none: ViT-B/32.
    pub clip_config: Option<PathBuf>,
    /// CLIP weights; none: `$CLIPGAUSSIAN_CLIP_B32_WEIGHTS`, then the Hugging Face cache.
    pub clip_weights: Option<PathBuf>,
    /// CLIP's `tokenizer.json`; none: `$CLIPGAUSSIAN_CLIP_TOKENIZER`, then the cache.
    pub tokenizer: Option<PathBuf>,
    /// VGG-19 weights; none: `$CLIPGAUSSIAN_VGG19_WEIGHTS`, then the cache.
    pub vgg_weights: Option<PathBuf>,
    /// Channel widths of the VGG-19 blocks (smaller only for test models).
    pub vgg_widths: [usize; 5],
}

impl Default for StylizeConfig {
    fn default() -> Self {
        Self {
            ply: None,
            data: None,
            out: None,
            style_prompt: None,
            style_image: None,
            source_prompt: style_loss::DEFAULT_SOURCE_PROMPT.to_string(),
            steps: 5000,
            seed: 0,
            resolution: 1,
            white_background: true,
            lambda_directional: 5.0,
            lambda_patch: 90.0,
            lambda_content: 0.8,
            lambda_background: 1000.0,
            feature_lr: 0.01,
            means_lr_start: 1e-4,
            means_lr_end: 1e-6,
            means_lr_steps: 30_000,
            opacity_lr: 0.05,
            scales_lr: 0.005,
            rotations_lr: 0.001,
            patch_size: 128,
            num_patches: 64,
            distortion_scale: 0.5,
            preview_views: vec![0],
            checkpoint_every: 500,
            clip_config: None,
            clip_weights: None,
            tokenizer: None,
            vgg_weights: None,
            vgg_widths: [64, 128, 256, 512, 512],
        }
    }
}

/// One edit of the configuration: `field` set to `value`.
#[derive(Clone, Debug, PartialEq)]
pub struct Override {
    /// The field name.
    pub field: String,
    /// Its new value.
    pub value: Value,
}

impl Override {
    /// A field set to a value.
    pub fn new(field: impl Into<String>, value: impl Into<Value>) -> Self {
        Self {
            field: field.into(),
            value: value.into(),
        }
    }

    /// Parses `field=value`: the value is JSON when it parses as JSON (`5`, `null`, `[0, 2]`,
    /// `true`), else a string.
    pub fn parse(text: &str) -> Result<Self, StylizeError> {
        let Some((field, value)) = text.split_once('=') else {
            return Err(StylizeError::Config(format!(
                "override {text:?} is not of the form field=value"
            )));
        };
        let field = field.trim();
        if field.is_empty() {
            return Err(StylizeError::Config(format!(
                "override {text:?} has no field name"
            )));
        }
        let value = serde_json::from_str(value).unwrap_or_else(|_| Value::String(value.into()));
        Ok(Self::new(field, value))
    }
}

impl StylizeConfig {
    /// The configuration in `file` (the defaults when `None`) with `overrides` applied in order,
    /// then checked with [`StylizeConfig::validate`]. Unknown fields are errors naming them.
    pub fn resolve(file: Option<&Path>, overrides: &[Override]) -> Result<Self, StylizeError> {
        let mut value = match file {
            Some(path) => {
                let text = std::fs::read_to_string(path).map_err(|source| StylizeError::Io {
                    path: path.to_path_buf(),
                    source,
                })?;
                serde_json::from_str(&text)
                    .map_err(|e| StylizeError::Config(format!("{}: {e}", path.display())))?
            }
            None => serde_json::to_value(Self::default()).expect("the config serializes"),
        };
        let Value::Object(fields) = &mut value else {
            return Err(StylizeError::Config(
                "the configuration must be a JSON object".into(),
            ));
        };
        for o in overrides {
            fields.insert(o.field.clone(), o.value.clone());
        }
        let source = file.map_or("the configuration".into(), |p| p.display().to_string());
        let config: Self = serde_json::from_value(value)
            .map_err(|e| StylizeError::Config(format!("{source}: {e}")))?;
        config.validate()?;
        Ok(config)
    }

    /// Checks what deserializing cannot: required paths, exactly one style, non-empty prompts,
    /// positive counts and rates, non-negative weights.
    pub fn validate(&self) -> Result<(), StylizeError> {
        let bad = |field: &str, why: &str| Err(StylizeError::Config(format!("{field}: {why}")));
        for (field, value) in [("ply", &self.ply), ("data", &self.data), ("out", &self.out)] {
            if value.is_none() {
                return bad(field, "is required");
            }
        }
        match (&self.style_prompt, &self.style_image) {
            (Some(_), Some(_)) => {
                return bad(
                    "style_prompt, style_image",
                    "give exactly one style (a prompt or an image), not both",
                )
            }
            (None, None) => {
                return bad(
                    "style_prompt, style_image",
                    "a style is required: a prompt or an image",
                )
            }
            (Some(p), None) if p.trim().is_empty() => {
                return bad("style_prompt", "the style prompt is empty")
            }
            _ => {}
        }
        if self.source_prompt.trim().is_empty() {
            return bad("source_prompt", "the source prompt is empty");
        }
        if self.steps == 0 {
            return bad("steps", "must be at least 1");
        }
        if self.resolution == 0 {
            return bad(
                "resolution",
                "must be at least 1 (1 keeps the images as they are)",
            );
        }
        let weights = [
            ("lambda_directional", self.lambda_directional),
            ("lambda_patch", self.lambda_patch),
            ("lambda_content", self.lambda_content),
            ("lambda_background", self.lambda_background),
        ];
        for (field, w) in weights {
            if !(w.is_finite() && w >= 0.0) {
                return bad(field, &format!("{w} must be finite and >= 0"));
            }
        }
        let rates = [
            ("feature_lr", self.feature_lr),
            ("means_lr_start", self.means_lr_start),
            ("means_lr_end", self.means_lr_end),
            ("opacity_lr", self.opacity_lr),
            ("scales_lr", self.scales_lr),
            ("rotations_lr", self.rotations_lr),
        ];
        for (field, lr) in rates {
            if !(lr.is_finite() && lr > 0.0) {
                return bad(field, &format!("{lr} must be finite and > 0"));
            }
        }
        if self.lambda_patch > 0.0 && (self.patch_size == 0 || self.num_patches == 0) {
            return bad(
                "patch_size, num_patches",
                "a patch loss needs a patch size and a number of patches above 0",
            );
        }
        if !(0.0..=1.0).contains(&self.distortion_scale) {
            return bad("distortion_scale", "must be in [0, 1]");
        }
        Ok(())
    }

    /// The required `ply` path ([`StylizeConfig::validate`] checked it is set).
    pub fn ply_path(&self) -> &Path {
        self.ply.as_deref().expect("validated: ply is set")
    }

    /// The required `data` path.
    pub fn data_path(&self) -> &Path {
        self.data.as_deref().expect("validated: data is set")
    }

    /// The required `out` path.
    pub fn out_path(&self) -> &Path {
        self.out.as_deref().expect("validated: out is set")
    }
}
