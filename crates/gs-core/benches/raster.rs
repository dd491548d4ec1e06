//! Rasterizer forward and backward time against Gaussian count at 800x800 (`--size WxH` for
//! another resolution), and the error of the f32 render and gradients against the f64
//! reference.
//!
//! `cargo bench -p gs-core --bench raster [-- [--volume] [--no-reference] [--backend cpu|wgpu]
//! [--size WxH] COUNT...]` (default counts 10000 100000 1000000); `--volume` times the
//! worst-case volume scene instead of the surface scene, `--no-reference` skips the f64
//! reference and the error columns, `--backend wgpu` times the wgpu backend (a real GPU when
//! there is one, else lavapipe) instead of the cpu backend: forward includes reading the image
//! back, backward includes uploading dL/dimage and waiting for the gradients.

use std::time::Instant;

use gs_core::raster::{backward, render, GradMask, Gradients, OutputGrads};
use gs_core::{Camera, GaussianSet, Real};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Which synthetic scene to time.
#[derive(Clone, Copy, PartialEq)]
enum Kind {
    /// Gaussians on the surfaces of five spheres, sized to their spacing and mostly opaque, as
    /// in a trained 3DGS object: pixels terminate after a few layers.
    Surface,
    /// Gaussians filling a 2-unit cube, sized so the image is covered tens of layers deep by
    /// semi-transparent splats: the worst case, where few pixels terminate.
    Volume,
}

