//! Times one full stylization loss and its image gradient at paper settings, split by term:
//! ViT-B/32-sized CLIP and full VGG-19 with random weights, one 800x800 render, 64 patches of
//! 128, VGG at 800x800.
//!
//! Run: `cargo run -p style-loss --example style_loss_timing [-- <repeats> [<term>]]`, where
//! `<term>` (directional, patch, content, background, all) times that one only (the dev profile
//! builds candle at opt-level 3, where the time is spent; `--release` also works). Add
//! `--features cuda` or `--features metal` and set `STYLE_LOSS_DEVICE=cuda|metal` to time a GPU,
//! `STYLE_LOSS_PRECISION=f16|bf16|auto` for CLIP in reduced precision, and
//! `STYLE_LOSS_VGG_PRECISION=bf16|auto` for VGG's backward in bf16. `STYLE_LOSS_SIZE=384` and
//! `STYLE_LOSS_PATCHES=8` time other sizes (the main job's: `configs/2d-preview.json`).

use std::time::Instant;

use candle_core::{Device, Tensor};
use style_loss::auto_precision::{choose_clip, choose_vgg, ClipProducts};
use style_loss::{
    background_mask_from_color, style_rng, ClipConfig, ClipModel, ClipPrecision, LossWeights,
    NamedTensors, PatchSettings, StyleDirection, StyleLoss, Vgg19Features, Vgg19Widths,
    VggPrecision,
};

fn device() -> candle_core::Result<Device> {
    match std::env::var("STYLE_LOSS_DEVICE").as_deref() {
        Ok("cuda") => Device::new_cuda(0),
        Ok("metal") => Device::new_metal(0),
        _ => Ok(Device::Cpu),
    }
}

fn seconds_since(start: Instant) -> f64 {
    start.elapsed().as_secs_f64()
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    style_loss::memory::keep_freed_memory();
    style_loss::cpu_threads::candle_ops_on_calling_thread();
    let repeats: usize = std::env::args().nth(1).map_or(Ok(1), |s| s.parse())?;
    let only_term = std::env::args().nth(2);
    let device = device()?;
    let side: usize = std::env::var("STYLE_LOSS_SIZE").map_or(Ok(800), |s| s.parse())?;
    let patches: usize = std::env::var("STYLE_LOSS_PATCHES").map_or(Ok(64), |s| s.parse())?;
    let (height, width) = (side, side);
    let mut precision: ClipPrecision = std::env::var("STYLE_LOSS_PRECISION")
        .as_deref()
        .unwrap_or("f32")
        .parse()?;
    let mut vgg_precision: VggPrecision = std::env::var("STYLE_LOSS_VGG_PRECISION")
        .as_deref()
        .unwrap_or("f32")
        .parse()?;
    // `auto` timed here, at this run's shapes, so that its cost and choice are reported.
    let config = ClipConfig::vit_b_32();
    if precision == ClipPrecision::Auto {
        let start = Instant::now();
        let choice = choose_clip(&device, ClipProducts::of(&config.vision, patches + 1))?;
        precision = precision.resolve(&choice);
        println!(
            "auto: CLIP {precision} ({choice}), timed in {:.2} s",
            seconds_since(start)
        );
    }
    if vgg_precision == VggPrecision::Auto {
        let start = Instant::now();
        let choice = choose_vgg(&device, Vgg19Widths::default())?;
        vgg_precision = vgg_precision.resolve(&choice);
        println!(
            "auto: VGG {vgg_precision} ({choice}), timed in {:.2} s",
            seconds_since(start)
        );
    }
    let start = Instant::now();
    let clip = ClipModel::from_tensors_with_precision(
        &config,
        &NamedTensors::random(&device),
        &device,
        precision,
    )?;
    let vgg = Vgg19Features::from_tensors_with_precision(
        &NamedTensors::random(&device),
        Vgg19Widths::default(),
        vgg_precision,
    )?;
    println!("random weights: {:.2} s", seconds_since(start));

    let dim = clip.config().projection_dim;
    let style = Tensor::rand(-1f32, 1f32, dim, &device)?;
    let direction = StyleDirection::from_embeddings(&style, &style.zeros_like()?)?;
    let render = Tensor::rand(0f32, 1f32, (1, 3, height, width), &device)?;
    let mut gt = Tensor::rand(0f32, 1f32, (1, 3, height, width), &device)?;
    // A white band as background, for the background loss.
    gt = gt.slice_assign(
        &[0..1, 0..3, 0..100, 0..width],
        &Tensor::ones((1, 3, 100, width), candle_core::DType::F32, &device)?,
    )?;
    let mask = background_mask_from_color(&gt, [1.0, 1.0, 1.0])?;
    let paper = LossWeights {
        background: 1000.0,
        ..LossWeights::default()
    };
    let only = |d: f64, p: f64, c: f64, b: f64| LossWeights {
        directional: d,
        patch: p,
        content: c,
        background: b,
    };
    let configurations = [
        (
            "directional (1 CLIP pass)",
            only(paper.directional, 0.0, 0.0, 0.0),
        ),
        (
            &format!("patch ({patches} CLIP passes)"),
            only(0.0, paper.patch, 0.0, 0.0),
        ),
        (
            &format!("content (VGG-19 {side}x{side})"),
            only(0.0, 0.0, paper.content, 0.0),
        ),
        ("background", only(0.0, 0.0, 0.0, paper.background)),
        ("all four terms", paper),
    ];
    println!(
        "device: {device:?}, CLIP {}, VGG {}, image {height}x{width}, {patches} patches of 128, \
         repeats {repeats}",
        clip.precision(),
        vgg.precision()
    );
    // The first cache_view also builds what a run builds once (VGG's exact kernels); the
    // second is what each further view costs.
    println!("| term | cache_view (s) | loss + gradient (s) | second cache_view (s) |");
    println!("|---|---|---|---|");
    for (name, weights) in configurations {
        if only_term
            .as_deref()
            .is_some_and(|term| !name.starts_with(term))
        {
            continue;
        }
        let loss = StyleLoss::new(
            clip.clone(),
            Some(vgg.clone()),
            direction.clone(),
            weights,
            PatchSettings {
                num_patches: patches,
                ..PatchSettings::default()
            },
        )?;
        let start = Instant::now();
        let cache = loss.cache_view(&gt, Some(&mask))?;
        let cache_time = seconds_since(start);
        let mut rng = style_rng(0);
        let mut best = f64::INFINITY;
        for _ in 0..repeats {
            let start = Instant::now();
            let out = loss.loss_and_grad(&render, &cache, &mut rng)?;
            out.grad.sum_all()?.to_scalar::<f32>()?;
            best = best.min(seconds_since(start));
        }
        let start = Instant::now();
        loss.cache_view(&gt, Some(&mask))?;
        let second_cache_time = seconds_since(start);
        println!("| {name} | {cache_time:.2} | {best:.2} | {second_cache_time:.2} |");
    }
    Ok(())
}
