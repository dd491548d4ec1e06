//! Writes and reads back 1M Gaussians of SH degree 3 in every splat format (`gs_core::splats`)
//! in a temporary folder and prints, per format, the file size and the write and read times
//! (best of three), as a markdown table.
//!
//! `cargo run --release -p gs-core --example splat_formats_timing [count]`

use std::time::Instant;

use gs_core::ply::PlyGaussians;
use gs_core::splats::{read_splats, write_splats, SplatFormat};
use gs_core::GaussianSet;
use rand::{Rng, SeedableRng};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let count: usize = match std::env::args().nth(1) {
        Some(arg) => arg.parse()?,
        None => 1_000_000,
    };
    let mut rng = rand::rngs::StdRng::seed_from_u64(0);
    let mut set = GaussianSet::zeros(count, 3);
    let mut fill = |values: &mut [f32], lo: f32, hi: f32| {
        for v in values.iter_mut() {
            *v = rng.random_range(lo..hi);
        }
    };
    fill(&mut set.means, -3.0, 3.0);
    fill(&mut set.log_scales, -5.0, -1.0);
    fill(&mut set.quats, -1.0, 1.0);
    fill(&mut set.opacity_logits, -4.0, 4.0);
    fill(&mut set.sh_dc, -1.5, 1.5);
    fill(&mut set.sh_rest, -0.3, 0.3);
    let ply = PlyGaussians::without_normals(set);
    let dir = std::env::temp_dir().join(format!("splat-timing-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    println!("| format | size (MB) | write (s) | read (s) |");
    println!("|---|---|---|---|");
    for format in SplatFormat::ALL {
        let path = dir.join(format!("scene{}", format.extension()));
        let (mut write_s, mut read_s) = (f64::INFINITY, f64::INFINITY);
        for _ in 0..3 {
            let start = Instant::now();
            write_splats(&path, &ply, format)?;
            write_s = write_s.min(start.elapsed().as_secs_f64());
            let start = Instant::now();
            let back = read_splats(&path)?;
            read_s = read_s.min(start.elapsed().as_secs_f64());
            assert_eq!(back.gaussians.len(), count);
        }
        let size = std::fs::metadata(&path)?.len() as f64 / 1e6;
        println!(
            "| {} | {size:.1} | {write_s:.2} | {read_s:.2} |",
            format.name()
        );
    }
    std::fs::remove_dir_all(&dir)?;
    Ok(())
}