/// `n` Gaussians of SH degree 3 of the given kind, seen from 4 units away.
fn scene(n: usize, kind: Kind) -> GaussianSet<f64> {
    let mut rng = ChaCha8Rng::seed_from_u64(n as u64);
    let mut g = GaussianSet::<f64>::zeros(n, 3);
    let spheres = [
        ([0.0, 0.0, 0.0], 0.7),
        ([0.9, -0.4, 0.3], 0.35),
        ([-0.9, 0.3, -0.2], 0.45),
        ([0.3, 0.7, -0.6], 0.3),
        ([-0.4, -0.7, 0.5], 0.3),
    ];
    let area: f64 = spheres
        .iter()
        .map(|(_, r)| 4.0 * std::f64::consts::PI * r * r)
        .sum();
    let spacing = (area / n as f64).sqrt();
    for i in 0..n {
        let p = match kind {
            Kind::Volume => [0; 3].map(|_| rng.random_range(-1.0..1.0)),
            Kind::Surface => {
                let (c, r) = spheres[i % spheres.len()];
                let z: f64 = rng.random_range(-1.0..1.0);
                let phi = rng.random_range(0.0..std::f64::consts::TAU);
                let s = (1.0 - z * z).sqrt();
                [
                    c[0] + r * s * phi.cos(),
                    c[1] + r * s * phi.sin(),
                    c[2] + r * z,
                ]
            }
        };
        g.means[3 * i..3 * i + 3].copy_from_slice(&p);
    }
    let (base, logits) = match kind {
        Kind::Volume => ((0.02 * (1e5 / n as f64).cbrt()).ln(), -2.0..3.0),
        Kind::Surface => ((0.8 * spacing).ln(), 0.0..5.0),
    };
    for v in &mut g.log_scales {
        *v = base + rng.random_range(-0.7..0.7);
    }
    for v in &mut g.quats {
        *v = rng.random_range(-1.0..1.0);
    }
    for v in &mut g.opacity_logits {
        *v = rng.random_range(logits.clone());
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

/// One backend's timings and outputs on one scene.
struct Measured {
    visible: String,
    pairs: usize,
    t_fwd: f64,
    t_bwd: f64,
    image: Vec<f32>,
    grads: Gradients<f32>,
}

fn measure_cpu(g: &GaussianSet, cam: &Camera, bg: [f32; 3], w: &[f32]) -> Measured {
    let (t_fwd, r) = time(|| render(g, cam, bg), 3);
    let out = OutputGrads {
        rgb: w,
        alpha: None,
        depth: None,
    };
    let (t_bwd, grads) = time(|| backward(g, cam, &r, &out, GradMask::ALL), 3);
    Measured {
        visible: r.visible_count().to_string(),
        pairs: r.intersection_count(),
        t_fwd,
        t_bwd,
        image: r.image.data,
        grads,
    }
}

fn measure_wgpu(
    ctx: &gs_wgpu::GpuContext,
    g: &GaussianSet,
    cam: &Camera,
    bg: [f32; 3],
    w: &[f32],
) -> Measured {
    let gg = gs_wgpu::GpuGaussians::upload(ctx, g).expect("scene fits on the GPU");
    let (t_fwd, (r, image)) = time(
        || {
            let r = gs_wgpu::render(ctx, &gg, cam, bg).expect("render");
            let image = r.image(ctx);
            (r, image)
        },
        3,
    );
    let out = OutputGrads {
        rgb: w,
        alpha: None,
        depth: None,
    };
    let (t_bwd, grads) = time(
        || {
            let grads = gs_wgpu::backward(ctx, &gg, &r, &out, GradMask::ALL).expect("backward");
            ctx.wait();
            grads
        },
        3,
    );
    Measured {
        visible: "-".into(),
        pairs: r.intersection_count(),
        t_fwd,
        t_bwd,
        image: image.data,
        grads: grads.download(ctx),
    }
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
    let with_reference = !std::env::args().any(|a| a == "--no-reference");
    let kind = if std::env::args().any(|a| a == "--volume") {
        Kind::Volume
    } else {
        Kind::Surface
    };
    let backend = std::env::args()
        .skip_while(|a| a != "--backend")
        .nth(1)
        .unwrap_or_else(|| "cpu".into());
    let ctx = (backend == "wgpu").then(|| {
        let ctx =
            gs_wgpu::GpuContext::new(gs_wgpu::AdapterChoice::AllowSoftware).expect("a GPU adapter");
        println!("device: {}", ctx.describe());
        ctx
    });
    match backend.as_str() {
        "cpu" => {}
        "wgpu" => {}
        other => panic!("unknown backend {other}: cpu or wgpu"),
    }
    let counts = if counts.is_empty() {
        vec![10_000, 100_000, 1_000_000]
    } else {
        counts
    };
    let (width, height) = std::env::args()
        .skip_while(|a| a != "--size")
        .nth(1)
        .map(|size| {
            let (w, h) = size.split_once('x').expect("--size WIDTHxHEIGHT");
            (
                w.parse().expect("--size WIDTHxHEIGHT"),
                h.parse().expect("--size WIDTHxHEIGHT"),
            )
        })
        .unwrap_or((800, 800));
    let cam = Camera::look_at(
        [0.0, -0.5, -4.0],
        [0.0; 3],
        [0.0, -1.0, 0.0],
        0.75,
        width,
        height,
    )
    .expect("valid camera");
    println!("image: {width}x{height}");
    let bg = [1.0f64, 1.0, 1.0];
    println!("threads: {}", rayon::current_num_threads());
    println!("| Gaussians | visible | tile pairs | forward ms | backward ms | total ms | image error: max / mean / share > 1e-3 | rel err means | rel err scales | rel err quats | rel err opacity | rel err sh |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    for n in counts {
        let g64 = scene(n, kind);
        let g32: GaussianSet = g64.cast();
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let w64: Vec<f64> = (0..3 * cam.pixel_count())
            .map(|_| rng.random_range(-1.0..1.0) / cam.pixel_count() as f64)
            .collect();
        let w32: Vec<f32> = w64.iter().map(|v| *v as f32).collect();
        let bg32 = bg.map(|v| v as f32);
        let m = match &ctx {
            Some(ctx) => measure_wgpu(ctx, &g32, &cam, bg32, &w32),
            None => measure_cpu(&g32, &cam, bg32, &w32),
        };
        let Measured {
            visible,
            pairs,
            t_fwd,
            t_bwd,
            image,
            grads: gr32,
        } = m;
        if !with_reference {
            println!(
                "| {n} | {visible} | {pairs} | {:.1} | {:.1} | {:.1} | - | - | - | - | - | - |",
                t_fwd * 1e3,
                t_bwd * 1e3,
                (t_fwd + t_bwd) * 1e3
            );
            continue;
        }

        let r64 = render(&g64, &cam, bg);
        let out64 = OutputGrads {
            rgb: &w64,
            alpha: None,
            depth: None,
        };
        let gr64 = backward(&g64, &cam, &r64, &out64, GradMask::ALL);
        let diffs: Vec<f64> = r64
            .image
            .data
            .iter()
            .zip(&image)
            .map(|(a, b)| (a - *b as f64).abs())
            .collect();
        let img_err = diffs.iter().fold(0.0f64, |m, d| m.max(*d));
        let img_mean = diffs.iter().sum::<f64>() / diffs.len() as f64;
        let img_over = diffs.iter().filter(|d| **d > 1e-3).count() as f64 / diffs.len() as f64;
        let a64 = gr64.gaussians.arrays();
        let a32 = gr32.gaussians.arrays();
        let sh64: Vec<f64> = a64[4].iter().chain(a64[5]).copied().collect();
        let sh32: Vec<f32> = a32[4].iter().chain(a32[5]).copied().collect();
        println!(
            "| {n} | {visible} | {pairs} | {:.1} | {:.1} | {:.1} | {:.2e} / {:.2e} / {:.4}% | {:.2e} | {:.2e} | {:.2e} | {:.2e} | {:.2e} |",
            t_fwd * 1e3,
            t_bwd * 1e3,
            (t_fwd + t_bwd) * 1e3,
            img_err,
            img_mean,
            100.0 * img_over,
            rel_err(a64[0], a32[0]),
            rel_err(a64[1], a32[1]),
            rel_err(a64[2], a32[2]),
            rel_err(a64[3], a32[3]),
            rel_err(&sh64, &sh32),
        );
    }
}
