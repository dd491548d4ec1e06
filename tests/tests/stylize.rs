//! CLIPGaussian's stylization step end to end on the CPU: gs-core renders, style-loss computes
//! the four losses and dL/dimage, gs-core back-propagates and steps Adam. Tiny random CLIP and
//! VGG-19 (the style-loss fixtures) keep it to seconds.

use std::path::PathBuf;

use candle_core::{Device, Tensor};
use gs_core::adam::{Adam, AdamHyper};
use gs_core::model::{BaseModel, View};
use gs_core::raster::render;
use gs_core::sampler::ViewSampler;
use gs_core::train::CpuTrainer;
use gs_core::{Camera, GaussianSet, Image};
use gs_stylize::rates::gaussian_stylization;
use rand::{Rng, SeedableRng};
use style_loss::clip::{ClipConfig, ClipModel};
use style_loss::image_layout::hwc_to_tensor;
use style_loss::style_direction::image_embedding;
use style_loss::{
    style_rng, LossWeights, PatchSettings, StyleDirection, StyleLoss, StyleObjective,
    Vgg19Features, Vgg19Widths,
};

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../crates/style-loss/tests/fixtures")
        .join(name)
}

fn scene() -> GaussianSet {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let mut g = GaussianSet::zeros(80, 1);
    for v in &mut g.means {
        *v = rng.random_range(-0.7..0.7);
    }
    for v in &mut g.log_scales {
        *v = rng.random_range(-2.2..-1.4);
    }
    for v in &mut g.quats {
        *v = rng.random_range(-1.0..1.0);
    }
    for v in &mut g.opacity_logits {
        *v = rng.random_range(0.0..3.0);
    }
    for v in &mut g.sh_dc {
        *v = rng.random_range(-0.5..0.5);
    }
    g
}

fn views() -> Vec<View> {
    (0..4)
        .map(|k| {
            let a = k as f64 * std::f64::consts::FRAC_PI_2;
            let eye = [3.0 * a.cos(), -0.5, 3.0 * a.sin()];
            View::still(Camera::look_at(eye, [0.0; 3], [0.0, -1.0, 0.0], 0.9, 48, 48).unwrap())
        })
        .collect()
}

fn style_loss(targets: &[Image]) -> StyleLoss {
    let device = Device::Cpu;
    let config = ClipConfig::from_json_file(&fixture("tiny_clip/config.json")).unwrap();
    let clip = ClipModel::load(&config, &fixture("tiny_clip/model.safetensors"), &device).unwrap();
    let vgg = Vgg19Features::load(
        &fixture("tiny_vgg19.safetensors"),
        Vgg19Widths([4, 8, 16, 32, 32]),
        &device,
    )
    .unwrap();
    // Style: a saturated red picture; source: the first ground-truth view.
    let red = Tensor::from_slice(&[0.9f32, 0.1, 0.1], (3, 1, 1), &device)
        .unwrap()
        .broadcast_as((3, 48, 48))
        .unwrap()
        .contiguous()
        .unwrap();
    let gt = hwc_to_tensor(&targets[0].data, 48, 48, &device)
        .unwrap()
        .squeeze(0)
        .unwrap();
    let direction = StyleDirection::from_embeddings(
        &image_embedding(&clip, &red).unwrap(),
        &image_embedding(&clip, &gt).unwrap(),
    )
    .unwrap();
    let weights = LossWeights {
        directional: 5.0,
        patch: 90.0,
        content: 0.8,
        background: 0.0,
    };
    let patches = PatchSettings {
        patch_size: 32,
        num_patches: 4,
        distortion_scale: 0.5,
    };
    StyleLoss::new(clip, Some(vgg), direction, weights, patches).unwrap()
}

/// The total loss over all views with the same patches each time, so before and after compare.
fn fixed_loss(loss: &StyleLoss, model: &GaussianSet, views: &[View], targets: &[Image]) -> f64 {
    let mut rng = style_rng(99);
    views
        .iter()
        .zip(targets)
        .map(|(v, t)| {
            let gt = hwc_to_tensor(&t.data, 48, 48, &Device::Cpu).unwrap();
            let cache = loss.cache_view(&gt, None).unwrap();
            let img = render(model, &v.camera, [1.0; 3]).image;
            let x = hwc_to_tensor(&img.data, 48, 48, &Device::Cpu).unwrap();
            let patches = loss.sample_patches(&mut rng, 48, 48).unwrap();
            loss.loss_and_grad_with_patches(&x, &cache, &patches)
                .unwrap()
                .total
        })
        .sum()
}

#[test]
fn stylizing_a_scene_lowers_the_style_loss_and_keeps_the_count() {
    let base = scene();
    let views = views();
    let targets: Vec<Image> = views
        .iter()
        .map(|v| render(&base, &v.camera, [1.0; 3]).image)
        .collect();
    let loss = style_loss(&targets);
    let before = fixed_loss(&loss, &base, &views, &targets);

    let mut objective = StyleObjective::new(loss.clone(), &targets, None, 7, &Device::Cpu).unwrap();
    let model = base.clone();
    // The paper's 3D learning rates (extent about 3.3 here), feature_lr 0.01.
    let groups = gaussian_stylization(0.01)
        .optimizer_groups(&model.group_names(), 3.3)
        .unwrap();
    let adam = Adam::new(groups, &model.group_lens(), AdamHyper::default());
    let mut trainer = CpuTrainer::new(model, adam).unwrap();
    let mut sampler = ViewSampler::new(views.len(), 1);
    let mut term_names = Vec::new();
    for _ in 0..60 {
        let batch = sampler.next_batch();
        let r = trainer
            .step(&views, batch, [1.0; 3], &mut objective)
            .unwrap();
        term_names = r.value.terms.iter().map(|(n, _)| n.clone()).collect();
        let sum: f32 = r.value.terms.iter().map(|(_, v)| v).sum();
        assert!((sum - r.value.loss).abs() <= 1e-4 * r.value.loss.abs().max(1.0));
    }
    let model = trainer.into_model();

    assert_eq!(term_names, ["directional", "patch", "content"]);
    assert_eq!(
        model.len(),
        base.len(),
        "stylization never changes the count"
    );
    let after = fixed_loss(&loss, &model, &views, &targets);
    assert!(after < 0.95 * before, "style loss {before} -> {after}");
    // The style pulls towards red: the renders get redder relative to green and blue.
    let redness = |m: &GaussianSet| -> f64 {
        views
            .iter()
            .map(|v| {
                let img = render(m, &v.camera, [1.0; 3]).image;
                img.data
                    .chunks(3)
                    .map(|p| p[0] as f64 - 0.5 * (p[1] + p[2]) as f64)
                    .sum::<f64>()
            })
            .sum()
    };
    assert!(
        redness(&model) > redness(&base),
        "the renders did not move towards red"
    );

    use gs_core::train::Objective;
    let wrong = Image::filled(40, 48, [0.5; 3]);
    let e = objective.evaluate(0, &wrong).unwrap_err().to_string();
    assert!(e.contains("40x48") && e.contains("48x48"), "{e}");
    assert!(
        objective.evaluate(4, &targets[0]).is_err(),
        "view 4 does not exist"
    );
}
