//! The 2D figures of docs/benchmarks.md on the default picture's landscape drawn at 512x512:
//!
//! - `fit [counts...]`: fit PSNR (front camera) and elapsed time at 100, 250, 500 and 1000
//!   steps for each Gaussian count (default 10k, 50k, 100k);
//! - `step [count] [patches]`: one stylization step of a fitted-size model (default 100k
//!   Gaussians) with ViT-B/32-sized CLIP and VGG-19 of random weights and patches of 128
//!   (default the paper's 64), split into render, style loss with its image gradient, and
//!   backward + Adam.
//!
//! Run: `cargo run --release -p base-mirage --example benchmark_2d -- fit` (or `-- step`).

use std::time::Instant;

use base_mirage::fit::{fit_groups, PictureFitSettings};
use base_mirage::init::initial_gaussians;
use base_mirage::mirror::{extent, mirror_views, mirrored, plane_half_size};
use base_mirage::picture::landscape;
use base_mirage::stylize::PictureStylizeConfig;
use candle_core::Device;
use gs_core::adam::{Adam, AdamHyper};
use gs_core::image_loss::{psnr, PhotometricObjective};
use gs_core::model::BaseModel;
use gs_core::raster::render;
use gs_core::sampler::ViewSampler;
use gs_core::train::CpuTrainer;
use style_loss::test_models::random_full_size_loss;
use style_loss::{ClipPrecision, PatchSettings, StyleObjective};

/// Side of the benchmark picture, pixels.
const BENCHMARK_SIDE: u32 = 512;

/// Steps at which the fit's PSNR is measured.
const MILESTONES: [u64; 4] = [100, 250, 500, 1000];

fn fit_table(counts: &[usize]) -> Result<(), Box<dyn std::error::Error>> {
    let picture = landscape(BENCHMARK_SIDE);
    let (w, h) = (picture.width, picture.height);
    let settings = PictureFitSettings::default();
    let views = mirror_views(w, h, settings.distance)?;
    let (hw, hh) = plane_half_size(w, h, settings.distance);
    println!("| Gaussians | steps | PSNR (dB) | fit time (s) |");
    println!("|---|---|---|---|");
    for &count in counts {
        let model = initial_gaussians(count, settings.sh_degree, hw, hh, settings.seed);
        let mut objective = PhotometricObjective::new(
            vec![picture.clone(), mirrored(&picture)],
            settings.lambda_dssim,
        );
        let adam = Adam::new(
            fit_groups(extent(settings.distance)),
            &model.group_lens(),
            AdamHyper::default(),
        );
        let mut trainer = CpuTrainer::new(model, adam)?;
        let mut sampler = ViewSampler::new(2, settings.seed);
        let start = Instant::now();
        for &milestone in &MILESTONES {
            while trainer.step_count() < milestone {
                let batch = sampler.next_batch();
                trainer.step(&views, batch, settings.background, &mut objective)?;
            }
            let seconds = start.elapsed().as_secs_f64();
            let model = trainer.model();
            let shown = render(&model.renderable(), &views[0].camera, settings.background).image;
            println!(
                "| {count} | {milestone} | {:.2} | {seconds:.1} |",
                psnr(&shown, &picture)
            );
        }
    }
    Ok(())
}

fn step_table(count: usize, patches: usize) -> Result<(), Box<dyn std::error::Error>> {
    let device = Device::Cpu;
    let picture = landscape(BENCHMARK_SIDE);
    let (w, h) = (picture.width, picture.height);
    let settings = PictureFitSettings::default();
    let views = mirror_views(w, h, settings.distance)?;
    let (hw, hh) = plane_half_size(w, h, settings.distance);
    let model = initial_gaussians(count, settings.sh_degree, hw, hh, settings.seed);
    let loss = random_full_size_loss(
        PatchSettings {
            num_patches: patches,
            ..PatchSettings::default()
        },
        ClipPrecision::F32,
        &device,
    )?;
    let start = Instant::now();
    let mut objective =
        StyleObjective::new(loss, std::slice::from_ref(&picture), None, 0, &device)?;
    let cache = start.elapsed().as_secs_f64();
    let paper = PictureStylizeConfig::default();
    let adam = Adam::new(
        paper
            .learning_rates
            .optimizer_groups(&model.group_names(), extent(settings.distance))?,
        &model.group_lens(),
        AdamHyper::default(),
    );
    let mut trainer = CpuTrainer::new(model, adam)?;
    let batch = ViewSampler::new(1, 0).next_batch();
    let r = trainer.step(&views[..1], batch, settings.background, &mut objective)?;
    println!("| phase ({count} Gaussians, {w}x{h}) | seconds |");
    println!("|---|---|");
    println!("| per-view cache (once per view) | {cache:.1} |");
    println!("| render | {:.3} |", r.render_time.as_secs_f64());
    println!(
        "| style loss + dL/dimage (1 CLIP pass, {patches} patch passes, VGG-19) | {:.1} |",
        r.objective_time.as_secs_f64()
    );
    println!(
        "| rasterizer backward + Adam | {:.3} |",
        r.backward_time.as_secs_f64()
    );
    Ok(())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    style_loss::memory::keep_freed_memory();
    style_loss::cpu_threads::candle_ops_on_calling_thread();
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.first().map(String::as_str) {
        Some("fit") => {
            let counts: Vec<usize> = if args.len() > 1 {
                args[1..]
                    .iter()
                    .map(|a| a.parse())
                    .collect::<Result<_, _>>()?
            } else {
                vec![10_000, 50_000, 100_000]
            };
            fit_table(&counts)
        }
        Some("step") => step_table(
            args.get(1).map_or(Ok(100_000), |a| a.parse())?,
            args.get(2).map_or(Ok(64), |a| a.parse())?,
        ),
        _ => Err("usage: benchmark_2d fit [counts...] | step [count] [patches]".into()),
    }
}
