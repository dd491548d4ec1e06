//! MiraGe's flat Gaussians built on the GPU (its `gpu_forward` kernels) against the cpu path
//! ([`BaseModel`]): the rendered log-scales exactly, the image, and the gradient of every
//! parameter group, with in-plane scales clamped at either bound, on a bound, and with frozen
//! groups. Needs a GPU adapter (lavapipe in CI).

use base_mirage::flat::{FlatGaussians, FLAT_SCALE};
use base_mirage::mirror::{plane_camera, plane_half_size};
use gs_core::gaussians::PARAM_NAMES;
use gs_core::model::{BaseModel, View};
use gs_core::raster::{backward, render, OutputGrads};
use gs_core::GaussianSet;
use gs_wgpu::{
    self as gpu, read_f32, test_context, GpuContext, GpuModel, GpuOptions, GpuParams, GpuScratch,
    GpuStep, ParameterBinding,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const W: u32 = 40;
const H: u32 = 28;

/// `n` (at least 15) flat Gaussians on the framed plane with scales inside, outside and on
/// the clamp's bounds.
fn model(n: usize) -> FlatGaussians {
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let (hw, hh) = plane_half_size(W, H, 1.0);
    let mut g = GaussianSet::zeros(n, 1);
    for i in 0..n {
        g.means[3 * i] = rng.random_range(-0.8 * hw..0.8 * hw) as f32;
        g.means[3 * i + 1] = rng.random_range(-0.05..0.05);
        g.means[3 * i + 2] = rng.random_range(-0.8 * hh..0.8 * hh) as f32;
        g.log_scales[3 * i + 1] = rng.random_range(-3.5..-2.0);
        g.log_scales[3 * i + 2] = rng.random_range(-3.5..-2.0);
        for q in 0..4 {
            g.quats[4 * i + q] = 1.0 + rng.random_range(-0.3..0.3);
        }
        g.opacity_logits[i] = rng.random_range(-1.0..2.0);
        for v in g.sh_dc[3 * i..3 * i + 3].iter_mut() {
            *v = rng.random_range(-1.0..1.0);
        }
        for v in g.sh_rest[9 * i..9 * i + 9].iter_mut() {
            *v = rng.random_range(-0.3..0.3);
        }
    }
    g.log_scales[4] = 0.4; // clamped above
    g.log_scales[8] = -19.0; // clamped below
    g.log_scales[10] = 0.0; // on the upper bound: passes
    g.log_scales[14] = FLAT_SCALE.ln() as f32; // on the lower bound: passes
    FlatGaussians::new(g)
}

/// A context with `options`, or `None` (the test is skipped) where there is no GPU adapter.
fn context(options: GpuOptions) -> Option<GpuContext> {
    test_context(options)
}

/// Within 1e-4 of the largest magnitude (f32 sums in another order, nothing more).
fn assert_close(what: &str, want: &[f32], got: &[f32]) {
    assert_eq!(want.len(), got.len(), "{what}: sizes");
    let max = want.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    for (k, (a, b)) in want.iter().zip(got).enumerate() {
        assert!(
            (a - b).abs() <= 1e-4 * max.max(1e-30),
            "{what}[{k}]: cpu {a} gpu {b} (largest {max})"
        );
    }
}

#[test]
fn the_gpu_construction_matches_the_cpu_one_forward_and_backward() {
    // Parameter blocks bound as uniforms (hardware adapters) and as read-only storage (software
    // ones), whichever adapter runs this.
    for binding in [ParameterBinding::Uniform, ParameterBinding::Storage] {
        let Some(ctx) = context(GpuOptions {
            parameter_binding: Some(binding),
            ..GpuOptions::default()
        }) else {
            return;
        };
        let mut model = model(30);
        let view = View::still(plane_camera(W, H, 1.0, false).unwrap());
        let bg = [0.1, 0.2, 0.3];
        let params = GpuParams::upload(&ctx, &mut model).unwrap();
        let mut scratch = GpuScratch::default();
        let mut step = GpuStep {
            ctx: &ctx,
            params: &params,
            scratch: &mut scratch,
        };
        let gaussians = model.gpu_forward(&mut step, &view).unwrap().gaussians;
        let renderable = model.renderable();
        assert_eq!(
            gaussians.download(&ctx),
            renderable,
            "rendered Gaussians, bit for bit"
        );

        let cpu_r = render(&renderable, &view.camera, bg);
        let gpu_r = gpu::render(&ctx, &gaussians, &view.camera, bg).unwrap();
        assert_close("image", &cpu_r.image.data, &gpu_r.image(&ctx).data);

        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let dl: Vec<f32> = (0..3 * W * H)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let out = OutputGrads {
            rgb: &dl,
            alpha: None,
            depth: None,
        };
        for trained in [[true; 6], [false, true, true, false, true, false]] {
            let mask = model.grad_mask(&trained);
            let cpu_grads = backward(&renderable, &view.camera, &cpu_r, &out, mask);
            let mut want: Vec<Vec<f32>> =
                model.group_lens().iter().map(|&n| vec![0.0; n]).collect();
            model
                .backward(&view, (), &cpu_grads.gaussians, &trained, &mut want)
                .unwrap();
            let gpu_grads = gpu::backward(&ctx, &gaussians, &gpu_r, &out, mask).unwrap();
            let got = model
                .gpu_backward(&mut step, &view, (), gpu_grads, &trained)
                .unwrap();
            for (k, name) in PARAM_NAMES.iter().enumerate() {
                let what = format!("trained {trained:?}: gradient of {name}");
                match &got[k] {
                    Some(buffer) => {
                        assert!(trained[k], "{what}: a frozen group got a gradient");
                        let got = read_f32(&ctx, buffer, want[k].len());
                        assert_close(&what, &want[k], &got);
                        if k == 1 {
                            for i in [0, 3, 4, 8] {
                                assert_eq!(got[i], 0.0, "{what}[{i}]: flat axis or clamped");
                            }
                            assert!(got[10] != 0.0 && got[14] != 0.0, "{what}: on a bound");
                        }
                    }
                    None => assert!(!trained[k], "{what}: missing"),
                }
            }
        }
    }
}

#[test]
fn the_construction_runs_in_chunks_past_the_binding_limit() {
    // 3 KiB bindings hold the log-scales of 256 Gaussians: 1000 are built in four chunks.
    let Some(ctx) = context(GpuOptions {
        max_binding_bytes: Some(3 * 1024),
        ..GpuOptions::default()
    }) else {
        return;
    };
    let mut model = model(1000);
    let view = View::still(plane_camera(W, H, 1.0, false).unwrap());
    let params = GpuParams::upload(&ctx, &mut model).unwrap();
    let mut scratch = GpuScratch::default();
    let mut step = GpuStep {
        ctx: &ctx,
        params: &params,
        scratch: &mut scratch,
    };
    let gaussians = model.gpu_forward(&mut step, &view).unwrap().gaussians;
    assert_eq!(
        gaussians.download(&ctx),
        model.renderable(),
        "rendered Gaussians, bit for bit"
    );
}
