//! `clipgaussian`: the command line of the workspace.
//!
//! Until the stylization binaries exist, its job is `fit-demo`: fit a random Gaussian set to
//! renders of the embedded default scene and write before/after pictures.

mod demo_scene;

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use gs_core::adam::{AdamHyper, LrSchedule};
use gs_core::image_loss::{psnr, PhotometricObjective};
use gs_core::model::{GaussianLrs, View};
use gs_core::raster::render;
use gs_core::train::{TrainConfig, ViewSampler};
use gs_core::{GaussianSet, Image};
use gs_wgpu::backend::{DeviceChoice, OpenDevice, Trainer};
use indicatif::{ProgressBar, ProgressStyle};

#[derive(Parser)]
#[command(version, about = "CLIPGaussian style transfer for Gaussian splatting")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Fit a random Gaussian set to renders of the embedded default scene (a striped torus
    /// around a ball) with L1 + D-SSIM, and write before/after pictures.
    FitDemo(FitDemoArgs),
}

#[derive(clap::Args)]
struct FitDemoArgs {
    /// Folder for the pictures (created if missing). Writes `views.png` (one row per view for
    /// the first four views: target | before | after) and `after.png` (the fitted set from
    /// view 0).
    #[arg(long, default_value = "out/fit-demo")]
    out: PathBuf,
    /// Optimisation steps, one view per step.
    #[arg(long, default_value_t = 1500)]
    steps: u64,
    /// Number of Gaussians fitted (fixed for the whole run).
    #[arg(long, default_value_t = 3000)]
    gaussians: usize,
    /// Number of training cameras on the ring around the scene.
    #[arg(long, default_value_t = 12)]
    views: usize,
    /// Render size in pixels (square).
    #[arg(long, default_value_t = 256)]
    size: u32,
    /// Seed of the initial Gaussians and of the view order.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Where to train: cpu, gpu, or auto (a real GPU when there is one, else the cpu).
    #[arg(long, default_value_t = DeviceChoice::Auto)]
    device: DeviceChoice,
}

fn main() -> Result<()> {
    match Cli::parse().command {
        Command::FitDemo(args) => fit_demo(&args),
    }
}

fn mean_psnr(model: &GaussianSet, views: &[View], targets: &[Image], bg: [f32; 3]) -> f64 {
    views
        .iter()
        .zip(targets)
        .map(|(v, t)| psnr(&render(model, &v.camera, bg).image, t))
        .sum::<f64>()
        / views.len() as f64
}

fn fit_demo(args: &FitDemoArgs) -> Result<()> {
    if args.views == 0 || args.gaussians == 0 || args.size < 16 {
        bail!("--views and --gaussians must be at least 1 and --size at least 16");
    }
    let backend = args.device.open()?;
    println!("device: {}", backend.describe());
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create the output folder {}", args.out.display()))?;
    let bg = [1.0f32; 3];
    let scene = demo_scene::default_scene();
    let views = demo_scene::ring_views(args.views, args.size)?;
    let targets: Vec<Image> = views
        .iter()
        .map(|v| render(&scene, &v.camera, bg).image)
        .collect();
    let initial = demo_scene::random_init(args.gaussians, args.seed);
    let before: Vec<Image> = views
        .iter()
        .map(|v| render(&initial, &v.camera, bg).image)
        .collect();
    let psnr_before = mean_psnr(&initial, &views, &targets, bg);

    // 3DGS's fitting rates, the means' rate scaled up for this small scene and decaying over
    // the run.
    let lrs = GaussianLrs {
        means: LrSchedule::Exponential {
            start: 1.6e-4 * 13.0,
            end: 1.6e-6 * 13.0,
            steps: args.steps,
        },
        scales: 0.005,
        rotations: 0.001,
        opacities: 0.05,
        feature: 0.0025,
    };
    let mut trainer = Trainer::new(&backend, initial, lrs.groups(), AdamHyper::default())?;
    let config = TrainConfig {
        steps: args.steps,
        background: bg,
    };
    let mut sampler = ViewSampler::new(views.len(), args.seed);
    let mut objective = PhotometricObjective {
        targets: targets.clone(),
        lambda: 0.2,
    };
    let bar = ProgressBar::new(args.steps).with_style(
        ProgressStyle::with_template(
            "{bar:40} {pos}/{len} steps, {elapsed} elapsed, ETA {eta}  {msg}",
        )
        .expect("valid template"),
    );
    let start = Instant::now();
    let mut phase_secs = [0.0f64; 3];
    trainer.train(&views, &mut objective, &mut sampler, &config, |r| {
        phase_secs[0] += r.render_time.as_secs_f64();
        phase_secs[1] += r.objective_time.as_secs_f64();
        phase_secs[2] += r.backward_time.as_secs_f64();
        bar.set_position(r.step);
        if r.step % 10 == 0 || r.step == r.steps {
            bar.set_message(format!("loss {:.4}", r.value.loss));
        }
        ControlFlow::Continue(())
    })?;
    bar.finish();
    let model = trainer.into_model();
    let psnr_after = mean_psnr(&model, &views, &targets, bg);

    let rows: Vec<Image> = views
        .iter()
        .zip(&targets)
        .zip(&before)
        .take(4)
        .map(|((v, t), b)| {
            let after = render(&model, &v.camera, bg).image;
            Image::side_by_side(&[t, b, &after])
        })
        .collect();
    save_rows(&rows, &args.out.join("views.png"))?;
    render(&model, &views[0].camera, bg)
        .image
        .save_png(&args.out.join("after.png"))?;
    println!(
        "fitted {} Gaussians in {:.1} s: mean PSNR over {} views {:.2} dB -> {:.2} dB",
        args.gaussians,
        start.elapsed().as_secs_f64(),
        views.len(),
        psnr_before,
        psnr_after
    );
    let per_step = |s: f64| 1e3 * s / args.steps.max(1) as f64;
    println!(
        "per step: render {:.1} ms, L1+SSIM {:.1} ms, backward + Adam {:.1} ms",
        per_step(phase_secs[0]),
        per_step(phase_secs[1]),
        per_step(phase_secs[2])
    );
    println!(
        "wrote {} and {}",
        args.out.join("views.png").display(),
        args.out.join("after.png").display()
    );
    Ok(())
}

/// Stacks equally wide images top to bottom and writes them as one PNG.
fn save_rows(rows: &[Image], path: &Path) -> Result<()> {
    let width = rows[0].width;
    let height = rows.iter().map(|r| r.height).sum();
    let data = rows.iter().flat_map(|r| r.data.iter().copied()).collect();
    Image {
        width,
        height,
        data,
    }
    .save_png(path)?;
    Ok(())
}
