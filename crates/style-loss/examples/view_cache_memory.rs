//! Peak memory of a style objective's per-view ground-truth cache against the number of views:
//! ViT-B/32-sized CLIP and full VGG-19 with random weights (the shapes, and so the memory, of
//! the real ones), `views` random pictures of `width x height`, the paper's 3D weights (no
//! background term). Prints the views, the seconds the cache took and the process's peak
//! resident memory (`VmHWM`).
//!
//! `cargo run --release -p style-loss --features test-models --example view_cache_memory --
//! <views> [budget_mb|all] [width height]`: with a budget, the caches past it go to a
//! temporary folder (as a run's `view_cache_mb`); `all` holds every cache in memory.

use std::time::Instant;

use candle_core::Device;
use gs_core::Image;
use style_loss::test_models::random_full_size_loss;
use style_loss::{CacheBudget, ClipPrecision, PatchSettings, StyleObjective};

/// The process's peak resident memory, MB (NaN where it cannot be read).
fn peak_mb() -> f64 {
    style_loss::memory::peak_resident_mb().unwrap_or(f64::NAN)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    style_loss::memory::keep_freed_memory();
    style_loss::cpu_threads::candle_ops_on_calling_thread();
    let mut args = std::env::args().skip(1);
    let views: usize = args.next().map_or(Ok(10), |s| s.parse())?;
    let budget = match args.next().as_deref() {
        None | Some("all") => CacheBudget::unbounded(),
        Some(mb) => CacheBudget {
            resident_bytes: mb.parse::<u64>()? << 20,
            spill: Some(std::env::temp_dir().join(format!("view-cache-{}", std::process::id()))),
        },
    };
    let width: u32 = args.next().map_or(Ok(854), |s| s.parse())?;
    let height: u32 = args.next().map_or(Ok(480), |s| s.parse())?;
    let device = Device::Cpu;
    let loss = random_full_size_loss(PatchSettings::default(), ClipPrecision::F32, &device)?;
    let targets: Vec<Image> = (0..views)
        .map(|v| Image {
            width,
            height,
            data: (0..3 * width as usize * height as usize)
                .map(|i| ((i * 7919 + v * 104_729) % 1000) as f32 / 1000.0)
                .collect(),
        })
        .collect();
    let before = peak_mb();
    let start = Instant::now();
    let objective =
        StyleObjective::with_progress(loss, &targets, None, 0, &device, &budget, &mut |_, _| {})?;
    let seconds = start.elapsed().as_secs_f64();
    println!(
        "views {views} at {width}x{height}, {} in memory: cache {seconds:.1} s, peak {:.0} MB \
         (before the cache {before:.0} MB)",
        objective.resident_views(),
        peak_mb()
    );
    drop(objective);
    Ok(())
}
