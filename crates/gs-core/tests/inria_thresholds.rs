//! The cpu (f64 and f32) and wgpu rasterizers against INRIA's, Gaussian by Gaussian, on scenes
//! built to sit at each rule that decides whether a Gaussian is drawn at a pixel
//! (`scripts/make_raster_thresholds_fixture.py`: Gaussians past the right and bottom edges whose
//! tile rectangle INRIA keeps, tiny splats at window and tile edges, alpha just above and below
//! 1/255, pixels that stop at transmittance 1e-4, depths either side of the near plane; picture
//! sizes that are and are not multiples of the tile).
//!
//! The reference is INRIA's `diff-gaussian-rasterization` transcribed in float64 PyTorch, the
//! renderer of every modality's authors, differentiated as its hand-written backward does (the
//! gradient through the alpha cap, the Jacobian's clamp, the `1e-7` of the conic's gradient).
//! A Gaussian that one side moves and the other leaves (a gradient exactly zero on one side
//! only) fails by name; every other gradient must agree to the precision of the backend. The
//! wgpu tests need an adapter (lavapipe in CI).

mod common;

use std::collections::HashMap;
use std::path::PathBuf;

use gs_core::raster::{backward, render, GradMask, OutputGrads};
use gs_core::{Camera, GaussianSet, Real};
use safetensors::{Dtype, SafeTensors};
use serde_json::Value;

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/inria_thresholds")
}

/// One scene of the fixture.
struct Case {
    name: String,
    camera: Camera,
    background: [f64; 3],
    /// What each Gaussian was placed for (`random`, `past_right_edge`, ...).
    kinds: Vec<String>,
    gaussians: GaussianSet<f64>,
    /// dL/dRGB, `[H, W, 3]`.
    out_grad: Vec<f64>,
    /// INRIA's picture `[H, W, 3]` and alpha `[H, W]`.
    rgb: Vec<f64>,
    alpha: Vec<f64>,
    /// INRIA's gradients by our group names, in our layouts.
    grads: HashMap<&'static str, Vec<f64>>,
}

/// Our group names, INRIA's, and the values per Gaussian.
const GROUPS: [(&str, &str, usize); 6] = [
    ("means", "xyz", 3),
    ("scales", "scaling", 3),
    ("rotations", "rotation", 4),
    ("opacities", "opacity", 1),
    ("sh_dc", "f_dc", 3),
    ("sh_rest", "f_rest", 45),
];

fn values(tensors: &SafeTensors, name: &str) -> Vec<f64> {
    let t = tensors
        .tensor(name)
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    match t.dtype() {
        Dtype::F32 => t
            .data()
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes(b.try_into().unwrap()) as f64)
            .collect(),
        Dtype::F64 => t
            .data()
            .chunks_exact(8)
            .map(|b| f64::from_le_bytes(b.try_into().unwrap()))
            .collect(),
        other => panic!("{name}: {other:?}"),
    }
}

fn load_cases() -> Vec<Case> {
    let index: Value =
        serde_json::from_str(&std::fs::read_to_string(fixtures().join("cases.json")).unwrap())
            .unwrap();
    index["cases"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            let name = c["name"].as_str().unwrap().to_string();
            let bytes = std::fs::read(fixtures().join(format!("{name}.safetensors"))).unwrap();
            let tensors = SafeTensors::deserialize(&bytes).unwrap();
            let (width, height) = (
                c["width"].as_u64().unwrap() as u32,
                c["height"].as_u64().unwrap() as u32,
            );
            let w2c: Vec<Vec<f64>> = serde_json::from_value(c["w2c"].clone()).unwrap();
            // INRIA's camera: focal from the horizontal field of view, the same vertically,
            // principal point at the centre.
            let fx = width as f64 / (2.0 * (c["fov_x"].as_f64().unwrap() / 2.0).tan());
            let camera = Camera {
                rotation: std::array::from_fn(|r| std::array::from_fn(|k| w2c[r][k])),
                translation: std::array::from_fn(|r| w2c[r][3]),
                fx,
                fy: fx,
                cx: width as f64 / 2.0,
                cy: height as f64 / 2.0,
                width,
                height,
            };
            let kinds: Vec<String> = serde_json::from_value(c["kinds"].clone()).unwrap();
            let mut gaussians = GaussianSet::<f64>::zeros(kinds.len(), 3);
            for (ours, (_, inria, _)) in gaussians.arrays_mut().into_iter().zip(GROUPS) {
                *ours = values(&tensors, &format!("param.{inria}"));
            }
            gaussians.check_shapes().unwrap();
            let grads = GROUPS
                .iter()
                .map(|&(ours, inria, _)| (ours, values(&tensors, &format!("grad.{inria}"))))
                .collect();
            let background: Vec<f64> = serde_json::from_value(c["background"].clone()).unwrap();
            Case {
                name,
                camera,
                background: background.try_into().unwrap(),
                kinds,
                gaussians,
                out_grad: values(&tensors, "out_grad"),
                rgb: values(&tensors, "rgb"),
                alpha: values(&tensors, "alpha"),
                grads,
            }
        })
        .collect()
}

