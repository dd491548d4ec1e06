//! Writes and reads back a 1M-Gaussian SH degree 3 binary PLY in a temporary folder and prints
//! both times (best of three) and the file size.
//!
//! `cargo run --release -p gs-core --example ply_timing [count]`

use std::time::Instant;

use gs_core::ply::{read_ply, write_ply, PlyFormat, PlyGaussians};
use gs_core::GaussianSet;
use rand::{Rng, SeedableRng};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let count: usize = match std::env::args().nth(1) {
        Some(arg) => arg.parse()?,
        None => 1_000_000,
    };
    let mut rng = rand::rngs::StdRng::seed_from_u64(0);
    let mut set = GaussianSet::zeros(count, 3);
    for array in set.arrays_mut() {
        for v in array.iter_mut() {
            *v = rng.random_range(-3.0f32..3.0);
        }
    }
    let ply = PlyGaussians::new(set);
    let dir = std::env::temp_dir().join(format!("ply-timing-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let path = dir.join("point_cloud.ply");
    let mut write_s = f64::INFINITY;
    let mut read_s = f64::INFINITY;
    for _ in 0..3 {
        let t = Instant::now();
        write_ply(&path, &ply, PlyFormat::BinaryLittleEndian)?;
        write_s = write_s.min(t.elapsed().as_secs_f64());
        let t = Instant::now();
        let back = read_ply(&path)?;
        read_s = read_s.min(t.elapsed().as_secs_f64());
        assert_eq!(
            back.gaussians, ply.gaussians,
            "the file reads back what was written"
        );
    }
    let bytes = std::fs::metadata(&path)?.len();
    std::fs::remove_dir_all(&dir)?;
    println!(
        "{count} Gaussians, SH degree 3, {:.1} MB binary PLY: write {write_s:.3} s, read {read_s:.3} s \
         (best of 3, {} threads)",
        bytes as f64 / 1e6,
        rayon::current_num_threads()
    );
    Ok(())
}
