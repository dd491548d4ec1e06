//! The 4D numbers of docs/benchmarks.md on this machine:
//! 1. fitting the generated 24-frame 64-pixel scene of the tests (time, held-out PSNR);
//! 2. a D-NeRF-sized fit (800 x 800, 150 frames, D-MiSo's defaults: 100,000 points, a network
//!    of width 256, batches of 2, 2000 cores of 500 sub-Gaussians): a few steps of each stage,
//!    timed, and the 40,000-step fit estimated from them;
//! 3. one stylization step at a batch of 4 views of 800 x 800 (ViT-B/32- and VGG-19-sized random
//!    weights, the paper's 64 patches) on a model of 2000 cores of 500 sub-Gaussians.
//!
//! Run: `cargo run --release -p base-dmiso --example benchmark_4d -- [<small fit steps>
//! [small|stylize]]` (default 3000; `small`: the small scene only; `stylize`: the stylization
//! step only). `BENCHMARK_4D_DEVICE=gpu` (or `auto`) runs the rasterizer, the network and the
//! loss where `--device gpu` puts them (with the `cuda` feature, the loss and the network on
//! CUDA); the default is the cpu.

#[path = "../tests/common/mod.rs"]
mod common;

use std::ops::ControlFlow;
use std::time::Instant;

use base_dmiso::deform_net::NetShape;
use base_dmiso::fit::{fit, mean_psnr, render_views, DynamicSceneFitSettings};
use base_dmiso::init::{initial_model, with_sub_gaussians};
use base_dmiso::stylize::{stylize_groups, DynamicSceneStylizeConfig};
use gs_core::adam::AdamHyper;
use gs_core::dataset::scene_extent;
use gs_core::device::DeviceChoice;
use gs_core::sampler::{BatchOrder, ViewSampler};
use gs_core::train::TrainConfig;
use gs_wgpu::backend::{OpenDevice, Trainer};
use style_loss::test_models::random_full_size_loss;
use style_loss::{ClipPrecision, PatchSettings, StyleObjective};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let steps: u64 = std::env::args()
        .nth(1)
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(3000);
    let choice: DeviceChoice = std::env::var("BENCHMARK_4D_DEVICE")
        .as_deref()
        .unwrap_or("cpu")
        .parse()?;
    let backend = choice.open()?;
    let (device, note) = style_loss::compute_device::open_for(choice)?;
    let note = if note.is_empty() {
        note
    } else {
        format!(" ({note})")
    };
    println!(
        "threads: {}; rasterizer on {}; loss and network on {device:?}{note}",
        rayon::current_num_threads(),
        backend.describe()
    );
    let only = std::env::args().nth(2);
    if only.as_deref() == Some("stylize") {
        return stylization_step(&backend, &device);
    }

    // 1. The small scene.
    let train = common::views(24, 0.0, 64);
    let test = common::views(6, 0.5, 64);
    let images: Vec<_> = train.iter().map(|v| common::render(v, [1.0; 3])).collect();
    let truths: Vec<_> = test.iter().map(|v| common::render(v, [1.0; 3])).collect();
    let extent = scene_extent(&train);
    for (points, width) in [(600, 64), (2000, 128)] {
        let settings = DynamicSceneFitSettings {
            points,
            steps,
            warm_up: steps / 6,
            subs_from: steps * 7 / 12,
            sub_cores: points / 2,
            subs_per_core: 4,
            deform_width: width,
            seed: 3,
            ..DynamicSceneFitSettings::default()
        };
        let start = Instant::now();
        let mut model = fit(
            &train,
            &images,
            extent,
            &settings,
            &backend,
            &device,
            |_| ControlFlow::Continue(()),
        )?;
        let seconds = start.elapsed().as_secs_f64();
        let renders = render_views(&mut model, &test, [1.0; 3], &backend)?;
        println!(
            "small scene: {points} points, width {width}, {steps} steps: {seconds:.1} s \
             ({:.1} ms/step), {} cores of 4 sub-Gaussians, held-out PSNR {:.2} dB",
            1000.0 * seconds / steps as f64,
            model.cores(),
            mean_psnr(&renders, &truths)
        );
    }

    if only.as_deref() == Some("small") {
        return Ok(());
    }

    // 2. A D-NeRF-sized fit, a few steps of each stage.
    let big_train = common::views(150, 0.0, 800);
    let big_images: Vec<_> = big_train
        .iter()
        .map(|v| common::render(v, [1.0; 3]))
        .collect();
    let defaults = DynamicSceneFitSettings::default();
    let settings = DynamicSceneFitSettings {
        steps: 9,
        warm_up: 3,
        subs_from: 6,
        ..defaults.clone()
    };
    let mut per_step = Vec::new();
    fit(
        &big_train,
        &big_images,
        scene_extent(&big_train),
        &settings,
        &backend,
        &device,
        |r| {
            per_step.push((
                r.step,
                (r.render_time + r.objective_time + r.backward_time).as_secs_f64(),
            ));
            ControlFlow::Continue(())
        },
    )?;
    // The second and third step of each stage (the first warms caches up).
    let stage = |k: usize| (per_step[3 * k + 1].1 + per_step[3 * k + 2].1) / 2.0;
    let (warm, deform, subs) = (stage(0), stage(1), stage(2));
    let estimate = warm * defaults.warm_up as f64
        + deform * (defaults.subs_from - defaults.warm_up) as f64
        + subs * (defaults.steps - defaults.subs_from) as f64;
    println!(
        "D-NeRF-sized fit (800x800, 150 views, batch {}): s/step warm-up {warm:.2}, deformation \
         {deform:.2}, sub-Gaussians {subs:.2}; estimated {} steps: {:.1} h",
        defaults.batch,
        defaults.steps,
        estimate / 3600.0
    );

    stylization_step(&backend, &device)
}

