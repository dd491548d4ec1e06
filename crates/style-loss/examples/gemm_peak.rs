//! The machine's matrix-product throughput on the CPU, the ceiling of a stylization step (whose
//! time is almost all products): the loss's f32 and f64 products (candle's, the `gemm` crate) and
//! bf16 products (gemmkit's), with the threads of `RAYON_NUM_THREADS`, on the shapes a step's
//! products have, best of `repeats`.
//!
//! Run: `cargo run --release -p style-loss --example gemm_peak [-- <repeats>]`.

use std::time::Instant;

use candle_core::{DType, Device, Tensor};
use style_loss::matmul::checked_matmul;

/// GFLOP/s of the best of `repeats` products `[m, k] x [k, n]` in `dtype`.
fn throughput(
    m: usize,
    k: usize,
    n: usize,
    dtype: DType,
    repeats: usize,
) -> candle_core::Result<f64> {
    let a = Tensor::rand(-1f32, 1f32, (m, k), &Device::Cpu)?.to_dtype(dtype)?;
    let b = Tensor::rand(-1f32, 1f32, (k, n), &Device::Cpu)?.to_dtype(dtype)?;
    let mut best = f64::INFINITY;
    for _ in 0..repeats {
        let start = Instant::now();
        let product = checked_matmul(&a, &b)?;
        drop(product);
        best = best.min(start.elapsed().as_secs_f64());
    }
    Ok(2.0 * (m * k * n) as f64 / best / 1e9)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    style_loss::memory::keep_freed_memory();
    style_loss::cpu_threads::candle_ops_on_calling_thread();
    let repeats: usize = std::env::args().nth(1).map_or(Ok(5), |s| s.parse())?;
    println!("| product [m, k] x [k, n] | what | f32 GFLOP/s | f64 GFLOP/s | bf16 GFLOP/s |");
    println!("|---|---|---|---|---|");
    let shapes = [
        (3200, 768, 3072, "CLIP ViT-B/32 MLP, 64 patches"),
        (400, 768, 3072, "CLIP ViT-B/32 MLP, 8 patches"),
        (147_456, 192, 64, "VGG conv1_2 kernel row at 384x384"),
        (9216, 1536, 512, "VGG conv4_x kernel row at 384x384"),
        (148_224, 576, 64, "VGG conv1_2 at 384x384, stacked"),
        (2400, 4608, 512, "VGG conv4_x at 384x384, stacked"),
    ];
    for (m, k, n, what) in shapes {
        println!(
            "| [{m}, {k}] x [{k}, {n}] | {what} | {:.0} | {:.0} | {:.0} |",
            throughput(m, k, n, DType::F32, repeats)?,
            throughput(m, k, n, DType::F64, repeats)?,
            throughput(m, k, n, DType::BF16, repeats)?
        );
    }
    Ok(())
}
