//! The video numbers of docs/benchmarks.md on this machine: fitting a generated 24-frame clip at
//! 854x480 (480p) with several Gaussian counts (PSNR against time), and one stylization step at
//! that size (ViT-B/32- and VGG-19-sized random weights, the paper's 64 patches).
//!
//! Run: `cargo run --release -p base-vegas --example benchmark_video -- [<fit steps> [<counts>]]`
//! (defaults 600 and `10000,30000,100000`).

use std::ops::ControlFlow;
use std::time::Instant;

use base_vegas::fit::{
    fit, mean_psnr, render_frames, training_targets, training_views, VideoFitSettings,
};
use base_vegas::init::initial_model;
use base_vegas::stylize::VideoStylizeConfig;
use candle_core::Device;
use gs_core::adam::AdamHyper;
use gs_core::mirror_pair::plane_half_size;
use gs_core::model::BaseModel;
use gs_core::sampler::ViewSampler;
use gs_core::train::TrainConfig;
use gs_core::Image;
use gs_wgpu::backend::{Backend, Trainer};
use style_loss::test_models::random_full_size_loss;
use style_loss::{ClipPrecision, PatchSettings, StyleObjective};

const WIDTH: u32 = 854;
const HEIGHT: u32 = 480;
const FRAMES: usize = 24;

/// Frame `f`: a striped, shaded backdrop panning slowly, two discs crossing it and a bar
/// turning, so that the clip has texture, edges and motion at several speeds.
fn frame(f: usize) -> Image {
    let s = f as f32 / (FRAMES - 1) as f32;
    let discs = [
        (0.15 + 0.6 * s, 0.35, 0.11, [0.9, 0.2, 0.15]),
        (0.85 - 0.5 * s, 0.65, 0.08, [0.15, 0.35, 0.9]),
    ];
    let angle = std::f32::consts::PI * s;
    let mut data = Vec::with_capacity((WIDTH * HEIGHT * 3) as usize);
    for y in 0..HEIGHT {
        for x in 0..WIDTH {
            let (u, v) = (x as f32 / WIDTH as f32, y as f32 / HEIGHT as f32);
            let stripes = 0.5 + 0.5 * (40.0 * (u + 0.05 * s) + 6.0 * v).sin();
            let mut rgb = [0.25 + 0.4 * u, 0.3 + 0.3 * stripes, 0.6 - 0.3 * v];
            let aspect = WIDTH as f32 / HEIGHT as f32;
            for (cx, cy, r, color) in discs {
                let (dx, dy) = ((u - cx) * aspect, v - cy);
                let d2 = dx * dx + dy * dy;
                if d2 < r * r {
                    let shade = 1.0 - 0.5 * d2 / (r * r);
                    rgb = color.map(|c| c * shade);
                }
            }
            let (dx, dy) = ((u - 0.5) * aspect, v - 0.5);
            let along = dx * angle.cos() + dy * angle.sin();
            let across = -dx * angle.sin() + dy * angle.cos();
            if along.abs() < 0.25 && across.abs() < 0.02 {
                rgb = [0.95, 0.9, 0.3];
            }
            data.extend(rgb);
        }
    }
    Image {
        width: WIDTH,
        height: HEIGHT,
        data,
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    style_loss::memory::keep_freed_memory();
    style_loss::cpu_threads::candle_ops_on_calling_thread();
    let steps: u64 = std::env::args().nth(1).map_or(Ok(600), |s| s.parse())?;
    let counts: Vec<usize> = std::env::args()
        .nth(2)
        .unwrap_or_else(|| "10000,30000,100000".into())
        .split(',')
        .map(str::parse)
        .collect::<Result<_, _>>()?;
    let frames: Vec<Image> = (0..FRAMES).map(frame).collect();
    println!(
        "clip: {FRAMES} frames of {WIDTH}x{HEIGHT}; fit: {steps} steps (one view each), cpu, {} threads",
        rayon::current_num_threads()
    );
    println!("| Gaussians | steps | fit time (s) | s / step | mean PSNR (dB) |");
    println!("|---|---|---|---|---|");
    for &count in &counts {
        let settings = VideoFitSettings {
            gaussians: count,
            steps,
            ..VideoFitSettings::default()
        };
        let start = Instant::now();
        let mut model = fit(&frames, &settings, &Backend::Cpu, |_| {
            ControlFlow::Continue(())
        })?;
        let seconds = start.elapsed().as_secs_f64();
        let renders = render_frames(&mut model, WIDTH, HEIGHT, 1.0, [0.0; 3], &Backend::Cpu)?;
        println!(
            "| {count} | {steps} | {seconds:.1} | {:.3} | {:.2} |",
            seconds / steps as f64,
            mean_psnr(&renders, &frames)
        );
    }

    let count = *counts.last().unwrap_or(&100_000);
    let (hw, hh) = plane_half_size(WIDTH, HEIGHT, 1.0);
    let model = initial_model(count, FRAMES, hw, hh, 0);
    let views = training_views(WIDTH, HEIGHT, FRAMES, 1.0)?;
    let loss = random_full_size_loss(PatchSettings::default(), ClipPrecision::F32, &Device::Cpu)?;
    let start = Instant::now();
    let mut objective =
        StyleObjective::new(loss, &training_targets(&frames), None, 0, &Device::Cpu)?;
    println!(
        "stylization: per-view cache of {} views: {:.1} s",
        views.len(),
        start.elapsed().as_secs_f64()
    );
    let groups = VideoStylizeConfig::default()
        .learning_rates
        .optimizer_groups(&model.group_names(), 1.0)?;
    let mut trainer = Trainer::new(&Backend::Cpu, model, groups, AdamHyper::default())?;
    let mut times = Vec::new();
    trainer.train(
        &views,
        &mut objective,
        &mut ViewSampler::new(views.len(), 0),
        &TrainConfig {
            steps: 2,
            background: [0.0; 3],
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
    let (render, loss, backward) = times[times.len() - 1];
    println!(
        "one stylization step ({count} Gaussians, after a warm-up step): render {render:.3} s, \
         style loss + gradient {loss:.2} s, backward + Adam {backward:.3} s, total {:.2} s",
        render + loss + backward
    );
    Ok(())
}