/// 3. One stylization step at a batch of 4 views of 800 x 800.
fn stylization_step(
    backend: &gs_wgpu::backend::Backend,
    device: &candle_core::Device,
) -> Result<(), Box<dyn std::error::Error>> {
    let views = common::views(150, 0.0, 800)[..8].to_vec();
    let targets: Vec<_> = views.iter().map(|v| common::render(v, [1.0; 3])).collect();
    let base = initial_model(2000, NetShape::DEFAULT, 0, device)?;
    let model = with_sub_gaussians(&base, 2000, 500, 0)?;
    let loss = random_full_size_loss(PatchSettings::default(), ClipPrecision::F32, device)?;
    let start = Instant::now();
    let mut objective = StyleObjective::new(loss, &targets, None, 0, device)?;
    println!(
        "stylization: per-view cache of {} views: {:.1} s",
        views.len(),
        start.elapsed().as_secs_f64()
    );
    let config = DynamicSceneStylizeConfig::default();
    let mut trainer = Trainer::new(
        backend,
        model,
        stylize_groups(&config.learning_rates, scene_extent(&views))?,
        AdamHyper::default(),
    )?;
    let mut times = Vec::new();
    trainer.train(
        &views,
        &mut objective,
        &mut ViewSampler::batches(views.len(), 4, BatchOrder::Consecutive, 0),
        &TrainConfig {
            steps: 2,
            background: [1.0; 3],
        },
        |r| {
            times.push((
                r.render_time.as_secs_f64(),
                r.objective_time.as_secs_f64(),
                r.backward_time.as_secs_f64(),
            ));
            ControlFlow::Continue(())
        },
    )?;
    for (i, (render, objective, backward)) in times.iter().enumerate() {
        println!(
            "stylization step {} (batch of 4, 1,000,000 sub-Gaussians, 800x800): {:.1} s = \
             model + render {render:.1} s, loss {objective:.1} s, backward + network + Adam \
             {backward:.1} s",
            i + 1,
            render + objective + backward
        );
    }
    Ok(())
}
