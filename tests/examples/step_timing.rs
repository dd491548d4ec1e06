//! Times one CLIPGaussian 3D stylization step on this machine, split into render, style loss
//! (CLIP full image + patches, VGG, background) with its image gradient, rasterizer backward and
//! Adam: 300k Gaussians of SH degree 3 at 800x800, ViT-B/32-sized CLIP and VGG-19 with random
//! weights, the paper's 64 patches of 128.
//!
//! Run: `cargo run --release -p integration-tests --example step_timing [-- <gaussians>]`.

use std::ops::ControlFlow;
use std::time::Instant;

use candle_core::Device;
use gs_core::adam::{Adam, AdamHyper};
use gs_core::model::{BaseModel, GaussianLrs, View};
use gs_core::raster::render;
use gs_core::train::{train, TrainConfig, ViewSampler};
use gs_core::{Camera, GaussianSet, Image};
use rand::{Rng, SeedableRng};
use style_loss::test_models::random_full_size_loss;
use style_loss::{PatchSettings, StyleObjective};

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

fn main() -> Result<(), Box<dyn std::error::Error>> {
    style_loss::memory::keep_freed_memory();
    let n: usize = std::env::args().nth(1).map_or(Ok(300_000), |s| s.parse())?;
    let device = Device::Cpu;
    let mut model = scene(n);
    let views: Vec<View> = (0..4)
        .map(|k| {
            let a = k as f64 * std::f64::consts::FRAC_PI_2;
            let eye = [3.2 * a.cos(), -0.8, 3.2 * a.sin()];
            Camera::look_at(eye, [0.0; 3], [0.0, -1.0, 0.0], 0.7, 800, 800).map(View::still)
        })
        .collect::<Result<_, _>>()?;
    let targets: Vec<Image> = views
        .iter()
        .map(|v| render(&model, &v.camera, [1.0; 3]).image)
        .collect();

    let start = Instant::now();
    let loss = random_full_size_loss(PatchSettings::default(), &device)?;
    println!("random weights: {:.1} s", start.elapsed().as_secs_f64());
    let start = Instant::now();
    let mut objective = StyleObjective::new(loss, &targets[..1], None, 0, &device)?;
    println!(
        "per-view cache (GT CLIP embedding + VGG features), once per view: {:.1} s",
        start.elapsed().as_secs_f64()
    );

    let mut adam = Adam::new(
        GaussianLrs::stylization(3.5, 0.01).groups(),
        &model.group_lens(),
        AdamHyper::default(),
    );
    let config = TrainConfig {
        steps: 1,
        background: [1.0; 3],
    };
    let mut report = None;
    train(
        &mut model,
        &views[..1],
        &mut objective,
        &mut adam,
        &mut ViewSampler::new(1, 0),
        &config,
        |r| {
            report = Some(r.clone());
            ControlFlow::Continue(())
        },
    )?;
    let r = report.expect("one step ran");

    // Adam alone on the same parameter count, for the split of the backward phase.
    let grads: Vec<Vec<f32>> = model.group_lens().iter().map(|&l| vec![1e-3; l]).collect();
    let grad_refs: Vec<&[f32]> = grads.iter().map(|g| g.as_slice()).collect();
    let start = Instant::now();
    adam.step(&mut model.groups_mut(), &grad_refs);
    let adam_secs = start.elapsed().as_secs_f64();

    let backward = r.backward_time.as_secs_f64();
    println!("| phase | seconds |");
    println!("|---|---|");
    println!(
        "| render (forward, {n} Gaussians, 800x800) | {:.3} |",
        r.render_time.as_secs_f64()
    );
    println!(
        "| style loss + dL/dimage (1 CLIP pass, 64 patch passes, VGG-19) | {:.1} |",
        r.objective_time.as_secs_f64()
    );
    println!(
        "| rasterizer backward | {:.3} |",
        (backward - adam_secs).max(0.0)
    );
    println!(
        "| Adam ({} parameters) | {:.3} |",
        model.group_lens().iter().sum::<usize>(),
        adam_secs
    );
    println!("terms: {:?}", r.value.terms);
    Ok(())
}