/// How closely a backend must follow INRIA's float64 rasterizer: each Gaussian's gradient of a
/// group within `relative` of its size or of `floor` times the largest of its kind in the group
/// (so that the placed Gaussians, whose gradients are small, are held to their own size), and
/// the picture
/// within `picture` everywhere.
struct Tolerance {
    relative: f64,
    floor: f64,
    picture: f64,
}

/// The failures of `ours` (gradients in our layout, [`GaussianSet::arrays`] order), the picture
/// and alpha `(rgb, alpha)` against the case's reference, one line each.
fn compare(
    case: &Case,
    backend: &str,
    picture: (&[f64], &[f64]),
    ours: [Vec<f64>; 6],
    tol: &Tolerance,
) -> Vec<String> {
    let mut failures = Vec::new();
    for (what, want, got) in [
        ("picture", &case.rgb, picture.0),
        ("alpha", &case.alpha, picture.1),
    ] {
        let (worst, at) = want
            .iter()
            .zip(got)
            .map(|(a, b)| (a - b).abs())
            .enumerate()
            .fold((0.0, 0), |m, (i, d)| if d > m.0 { (d, i) } else { m });
        if worst > tol.picture {
            failures.push(format!(
                "{} {backend}: {what} differs by {worst:.2e} at entry {at}",
                case.name
            ));
        }
    }
    for ((group, _, width), got) in GROUPS.iter().zip(ours) {
        let want = &case.grads[group];
        assert_eq!(want.len(), got.len(), "{group}: sizes");
        let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
        // The largest gradient of each kind: the floor of a Gaussian's error is its kind's, so
        // that the placed Gaussians, whose gradients are small, are held to their own size.
        let mut largest: HashMap<&str, f64> = HashMap::new();
        for (w, kind) in want.chunks_exact(*width).zip(&case.kinds) {
            let l = largest.entry(kind.as_str()).or_insert(0.0);
            *l = l.max(norm(w));
        }
        for (i, (w, g)) in want
            .chunks_exact(*width)
            .zip(got.chunks_exact(*width))
            .enumerate()
        {
            let kind = &case.kinds[i];
            let (nw, ng) = (norm(w), norm(g));
            let line =
                |what: String| format!("{} {backend}: Gaussian {i} ({kind}): {what}", case.name);
            if nw > 0.0 && ng == 0.0 {
                failures.push(line(format!(
                    "{group} moved by INRIA's rasterizer (gradient {nw:.2e}), not by ours"
                )));
            } else if nw == 0.0 && ng > 0.0 {
                failures.push(line(format!(
                    "{group} moved by ours (gradient {ng:.2e}), not by INRIA's rasterizer"
                )));
            } else {
                let diff: Vec<f64> = w.iter().zip(g).map(|(a, b)| a - b).collect();
                let floor = tol.floor * largest[kind.as_str()];
                let error = norm(&diff) / nw.max(floor).max(f64::MIN_POSITIVE);
                if error > tol.relative {
                    failures.push(line(format!(
                        "{group} gradient off by {error:.2e} (INRIA {w:?}, ours {g:?})"
                    )));
                }
            }
        }
    }
    failures
}

