//! Writes `viewer.html` pages of N random Gaussians of SH degree 3 (base and stylized) into a
//! folder and prints each page's size, for the viewer's benchmark (its load and frame times
//! are measured in Chromium by the commands in docs/benchmarks.md).
//!
//! `cargo run --release -p gs-stylize --example viewer_timing -- <folder> [count ...]`

use gs_core::{Camera, GaussianSet};
use gs_stylize::viewer::{write_viewer, Shown, ViewerScene};
use rand::{Rng, SeedableRng};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let folder = std::path::PathBuf::from(
        args.next()
            .ok_or("usage: viewer_timing <folder> [count ...]")?,
    );
    let counts: Vec<usize> = args.map(|a| a.parse()).collect::<Result<_, _>>()?;
    std::fs::create_dir_all(&folder)?;
    let camera = Camera::look_at([0.0, 0.0, -4.0], [0.0; 3], [0.0, -1.0, 0.0], 0.8, 800, 800)?;
    for n in if counts.is_empty() {
        vec![100_000]
    } else {
        counts
    } {
        let mut rng = rand::rngs::StdRng::seed_from_u64(n as u64);
        let mut random = |lo: f32, hi: f32, len: usize| -> Vec<f32> {
            (0..len).map(|_| rng.random_range(lo..hi)).collect()
        };
        let mut set = GaussianSet::zeros(n, 3);
        set.means = random(-1.0, 1.0, 3 * n);
        set.log_scales = random(-5.0, -3.0, 3 * n);
        set.quats = random(-1.0, 1.0, 4 * n);
        set.opacity_logits = random(-2.0, 3.0, n);
        set.sh_dc = random(-1.5, 1.5, 3 * n);
        set.sh_rest = random(-0.2, 0.2, 45 * n);
        let mut stylized = set.clone();
        stylized.sh_dc = random(-1.5, 1.5, 3 * n);
        let path = folder.join(format!("viewer-{n}.html"));
        let start = std::time::Instant::now();
        write_viewer(
            &path,
            &ViewerScene {
                title: format!("{n} random Gaussians"),
                shown: Shown::Still {
                    base: &set,
                    stylized: Some(&stylized),
                },
                cameras: vec![("front".into(), camera.clone())],
                background: [0.0; 3],
            },
        )?;
        println!(
            "{}: {n} Gaussians, {:.1} MB, written in {:.2} s",
            path.display(),
            std::fs::metadata(&path)?.len() as f64 / 1e6,
            start.elapsed().as_secs_f64()
        );
    }
    Ok(())
}
