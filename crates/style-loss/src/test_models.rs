//! Random-weight models for the tests and benchmarks of crates that stylize (feature
//! `test-models`):
//! - [`write_tiny_models`]: the committed tiny CLIP and VGG-19 fixtures of this crate, with
//!   CLIP's token embedding widened to the real 49,408-token vocabulary so the committed
//!   tokenizer can drive it;
//! - [`random_full_size_loss`]: a style loss with ViT-B/32- and VGG-19-sized random weights,
//!   which costs what the real one costs.
//!
//! Nothing here is downloaded; the weights are random, so only the mechanics and the cost of
//! a run can be measured with them, not the look of a style.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use candle_core::{Device, Tensor};

use crate::vgg::Vgg19Widths;
use crate::{
    ClipConfig, ClipModel, ClipPrecision, LossWeights, NamedTensors, PatchSettings, StyleDirection,
    StyleLoss, Vgg19Features,
};

/// Token count of CLIP's real vocabulary (and of the committed tokenizer).
const VOCAB: usize = 49408;

/// Width of the tiny CLIP's text tower.
const TEXT_WIDTH: usize = 32;

/// The files of the tiny models, for a run's configuration.
#[derive(Clone, Debug, PartialEq)]
pub struct TinyModelFiles {
    /// CLIP `config.json`.
    pub clip_config: PathBuf,
    /// CLIP weights (safetensors).
    pub clip_weights: PathBuf,
    /// CLIP `tokenizer.json`.
    pub tokenizer: PathBuf,
    /// VGG-19 weights (safetensors, torchvision layout).
    pub vgg_weights: PathBuf,
    /// Channel widths of the tiny VGG-19.
    pub vgg_widths: Vgg19Widths,
}

/// A committed fixture of this crate.
fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

/// Writes the tiny CLIP into `dir` (`clip.safetensors`, `clip_config.json`) and returns it
/// with the committed tokenizer and tiny VGG-19.
///
/// # Panics
/// If the fixtures cannot be read or `dir` cannot be written (a broken test setup).
pub fn write_tiny_models(dir: &Path) -> TinyModelFiles {
    let device = Device::Cpu;
    let mut tensors: HashMap<String, Tensor> =
        candle_core::safetensors::load(fixture("tiny_clip/model.safetensors"), &device)
            .expect("read the tiny CLIP fixture");
    // A fixed pseudo-random embedding in [-0.05, 0.05) (Knuth's multiplicative hash).
    let values: Vec<f32> = (0..VOCAB * TEXT_WIDTH)
        .map(|i| ((i as u64).wrapping_mul(2_654_435_761) % 10_000) as f32 / 100_000.0 - 0.05)
        .collect();
    tensors.insert(
        "text_model.embeddings.token_embedding.weight".into(),
        Tensor::from_vec(values, (VOCAB, TEXT_WIDTH), &device).expect("embedding tensor"),
    );
    let clip_weights = dir.join("clip.safetensors");
    candle_core::safetensors::save(&tensors, &clip_weights).expect("write the tiny CLIP");
    let text = std::fs::read_to_string(fixture("tiny_clip/config.json"))
        .expect("read the tiny CLIP config");
    let mut config: serde_json::Value = serde_json::from_str(&text).expect("tiny CLIP config");
    config["text_config"]["vocab_size"] = VOCAB.into();
    config["text_config"]["eos_token_id"] = (VOCAB - 1).into();
    let clip_config = dir.join("clip_config.json");
    std::fs::write(&clip_config, config.to_string()).expect("write the tiny CLIP config");
    TinyModelFiles {
        clip_config,
        clip_weights,
        tokenizer: fixture("tokenizer/tokenizer.json"),
        vgg_weights: fixture("tiny_vgg19.safetensors"),
        vgg_widths: Vgg19Widths([4, 8, 16, 32, 32]),
    }
}

/// A style loss with the paper's weights, `patches`, and ViT-B/32- and VGG-19-sized random
/// weights (a random style direction, CLIP in `precision`), for timing a stylization step
/// without real weights.
pub fn random_full_size_loss(
    patches: PatchSettings,
    precision: ClipPrecision,
    device: &Device,
) -> crate::Result<StyleLoss> {
    let clip = ClipModel::from_tensors_with_precision(
        &ClipConfig::vit_b_32(),
        &NamedTensors::random(device),
        device,
        precision,
    )?;
    let vgg = Vgg19Features::from_tensors(&NamedTensors::random(device), Vgg19Widths::default())?;
    let style = Tensor::rand(-1f32, 1f32, clip.config().projection_dim, device)?;
    let direction = StyleDirection::from_embeddings(&style, &style.zeros_like()?)?;
    StyleLoss::new(clip, Some(vgg), direction, LossWeights::default(), patches)
}