/// The gradient of a loss of the picture alone.
fn rgb_only<T: Real>(rgb: &[T]) -> OutputGrads<'_, T> {
    OutputGrads {
        rgb,
        alpha: None,
        depth: None,
    }
}

fn to_f64<T: Real>(v: &[T]) -> Vec<f64> {
    v.iter().map(|x| x.to_f64()).collect()
}

/// The cpu backend in precision `T` on every case.
fn cpu_failures<T: Real>(backend: &str, tol: &Tolerance) -> Vec<String> {
    let mut failures = Vec::new();
    for case in load_cases() {
        let g: GaussianSet<T> = case.gaussians.cast();
        let bg = case.background.map(T::from_f64);
        let out_grad: Vec<T> = case.out_grad.iter().map(|&v| T::from_f64(v)).collect();
        let rendered = render(&g, &case.camera, bg);
        let grads = backward(
            &g,
            &case.camera,
            &rendered,
            &rgb_only(&out_grad),
            GradMask::ALL,
        );
        let ours = grads.gaussians.arrays().map(to_f64);
        failures.extend(compare(
            &case,
            backend,
            (&to_f64(&rendered.image.data), &to_f64(&rendered.alpha)),
            ours,
            tol,
        ));
    }
    failures
}

fn assert_none(failures: Vec<String>) {
    assert!(
        failures.is_empty(),
        "{} differences from INRIA's rasterizer:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

/// In float64 the gradients agree to the order of sums (the worst 1e-9 of a Gaussian's), the
/// picture to the fixture's float32 storage.
#[test]
fn cpu_f64_draws_and_differentiates_each_gaussian_as_inria() {
    assert_none(cpu_failures::<f64>(
        "cpu f64",
        &Tolerance {
            relative: 1e-8,
            floor: 1e-6,
            picture: 1e-7,
        },
    ));
}

/// In float32 the worst Gaussian is 3e-4 of its gradient away (or of 1e-3 of the largest of its
/// kind), the picture 2.5e-5 (of Gaussians 0.2 in front of the camera); wgpu the same.
#[test]
fn cpu_f32_draws_and_differentiates_each_gaussian_as_inria() {
    assert_none(cpu_failures::<f32>(
        "cpu f32",
        &Tolerance {
            relative: 1e-3,
            floor: 1e-3,
            picture: 1e-4,
        },
    ));
}

#[test]
fn wgpu_draws_and_differentiates_each_gaussian_as_inria() {
    let Some(ctx) = common::gpu() else { return };
    let tol = Tolerance {
        relative: 1e-3,
        floor: 1e-3,
        picture: 1e-4,
    };
    let mut failures = Vec::new();
    for case in load_cases() {
        let g: GaussianSet<f32> = case.gaussians.cast();
        let bg = case.background.map(|v| v as f32);
        let out_grad: Vec<f32> = case.out_grad.iter().map(|&v| v as f32).collect();
        let gg = gs_wgpu::GpuGaussians::upload(ctx, &g).expect("upload");
        let rendered = gs_wgpu::render(ctx, &gg, &case.camera, bg).expect("render");
        let picture = (
            to_f64(&rendered.image(ctx).data),
            to_f64(&rendered.alpha(ctx)),
        );
        let grads = gs_wgpu::backward(ctx, &gg, &rendered, &rgb_only(&out_grad), GradMask::ALL)
            .expect("backward")
            .download(ctx);
        failures.extend(compare(
            &case,
            "wgpu",
            (&picture.0, &picture.1),
            grads.gaussians.arrays().map(to_f64),
            &tol,
        ));
    }
    assert_none(failures);
}

/// The fixture holds a Gaussian of every kind that INRIA draws, so that a rule that drops one
/// fails above (a fixture regenerated without them would pass vacuously).
#[test]
fn every_kind_of_threshold_gaussian_is_drawn_somewhere() {
    let cases = load_cases();
    for kind in [
        "past_right_edge",
        "past_bottom_edge",
        "near_left_edge",
        "near_top_edge",
        "tiny",
        "alpha_above",
        "stop",
        "near_plane",
    ] {
        let drawn = cases.iter().any(|c| {
            c.kinds
                .iter()
                .enumerate()
                .any(|(i, k)| k == kind && c.grads["opacities"][i] != 0.0)
        });
        assert!(drawn, "no {kind} Gaussian of the fixture is drawn");
    }
    let undrawn_below = cases.iter().all(|c| {
        c.kinds
            .iter()
            .enumerate()
            .all(|(i, k)| k != "alpha_below" || c.grads["opacities"][i] == 0.0)
    });
    assert!(undrawn_below, "an alpha_below Gaussian is drawn");
}

/// A camera at the origin looking along +z whose pixel (8, 8) has its centre on the z axis.
fn axis_camera() -> Camera {
    Camera {
        rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        translation: [0.0; 3],
        fx: 20.0,
        fy: 20.0,
        cx: 8.5,
        cy: 8.5,
        width: 17,
        height: 17,
    }
}

/// One opaque Gaussian of SH degree 0 on the z axis, of degree-0 coefficient `dc` in every
/// channel.
fn gaussian_of_colour<T: Real>(dc: T) -> GaussianSet<T> {
    let mut g = GaussianSet::<T>::zeros(1, 0);
    g.means[2] = T::from_f64(3.0);
    g.log_scales.fill(T::from_f64(0.2f64.ln()));
    g.opacity_logits[0] = T::from_f64(2.0);
    g.sh_dc.fill(dc);
    g
}

/// The colour gradient of a Gaussian whose colour is exactly 0: INRIA cuts it only where
/// `SH + 0.5 < 0` (`clamped`), so at 0 it passes.
fn colour_gradient_at_zero<T: Real>(dc: T) -> f64 {
    let g = gaussian_of_colour(dc);
    let camera = axis_camera();
    let colour = T::from_f64(gs_core::sh::C0) * dc + T::from_f64(0.5);
    assert!(colour == T::ZERO, "the colour is exactly 0");
    let rendered = render(&g, &camera, [T::ZERO; 3]);
    let ones = vec![T::ONE; 3 * camera.pixel_count()];
    let grads = backward(&g, &camera, &rendered, &rgb_only(&ones), GradMask::ALL);
    grads.gaussians.sh_dc[0].to_f64()
}

#[test]
fn a_colour_of_exactly_zero_passes_its_gradient_as_inria() {
    let c0 = gs_core::sh::C0;
    // The degree-0 coefficients whose colour rounds to exactly 0, among the neighbours of
    // -0.5 / C0 in each precision.
    let start32 = (-0.5 / c0) as f32;
    let dc32 = (-64i32..=64)
        .map(|k| f32::from_bits((start32.to_bits() as i32 + k) as u32))
        .find(|&dc| (c0 as f32) * dc + 0.5 == 0.0)
        .expect("an f32 coefficient of colour 0");
    let start64 = -0.5 / c0;
    let dc64 = (-64i64..=64)
        .map(|k| f64::from_bits((start64.to_bits() as i64 + k) as u64))
        .find(|&dc| c0 * dc + 0.5 == 0.0)
        .expect("an f64 coefficient of colour 0");
    assert!(colour_gradient_at_zero(dc32) > 0.0, "f32");
    assert!(colour_gradient_at_zero(dc64) > 0.0, "f64");
    // Just below 0 the clamp cuts it.
    let below = f64::from_bits(dc64.to_bits() + 1);
    assert!(c0 * below + 0.5 < 0.0);
    let g = gaussian_of_colour(below);
    let rendered = render(&g, &axis_camera(), [0.0; 3]);
    let ones = vec![1.0; 3 * axis_camera().pixel_count()];
    let grads = backward(
        &g,
        &axis_camera(),
        &rendered,
        &rgb_only(&ones),
        GradMask::ALL,
    );
    assert_eq!(grads.gaussians.sh_dc[0], 0.0);
}
