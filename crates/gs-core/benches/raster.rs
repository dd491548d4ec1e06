//! Rasterizer forward and backward time against Gaussian count at 800x800, and the error of the
//! f32 render and gradients against the f64 reference.
//!
//! `cargo bench -p gs-core --bench raster [-- COUNT...]` (default counts 10000 100000 1000000).

use std::time::Instant;

use gs_core::raster::{backward, render, GradMask, OutputGrads};
use gs_core::{Camera, GaussianSet, Real};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// `n` Gaussians of SH degree 3 in a 2-unit cube seen from 4 units away, sized so that the
/// image is covered a few layers deep whatever `n` is (scale ~ n^(-1/3)).
fn scene(n: usize) -> GaussianSet<f64> {
    let mut rng = ChaCha8Rng::seed_from_u64(n as u64);
    let mut g = GaussianSet::<f64>::zeros(n, 3);
    let base = (0.02 * (1e5 / n as f64).cbrt()).ln();
    for v in &mut g.means {
        *v = rng.random_range(-1.0..1.0);
    }
    for v in &mut g.log_scales {
        *v = base + rng.random_range(-0.7..0.7);
    }
    for v in &mut g.quats {
        *v = rng.random_range(-1.0..1.0);
    }
    for v in &mut g.opacity_logits {
        *v = rng.random_range(-2.0..3.0);
    }
    for v in &mut g.sh_dc {
        *v = rng.random_range(-1.5..1.5);
    }
    for v in &mut g.sh_rest {
        *v = rng.random_range(-0.2..0.2);
    }
    g
}

fn time<R>(f: impl FnMut() -> R, reps: usize) -> (f64, R) {
    let mut f = f;
    let mut best = f64::INFINITY;
    let mut out = None;
    for _ in 0..reps {
        let t = Instant::now();
        let r = f();
        best = best.min(t.elapsed().as_secs_f64());
        out = Some(r);
    }
    (best, out.expect("reps >= 1"))
}

fn rel_err<T: Real>(reference: &[f64], got: &[T]) -> f64 {
    let num: f64 = reference
        .iter()
        .zip(got)
        .map(|(a, b)| (a - b.to_f64()).powi(2))
        .sum();
    let den: f64 = reference.iter().map(|a| a * a).sum();
    (num / den.max(1e-300)).sqrt()
}

fn main() {
    let counts: Vec<usize> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let counts = if counts.is_empty() {
        vec![10_000, 100_000, 1_000_000]
    } else {
        counts
    };
    let cam = Camera::look_at(
        [0.0, -0.5, -4.0],
        [0.0; 3],
        [0.0, -1.0, 0.0],
        0.75,
        800,
        800,
    )
    .expect("valid camera");
    let bg = [1.0f64, 1.0, 1.0];
    println!("threads: {}", rayon::current_num_threads());
    println!("| Gaussians | visible | tile pairs | forward ms | backward ms | total ms | max abs err image | rel err means | rel err scales | rel err quats | rel err opacity | rel err sh |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    for n in counts {
        let g64 = scene(n);
        let g32: GaussianSet = g64.cast();
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let w64: Vec<f64> = (0..3 * cam.pixel_count())
            .map(|_| rng.random_range(-1.0..1.0) / cam.pixel_count() as f64)
            .collect();
        let w32: Vec<f32> = w64.iter().map(|v| *v as f32).collect();
        let bg32 = bg.map(|v| v as f32);
        let (t_fwd, r32) = time(|| render(&g32, &cam, bg32), 3);
        let out32 = OutputGrads {
            rgb: &w32,
            alpha: None,
            depth: None,
        };
        let (t_bwd, gr32) = time(|| backward(&g32, &cam, &r32, &out32, GradMask::ALL), 3);

        let r64 = render(&g64, &cam, bg);
        let out64 = OutputGrads {
            rgb: &w64,
            alpha: None,
            depth: None,
        };
        let gr64 = backward(&g64, &cam, &r64, &out64, GradMask::ALL);
        let img_err = r64
            .image
            .data
            .iter()
            .zip(&r32.image.data)
            .fold(0.0f64, |m, (a, b)| m.max((a - *b as f64).abs()));
        let a64 = gr64.gaussians.arrays();
        let a32 = gr32.gaussians.arrays();
        let sh64: Vec<f64> = a64[4].iter().chain(a64[5]).copied().collect();
        let sh32: Vec<f32> = a32[4].iter().chain(a32[5]).copied().collect();
        println!(
            "| {n} | {} | {} | {:.1} | {:.1} | {:.1} | {:.2e} | {:.2e} | {:.2e} | {:.2e} | {:.2e} | {:.2e} |",
            r32.visible_count(),
            r32.intersection_count(),
            t_fwd * 1e3,
            t_bwd * 1e3,
            (t_fwd + t_bwd) * 1e3,
            img_err,
            rel_err(a64[0], a32[0]),
            rel_err(a64[1], a32[1]),
            rel_err(a64[2], a32[2]),
            rel_err(a64[3], a32[3]),
            rel_err(&sh64, &sh32),
        );
    }
}
