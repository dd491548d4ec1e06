//! The views' cached ground truth held in memory up to a budget and on disk past it: the
//! losses and gradients are the same bit for bit whatever the budget, only the views within it
//! stay in memory, and the spill folder goes with the objective.

mod common;

use candle_core::Device;
use gs_core::train::Objective;
use gs_core::Image;
use style_loss::{
    CacheBudget, LossWeights, PatchSettings, StyleDirection, StyleLoss, StyleObjective,
};

/// The tiny models with every term on (the background term needs the masks).
fn loss() -> StyleLoss {
    let (clip, vgg) = common::tiny_models(style_loss::ClipPrecision::F32);
    let dim = clip.config().projection_dim;
    let style = candle_core::Tensor::ones(dim, candle_core::DType::F32, &Device::Cpu).unwrap();
    let direction = StyleDirection::from_embeddings(&style, &style.zeros_like().unwrap()).unwrap();
    let weights = LossWeights {
        background: 10.0,
        ..LossWeights::default()
    };
    let patches = PatchSettings {
        patch_size: 16,
        num_patches: 2,
        distortion_scale: 0.5,
    };
    StyleLoss::new(clip, Some(vgg), direction, weights, patches).unwrap()
}

/// `n` pictures of 40x32 (each its own pattern) and their masks.
fn views(n: usize) -> (Vec<Image>, Vec<Vec<f32>>) {
    let (w, h) = (40u32, 32u32);
    let pictures = (0..n)
        .map(|v| Image {
            width: w,
            height: h,
            data: (0..3 * (w * h) as usize)
                .map(|i| ((i * 31 + v * 97) % 255) as f32 / 255.0)
                .collect(),
        })
        .collect();
    let masks = (0..n)
        .map(|v| {
            (0..(w * h) as usize)
                .map(|i| f32::from(u8::from((i + v) % 7 == 0)))
                .collect()
        })
        .collect();
    (pictures, masks)
}

/// Every view's loss and gradient through `budget`, twice round.
fn run(budget: &CacheBudget, n: usize) -> (Vec<(f32, Vec<f32>)>, usize) {
    let (pictures, masks) = views(n);
    let mut objective = StyleObjective::with_progress(
        loss(),
        &pictures,
        Some(&masks),
        7,
        &Device::Cpu,
        budget,
        &mut |_, _| {},
    )
    .unwrap();
    let resident = objective.resident_views();
    let mut out = Vec::new();
    for round in 0..2 {
        for (v, picture) in pictures.iter().enumerate() {
            let mut render = picture.clone();
            for x in render.data.iter_mut() {
                *x = (*x * 0.7 + 0.1 * round as f32).min(1.0);
            }
            let value = objective.evaluate(v, &render).unwrap();
            out.push((value.loss, value.grad));
        }
    }
    (out, resident)
}

#[test]
fn spilled_caches_give_the_same_losses_and_memory_holds_only_the_budget() {
    let n = 5;
    let (in_memory, resident) = run(&CacheBudget::unbounded(), n);
    assert_eq!(resident, n);
    let dir = tempfile::tempdir().unwrap();
    let spill = dir.path().join("view_cache");
    let (pictures, masks) = views(1);
    let one = loss()
        .cache_view(
            &style_loss::image_layout::hwc_to_tensor(&pictures[0].data, 32, 40, &Device::Cpu)
                .unwrap(),
            Some(&candle_core::Tensor::from_slice(&masks[0], (32, 40), &Device::Cpu).unwrap()),
        )
        .unwrap()
        .bytes();
    for (budget, want_resident) in [(0, 0), (2 * one + one / 2, 2), (u64::MAX, n)] {
        let cache = CacheBudget {
            resident_bytes: budget,
            spill: Some(spill.clone()),
        };
        let (values, resident) = run(&cache, n);
        assert_eq!(resident, want_resident, "budget {budget}");
        assert_eq!(
            values, in_memory,
            "budget {budget}: the same values bit for bit"
        );
        assert!(
            !spill.exists(),
            "budget {budget}: the spill folder goes with the objective"
        );
    }
    // While the objective lives, the views past the budget are files.
    let (pictures, masks) = views(n);
    let objective = StyleObjective::with_progress(
        loss(),
        &pictures,
        Some(&masks),
        7,
        &Device::Cpu,
        &CacheBudget {
            resident_bytes: one,
            spill: Some(spill.clone()),
        },
        &mut |_, _| {},
    )
    .unwrap();
    assert_eq!(objective.resident_views(), 1);
    assert_eq!(std::fs::read_dir(&spill).unwrap().count(), n - 1);
    drop(objective);
    assert!(!spill.exists());
}
