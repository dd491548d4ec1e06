//! Helpers shared by the fixture tests: loading the PyTorch references and comparing.

// Each test crate compiles this module and uses only some helpers.
#![allow(dead_code)]

use std::collections::HashMap;
use std::path::PathBuf;

use candle_core::{Device, Tensor};

/// Path of a file under `tests/fixtures`.
pub fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests")
        .join("fixtures")
        .join(name)
}

/// All tensors of a fixture safetensors file, on the CPU.
pub fn load(name: &str) -> HashMap<String, Tensor> {
    candle_core::safetensors::load(fixture(name), &Device::Cpu)
        .unwrap_or_else(|e| panic!("cannot load fixture {name}: {e}"))
}

/// A parsed JSON fixture.
pub fn load_json(name: &str) -> serde_json::Value {
    let text = std::fs::read_to_string(fixture(name))
        .unwrap_or_else(|e| panic!("cannot read fixture {name}: {e}"));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("cannot parse fixture {name}: {e}"))
}

/// Flattened f64 values of a tensor.
pub fn values(t: &Tensor) -> Vec<f64> {
    t.flatten_all()
        .and_then(|t| t.to_dtype(candle_core::DType::F64))
        .and_then(|t| t.to_vec1::<f64>())
        .expect("tensor to vec")
}

/// `||a - b|| / ||b||` over all elements; panics on a shape mismatch.
pub fn relative_error(a: &Tensor, b: &Tensor) -> f64 {
    assert_eq!(a.dims(), b.dims(), "shape mismatch");
    let (a, b) = (values(a), values(b));
    let diff: f64 = a.iter().zip(&b).map(|(x, y)| (x - y) * (x - y)).sum();
    let norm: f64 = b.iter().map(|y| y * y).sum();
    assert!(norm > 0.0, "reference is all zeros");
    (diff / norm).sqrt()
}

/// Largest absolute difference; panics on a shape mismatch.
pub fn max_abs_diff(a: &Tensor, b: &Tensor) -> f64 {
    assert_eq!(a.dims(), b.dims(), "shape mismatch");
    values(a)
        .iter()
        .zip(values(b))
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// Cosine similarity of two flattened tensors.
pub fn cosine(a: &Tensor, b: &Tensor) -> f64 {
    let (a, b) = (values(a), values(b));
    assert_eq!(a.len(), b.len());
    let dot: f64 = a.iter().zip(&b).map(|(x, y)| x * y).sum();
    let na: f64 = a.iter().map(|x| x * x).sum::<f64>().sqrt();
    let nb: f64 = b.iter().map(|x| x * x).sum::<f64>().sqrt();
    dot / (na * nb)
}

/// Rows of an int64 `[rows, len]` tensor as token ids.
pub fn id_rows(t: &Tensor) -> Vec<Vec<u32>> {
    t.to_vec2::<i64>()
        .expect("int64 ids")
        .into_iter()
        .map(|row| row.into_iter().map(|v| v as u32).collect())
        .collect()
}

/// The tiny CLIP (in `precision`) and the tiny VGG-19 as torchvision initialises it (f32), from
/// the fixtures.
pub fn tiny_models(
    precision: style_loss::ClipPrecision,
) -> (style_loss::clip::ClipModel, style_loss::Vgg19Features) {
    tiny_models_in(precision, style_loss::VggPrecision::F32)
}

/// [`tiny_models`] with VGG's products in `vgg_precision`.
pub fn tiny_models_in(
    precision: style_loss::ClipPrecision,
    vgg_precision: style_loss::VggPrecision,
) -> (style_loss::clip::ClipModel, style_loss::Vgg19Features) {
    let config =
        style_loss::clip::ClipConfig::from_json_file(&fixture("tiny_clip/config.json")).unwrap();
    let clip = style_loss::clip::ClipModel::load_with_precision(
        &config,
        &fixture("tiny_clip/model.safetensors"),
        &Device::Cpu,
        precision,
    )
    .unwrap();
    let vgg = style_loss::Vgg19Features::load_with_precision(
        &fixture("tiny_vgg19_torchvision_init.safetensors"),
        style_loss::Vgg19Widths([4, 8, 16, 32, 32]),
        &Device::Cpu,
        vgg_precision,
    )
    .unwrap();
    (clip, vgg)
}
