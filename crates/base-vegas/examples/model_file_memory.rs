//! Peak memory and time of writing and reading a VeGaS model file (docs/benchmarks.md).
//!
//! Run: `cargo run --release -p base-vegas --example model_file_memory -- write <gaussians>
//! <frames> <file>`, then `... -- read <file>` in a fresh process; each prints its wall time
//! and the process's peak resident memory (`VmHWM`).

use std::path::Path;
use std::time::Instant;

use base_vegas::init::initial_model;
use base_vegas::model_file::{read_model, write_model};

/// The process's peak resident memory, MB (NaN where it cannot be read).
fn peak_mb() -> f64 {
    style_loss::memory::peak_resident_mb().unwrap_or(f64::NAN)
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let started = Instant::now();
    match args
        .iter()
        .map(String::as_str)
        .collect::<Vec<_>>()
        .as_slice()
    {
        ["write", count, frames, file] => {
            let model = initial_model(count.parse().unwrap(), frames.parse().unwrap(), 1.0, 1.0, 0);
            let built = peak_mb();
            write_model(Path::new(file), &model, None).unwrap();
            println!(
                "write: {:.2} s, peak {:.0} MB ({built:.0} MB with the model built)",
                started.elapsed().as_secs_f64(),
                peak_mb()
            );
        }
        ["read", file] => {
            let (model, _) = read_model(Path::new(file)).unwrap();
            let size = std::fs::metadata(file).unwrap().len() as f64 / 1e6;
            println!(
                "read {} Gaussians, {} frames, {size:.0} MB file: {:.2} s, peak {:.0} MB",
                model.params().len(),
                model.frames(),
                started.elapsed().as_secs_f64(),
                peak_mb()
            );
        }
        _ => eprintln!("usage: model_file_memory write <gaussians> <frames> <file> | read <file>"),
    }
}
