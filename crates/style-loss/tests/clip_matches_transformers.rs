//! The CLIP towers against `transformers.CLIPModel` (tiny config, random weights).

mod common;

use candle_core::{Device, Tensor, Var};
use common::{cosine, fixture, id_rows, load, relative_error};
use style_loss::clip::{ClipConfig, ClipModel};
use style_loss::nn::l2_normalize;
use style_loss::style_direction::{image_embedding, mean_text_embedding, prompt_embedding};
use style_loss::templates::format_templates;
use style_loss::{ClipTokenizer, NamedTensors, StyleDirection, DEFAULT_SOURCE_PROMPT};

fn tiny_clip() -> ClipModel {
    let config = ClipConfig::from_json_file(&fixture("tiny_clip/config.json")).unwrap();
    ClipModel::load(
        &config,
        &fixture("tiny_clip/model.safetensors"),
        &Device::Cpu,
    )
    .unwrap()
}

fn assert_rows_cosine(ours: &Tensor, reference: &Tensor) {
    assert_eq!(ours.dims(), reference.dims());
    for row in 0..ours.dim(0).unwrap() {
        let c = cosine(&ours.get(row).unwrap(), &reference.get(row).unwrap());
        assert!(c > 0.99999, "row {row}: cosine {c}");
    }
}

#[test]
fn config_is_read_from_hugging_face_json() {
    let config = ClipConfig::from_json_file(&fixture("tiny_clip/config.json")).unwrap();
    assert_eq!(config.projection_dim, 16);
    assert_eq!(config.vision.hidden_size, 24);
    assert_eq!(config.vision.image_size, 64);
    assert_eq!(config.vision.patch_size, 16);
    assert_eq!(config.text.vocab_size, 1000);
    assert_eq!(config.text.eos_token_id, 999);
}

#[test]
fn presets_are_valid() {
    let b32 = ClipConfig::vit_b_32();
    let l14 = ClipConfig::vit_l_14();
    b32.validate().unwrap();
    l14.validate().unwrap();
    assert_eq!((b32.vision.grid_size(), b32.projection_dim), (7, 512));
    assert_eq!((l14.vision.grid_size(), l14.projection_dim), (16, 768));
    let mut bad = ClipConfig::vit_b_32();
    bad.vision.image_size = 230;
    let err = bad.validate().unwrap_err().to_string();
    assert!(
        err.contains("vision_config.image_size") && err.contains("230"),
        "{err}"
    );
}

#[test]
fn image_embeddings_match() {
    let model = tiny_clip();
    let r = load("clip_reference.safetensors");
    let ours = l2_normalize(&model.encode_pixels(&r["pixel_values"]).unwrap()).unwrap();
    assert_rows_cosine(&ours, &r["image_embeds"]);
}

#[test]
fn text_embeddings_match() {
    let model = tiny_clip();
    let r = load("clip_reference.safetensors");
    let ours = model.encode_token_ids(&id_rows(&r["input_ids"])).unwrap();
    assert_rows_cosine(&l2_normalize(&ours).unwrap(), &r["text_embeds"]);
}

#[test]
fn legacy_eos_id_pools_at_the_largest_id() {
    // Old OpenAI configs say eos_token_id = 2; transformers then pools at argmax(ids), which is
    // the end token here too.
    let mut config = ClipConfig::from_json_file(&fixture("tiny_clip/config.json")).unwrap();
    config.text.eos_token_id = 2;
    let model = ClipModel::load(
        &config,
        &fixture("tiny_clip/model.safetensors"),
        &Device::Cpu,
    )
    .unwrap();
    let r = load("clip_reference.safetensors");
    let ours = model.encode_token_ids(&id_rows(&r["input_ids"])).unwrap();
    assert_rows_cosine(&l2_normalize(&ours).unwrap(), &r["text_embeds"]);
}

#[test]
fn template_mean_and_style_direction_match() {
    let model = tiny_clip();
    let r = load("clip_reference.safetensors");
    let style = mean_text_embedding(&model, &id_rows(&r["style_ids"])).unwrap();
    let source = mean_text_embedding(&model, &id_rows(&r["source_ids"])).unwrap();
    assert!(cosine(&style, &r["style_embed"]) > 0.99999);
    assert!(cosine(&source, &r["source_embed"]) > 0.99999);
    let direction = StyleDirection::from_embeddings(&style, &source).unwrap();
    assert!(cosine(direction.as_tensor(), &r["style_direction"]) > 0.99999);
}

