//! Times CLIPGaussian 3D stylization steps on this machine, split into render, style loss
//! (CLIP full image + patches, VGG, background) with its image gradient, and rasterizer backward
//! with Adam: Gaussians of SH degree 3 on a sphere, ViT-B/32-sized CLIP and VGG-19 with random
//! weights, the paper's 64 patches of 128, through the same `Trainer` and device choice as a
//! stylization run. Prints the mean of the timed steps (after one untimed warm-up step) and the
//! projected time of a 5000-step run.
//!
//! Run: `cargo run --release -p integration-tests --example step_timing -- [<gaussians>
//! [<device> [<steps> [<clip precision> [<width>x<height>]]]]]`, defaults 300000, cpu, 3,
//! f32, 800x800; `<device>` is cpu, gpu or auto as `--device`; build with `--features cuda`
//! (scripts/build_cuda.sh) for the style loss on CUDA.

use std::ops::ControlFlow;
use std::time::{Duration, Instant};

use gs_core::adam::AdamHyper;
use gs_core::model::{BaseModel, View};
use gs_core::raster::render;
use gs_core::sampler::ViewSampler;
use gs_core::train::TrainConfig;
use gs_core::{Camera, GaussianSet, Image};
use gs_stylize::rates::gaussian_stylization;
use gs_wgpu::backend::{DeviceChoice, OpenDevice, Trainer};
use rand::{Rng, SeedableRng};
use style_loss::compute_device;
use style_loss::test_models::random_full_size_loss;
use style_loss::{ClipPrecision, PatchSettings, StyleObjective};

/// `n` Gaussians on a unit sphere's surface, sized to their spacing and mostly opaque.
fn scene(n: usize) -> GaussianSet {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let mut g = GaussianSet::zeros(n, 3);
    let spacing = (4.0 * std::f32::consts::PI / n as f32).sqrt();
    for i in 0..n {
        let z: f32 = rng.random_range(-1.0..1.0);
        let phi: f32 = rng.random_range(0.0..std::f32::consts::TAU);
        let r = (1.0 - z * z).sqrt();
        g.means[3 * i..3 * i + 3].copy_from_slice(&[r * phi.cos(), r * phi.sin(), z]);
    }
    for v in &mut g.log_scales {
        *v = (0.8 * spacing).ln() + rng.random_range(-0.5..0.5);
    }
    for v in &mut g.quats {
        *v = rng.random_range(-1.0..1.0);
    }
    for v in &mut g.opacity_logits {
        *v = rng.random_range(0.0..4.0);
    }
    for v in &mut g.sh_dc {
        *v = rng.random_range(-1.0..1.0);
    }
    for v in &mut g.sh_rest {
        *v = rng.random_range(-0.1..0.1);
    }
    g
}

/// The command line: gaussians, device, timed steps, CLIP precision, image size.
struct Args {
    gaussians: usize,
    device: DeviceChoice,
    steps: u64,
    precision: ClipPrecision,
    size: (u32, u32),
}

fn parse_args() -> Result<Args, Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |i: usize| args.get(i).map(String::as_str);
    let size = match arg(4) {
        Some(s) => {
            let (w, h) = s
                .split_once('x')
                .ok_or(format!("size {s:?} is not <w>x<h>"))?;
            (w.parse()?, h.parse()?)
        }
        None => (800, 800),
    };
    Ok(Args {
        gaussians: arg(0).map_or(Ok(300_000), str::parse)?,
        device: arg(1).map_or(Ok(DeviceChoice::Cpu), str::parse)?,
        steps: arg(2).map_or(Ok(3), str::parse)?,
        precision: arg(3).map_or(Ok(ClipPrecision::F32), str::parse)?,
        size,
    })
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    style_loss::memory::keep_freed_memory();
    let args = parse_args()?;
    let n = args.gaussians;
    let (width, height) = args.size;
    let backend = args.device.open()?;
    let (loss_device, note) = compute_device::open_for(args.device)?;
    println!(
        "device: {}; style loss: {}{note} ({})",
        backend.describe(),
        compute_device::describe(&loss_device),
        args.precision
    );
    let model = scene(n);
    let views: Vec<View> = (0..4)
        .map(|k| {
            let a = k as f64 * std::f64::consts::FRAC_PI_2;
            let eye = [3.2 * a.cos(), -0.8, 3.2 * a.sin()];
            Camera::look_at(eye, [0.0; 3], [0.0, -1.0, 0.0], 0.7, width, height).map(View::still)
        })
        .collect::<Result<_, _>>()?;
    let targets: Vec<Image> = views
        .iter()
        .map(|v| render(&model, &v.camera, [1.0; 3]).image)
        .collect();

    let start = Instant::now();
    let loss = random_full_size_loss(PatchSettings::default(), args.precision, &loss_device)?;
    println!("random weights: {:.1} s", start.elapsed().as_secs_f64());
    let start = Instant::now();
    let mut objective = StyleObjective::new(loss, &targets, None, 0, &loss_device)?;
    println!(
        "per-view cache (GT CLIP embedding + VGG features) of {} views: {:.1} s",
        targets.len(),
        start.elapsed().as_secs_f64()
    );

    let groups = gaussian_stylization(0.01).optimizer_groups(&model.group_names(), 3.5)?;
    let mut trainer = Trainer::new(&backend, model, groups, AdamHyper::default())?;
    let mut sampler = ViewSampler::new(views.len(), 0);
    let mut phases = [Duration::ZERO; 3];
    let mut terms = Vec::new();
    let warm_up = Instant::now();
    let mut timed = None;
    trainer.train(
        &views,
        &mut objective,
        &mut sampler,
        &TrainConfig {
            steps: 1 + args.steps,
            background: [1.0; 3],
        },
        |r| {
            if r.step == 1 {
                println!("warm-up step: {:.2} s", warm_up.elapsed().as_secs_f64());
                timed = Some(Instant::now());
            } else {
                phases[0] += r.render_time;
                phases[1] += r.objective_time;
                phases[2] += r.backward_time;
                terms.clone_from(&r.value.terms);
            }
            ControlFlow::Continue(())
        },
    )?;
    let wall = timed.map_or(0.0, |t| t.elapsed().as_secs_f64()) / args.steps.max(1) as f64;
    let mean = |d: Duration| d.as_secs_f64() / args.steps.max(1) as f64;
    println!(
        "mean of {} steps, {n} Gaussians, {width}x{height}:",
        args.steps
    );
    println!("| phase | seconds |");
    println!("|---|---|");
    println!("| render (forward) | {:.4} |", mean(phases[0]));
    println!(
        "| style loss + dL/dimage (1 CLIP pass, 64 patch passes, VGG-19) | {:.4} |",
        mean(phases[1])
    );
    println!("| rasterizer backward + Adam | {:.4} |", mean(phases[2]));
    println!("| whole step (wall) | {wall:.4} |");
    println!("projected 5000-step run: {:.1} min", wall * 5000.0 / 60.0);
    println!(
        "parameters: {}",
        trainer.param_groups().iter().map(Vec::len).sum::<usize>()
    );
    println!("terms: {terms:?}");
    Ok(())
}
