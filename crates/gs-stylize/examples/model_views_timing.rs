//! What a run given only a splat file does before its first step, timed: read the file, find
//! the model's robust bounds, make the orbit's cameras ([`ModelViews`], the defaults but for
//! the view count) and render each view's ground truth on the cpu; and the memory those
//! pictures hold (`f32` RGB), for each view count asked.
//!
//! `cargo run --release -p gs-stylize --example model_views_timing -- SCENE.ply 8 32 64`

use std::path::PathBuf;
use std::time::Instant;

use gs_core::dataset::nerf_synthetic::TrainSplits;
use gs_core::dataset::LoadOptions;
use gs_core::orbit::RobustBounds;
use gs_core::splats::read_splats;
use gs_stylize::model_views::{model_picture, ModelViews};
use gs_wgpu::backend::Backend;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let path = PathBuf::from(args.next().ok_or("give a splat file, then view counts")?);
    let counts: Vec<usize> = args.map(|a| a.parse()).collect::<Result<_, _>>()?;
    let start = Instant::now();
    let model = read_splats(&path)?.gaussians;
    let read_s = start.elapsed().as_secs_f64();
    let start = Instant::now();
    let bounds = RobustBounds::of(&model)?;
    let bounds_s = start.elapsed().as_secs_f64();
    println!(
        "{} Gaussians: read {read_s:.2} s, bounds {bounds_s:.2} s (centre {:?}, radius {:.3}, \
         default orbit {})",
        model.len(),
        bounds.centre,
        bounds.radius,
        bounds.default_kind().name()
    );
    println!("| views | cameras (s) | ground truth (s) | per view (s) | cache (MB) |");
    println!("|---|---|---|---|---|");
    let backend = Backend::Cpu;
    let renderer = backend.renderer(&model)?;
    for count in counts {
        let settings = ModelViews {
            orbit_views: count,
            ..ModelViews::default()
        };
        let start = Instant::now();
        let (views, _) = settings.views(
            &path,
            &bounds,
            TrainSplits::TrainAndTest,
            &LoadOptions::default(),
        )?;
        let cameras_s = start.elapsed().as_secs_f64();
        let start = Instant::now();
        let mut bytes = 0usize;
        for view in &views {
            let image = model_picture(renderer.render(&view.view.camera, [0.0; 3])?);
            bytes += image.data.len() * std::mem::size_of::<f32>();
        }
        let render_s = start.elapsed().as_secs_f64();
        println!(
            "| {count} | {cameras_s:.3} | {render_s:.1} | {:.2} | {:.0} |",
            render_s / count as f64,
            bytes as f64 / 1e6
        );
    }
    Ok(())
}