#[test]
fn directional_loss_gradient_matches_autograd() {
    let model = tiny_clip();
    let r = load("clip_reference.safetensors");
    let style = mean_text_embedding(&model, &id_rows(&r["style_ids"])).unwrap();
    let source = mean_text_embedding(&model, &id_rows(&r["source_ids"])).unwrap();
    let direction = StyleDirection::from_embeddings(&style, &source).unwrap();
    let render = Var::from_tensor(&r["render"]).unwrap();
    let gt_embed = model.encode_images(&r["gt"]).unwrap();
    assert_rows_cosine(&gt_embed, &r["gt_embed"]);
    let embed = model.encode_images(render.as_tensor()).unwrap();
    let loss = direction
        .directional_loss(&embed, &gt_embed)
        .unwrap()
        .mean_all()
        .unwrap();
    let expected = r["directional_loss"].to_vec1::<f32>().unwrap()[0];
    let value = loss.to_scalar::<f32>().unwrap();
    assert!((value - expected).abs() < 1e-5, "{value} vs {expected}");
    let grads = loss.backward().unwrap();
    let grad = grads
        .get(render.as_tensor())
        .expect("gradient reaches the image");
    let err = relative_error(grad, &r["directional_grad"]);
    assert!(err < 1e-3, "relative error {err}");
}

#[test]
fn style_image_embedding_uses_the_first_three_channels() {
    let model = tiny_clip();
    let r = load("clip_reference.safetensors");
    let gt = r["gt"].squeeze(0).unwrap();
    let alpha = Tensor::ones((1, 40, 56), candle_core::DType::F32, &Device::Cpu).unwrap();
    let rgba = Tensor::cat(&[&gt, &alpha], 0).unwrap();
    let embedding = image_embedding(&model, &rgba).unwrap();
    assert!(cosine(&embedding, &r["gt_embed"]) > 0.99999);
}

#[test]
fn text_style_pipeline_runs_from_prompts() {
    // A tiny text tower over CLIP's real vocabulary size, random weights: checks that prompts
    // go through the tokenizer, the 79 templates and the tower to a unit direction.
    let mut config = ClipConfig::from_json_file(&fixture("tiny_clip/config.json")).unwrap();
    config.text.vocab_size = 49408;
    config.text.eos_token_id = 49407;
    let model = ClipModel::from_tensors(&config, &NamedTensors::random(&Device::Cpu), &Device::Cpu)
        .unwrap();
    let tokenizer = ClipTokenizer::from_file(&fixture("tokenizer/tokenizer.json")).unwrap();
    let fire = prompt_embedding(&model, &tokenizer, "fire").unwrap();
    let ids = tokenizer.encode_all(&format_templates("fire")).unwrap();
    assert_eq!(ids.len(), 79);
    let by_hand = mean_text_embedding(&model, &ids).unwrap();
    assert!(cosine(&fire, &by_hand) > 0.999999);
    let direction =
        StyleDirection::from_text(&model, &tokenizer, "fire", DEFAULT_SOURCE_PROMPT).unwrap();
    let source = prompt_embedding(&model, &tokenizer, "a Photo").unwrap();
    let expected = StyleDirection::from_embeddings(&fire, &source).unwrap();
    assert!(cosine(direction.as_tensor(), expected.as_tensor()) > 0.999999);
    let norm = direction
        .as_tensor()
        .sqr()
        .unwrap()
        .sum_all()
        .unwrap()
        .to_scalar::<f32>()
        .unwrap();
    assert!((norm - 1.0).abs() < 1e-5, "direction norm^2 {norm}");
}

#[test]
fn text_tower_can_be_dropped() {
    let mut model = tiny_clip();
    model.drop_text_tower();
    assert!(model.encode_token_ids(&[vec![998, 999]]).is_err());
}

#[test]
fn wrong_config_names_file_and_tensor() {
    let config = ClipConfig::vit_b_32();
    let err = ClipModel::load(
        &config,
        &fixture("tiny_clip/model.safetensors"),
        &Device::Cpu,
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("model.safetensors") && err.contains("text_model."),
        "{err}"
    );
}

/// The towers as a CUDA or Metal device composes them (no fused CPU kernel), on the CPU: image
/// and text embeddings and the template mean (the text style), against transformers.
#[test]
fn generic_path_towers_match_transformers() {
    let _generic = style_loss::GenericPath::on();
    let model = tiny_clip();
    let r = load("clip_reference.safetensors");
    let image = l2_normalize(&model.encode_pixels(&r["pixel_values"]).unwrap()).unwrap();
    assert_rows_cosine(&image, &r["image_embeds"]);
    let text = model.encode_token_ids(&id_rows(&r["input_ids"])).unwrap();
    assert_rows_cosine(&l2_normalize(&text).unwrap(), &r["text_embeds"]);
    let style = mean_text_embedding(&model, &id_rows(&r["style_ids"])).unwrap();
    let source = mean_text_embedding(&model, &id_rows(&r["source_ids"])).unwrap();
    let direction = StyleDirection::from_embeddings(&style, &source).unwrap();
    assert!(cosine(direction.as_tensor(), &r["style_direction"]) > 0.99999);
}
