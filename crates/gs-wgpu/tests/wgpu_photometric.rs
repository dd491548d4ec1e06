//! The photometric loss on the device (`gs_wgpu::photometric`) against gs-core's
//! `PhotometricObjective` (in a `ClampedObjective` for the clamped render) on the same render
//! read back: the loss, its terms, dL/dimage and the PSNR's squared error, for images smaller
//! than the window and larger than a workgroup, with values exactly 0 and 1 and above 1 (the
//! clamp's ends pass the gradient, the outside does not), exact ties of render and target (L1's
//! zero), every D-SSIM weight and a batch factor; and a GPU training run with the loss on the
//! device against the same run with it on the host. Needs a GPU adapter (lavapipe in CI).

/// The scenes and GPU contexts of gs-core's rasterizer tests, shared with them.
#[path = "../../gs-core/tests/common/mod.rs"]
mod common;

use std::ops::ControlFlow;

use common::{
    fit_lrs, gpu, gpu_per_parameter_binding, gpu_with, oblique_camera, random_scene, ring_views,
};
use gs_core::adam::{AdamHyper, LrSchedule};
use gs_core::image_loss::{psnr, PhotometricObjective, PsnrLog};
use gs_core::model::GaussianLrs;
use gs_core::render_clamp::{ClampedObjective, RenderClamp};
use gs_core::sampler::{BatchOrder, ViewSampler};
use gs_core::train::{Objective, ObjectiveValue, TrainConfig};
use gs_core::{Camera, GaussianSet, GsError, Image};
use gs_wgpu::backend::{Backend, Trainer};
use gs_wgpu::{photometric, read_f32, render, upload_target, GpuContext, GpuGaussians, GpuOptions};

/// The GPU render of a random scene whose brightest colours pass 1 over `background`, and the
/// render read back.
fn rendered(
    ctx: &GpuContext,
    seed: u64,
    camera: &Camera,
    background: [f32; 3],
) -> (gs_wgpu::GpuRendered, Image) {
    let mut g = random_scene::<f32>(seed, 40, 1);
    // Bright opaque Gaussians: colours above 1.
    for k in (0..g.len()).step_by(4) {
        g.sh_dc[3 * k..3 * k + 3].fill(6.0);
        g.opacity_logits[k] = 5.0;
    }
    let gg = GpuGaussians::upload(ctx, &g).expect("upload");
    let r = render(ctx, &gg, camera, background).expect("render");
    let image = r.image(ctx);
    (r, image)
}

/// A target: the render itself on the left half (ties), a perturbed copy on the right.
fn target_of(image: &Image, seed: u64) -> Image {
    let w = image.width as usize;
    let mut data = image.data.clone();
    for (i, v) in data.iter_mut().enumerate() {
        let x = (i / 3) % w;
        if x >= w / 2 {
            let h = ((i as u64 * 2654435761 + seed) % 1000) as f32 / 1000.0;
            *v = (0.7 * *v + 0.3 * h).clamp(0.0, 1.0);
        }
    }
    Image {
        width: image.width,
        height: image.height,
        data,
    }
}

/// Within `tol` of the largest magnitude of `want`, entry by entry.
fn assert_close(what: &str, want: &[f32], got: &[f32], tol: f32) {
    assert_eq!(want.len(), got.len(), "{what}: sizes");
    let max = want.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    for (k, (a, b)) in want.iter().zip(got).enumerate() {
        assert!(
            (a - b).abs() <= tol * max.max(1e-30),
            "{what}[{k}]: cpu {a} gpu {b} (largest {max})"
        );
    }
}

/// The device's loss against gs-core's on one render.
fn check(ctx: &GpuContext, case: &str, camera: &Camera, background: [f32; 3], lambda: f32) {
    let (r, image) = rendered(ctx, 7, camera, background);
    let target = target_of(&image, 3);
    let target_gpu = upload_target(ctx, &target).expect("upload");
    for clamp in [RenderClamp::Off, RenderClamp::Unit] {
        let case = format!("{case}, lambda {lambda}, {clamp:?}");
        let mut objective = PhotometricObjective::new(vec![target.clone()], lambda);
        let want = ClampedObjective::new(&mut objective, clamp)
            .evaluate(0, &image)
            .expect("cpu objective");
        for factor in [1.0f32, 0.5] {
            let got = photometric(ctx, &r, &target_gpu, lambda, clamp, factor).expect("device");
            let value = got.sums.value(lambda);
            assert!(
                (value.loss - want.loss).abs() <= 5e-5 * want.loss.abs().max(1e-3),
                "{case}: loss cpu {} gpu {}",
                want.loss,
                value.loss
            );
            for ((name, w), (n2, g)) in want.terms.iter().zip(&value.terms) {
                assert_eq!(name, n2);
                assert!(
                    (w - g).abs() <= 5e-5 * w.abs().max(1e-3),
                    "{case}: {name} {w} {g}"
                );
            }
            let grad = read_f32(ctx, &got.grad, image.data.len());
            let scaled: Vec<f32> = want.grad.iter().map(|g| g * factor).collect();
            assert_close(
                &format!("{case}: dL/dimage x {factor}"),
                &scaled,
                &grad,
                1e-4,
            );
            // The clamp's ends pass the gradient, the outside does not; ties get L1's zero.
            for (i, (&x, &g)) in image.data.iter().zip(&grad).enumerate() {
                if clamp == RenderClamp::Unit && !(0.0..=1.0).contains(&x) {
                    assert_eq!(g, 0.0, "{case}: value {i} ({x}) outside [0, 1]");
                }
            }
            let db = psnr(&image, &target);
            let device_db = gs_core::image_loss::psnr_of_mse(got.sums.mse);
            assert!(
                (db - device_db).abs() < 1e-3,
                "{case}: PSNR {db} {device_db}"
            );
        }
    }
    // The cases the test is for are there (on images large enough to show them): values above
    // 1, and the bare background, exactly 0 or 1.
    if camera.pixel_count() >= 1000 {
        assert!(
            image.data.iter().any(|&x| x > 1.0),
            "{case}: no value above 1"
        );
        assert!(
            image.data.iter().any(|&x| x == background[0]),
            "{case}: no bare background"
        );
    }
}

#[test]
fn the_device_loss_is_gs_cores_on_every_size_weight_and_clamp() {
    let Some(ctx) = gpu() else { return };
    for (w, h) in [(5, 3), (16, 16), (37, 29), (70, 41)] {
        let camera = oblique_camera(w, h);
        for (background, lambda) in [
            ([0.0; 3], 0.2),
            ([1.0; 3], 0.2),
            ([0.0; 3], 0.0),
            ([1.0; 3], 1.0),
        ] {
            check(
                ctx,
                &format!("{w}x{h} over {background:?}"),
                &camera,
                background,
                lambda,
            );
        }
    }
}

#[test]
fn the_device_loss_is_the_same_with_parameter_blocks_bound_either_way() {
    for ctx in gpu_per_parameter_binding(GpuOptions::default()) {
        let binding = ctx.parameter_binding();
        check(
            &ctx,
            &format!("{binding:?}"),
            &oblique_camera(37, 29),
            [1.0; 3],
            0.2,
        );
    }
}

/// The same objective with its device form hidden: the trainer brings each render to the host.
struct OnTheHost<O>(O);

impl<O: Objective> Objective for OnTheHost<O> {
    type Error = O::Error;
    fn evaluate(&mut self, view: usize, image: &Image) -> Result<ObjectiveValue, Self::Error> {
        self.0.evaluate(view, image)
    }
}

/// `steps` steps of batches of `batch` views, the loss on the device or on the host: the
/// losses of every step, the PSNR log and the parameters at the end.
fn train(
    device_loss: bool,
    batch: usize,
    steps: u64,
) -> (Vec<f32>, Vec<(usize, f64)>, GaussianSet) {
    let ctx = gpu_with(GpuOptions::default()).expect("an adapter, as gpu() found");
    let backend = Backend::Gpu(std::sync::Arc::new(ctx));
    let views = ring_views(4, 24);
    let target: GaussianSet = random_scene(1, 30, 1);
    let target_gpu = match &backend {
        Backend::Gpu(ctx) => GpuGaussians::upload(ctx, &target).unwrap(),
        Backend::Cpu => unreachable!(),
    };
    let targets = views
        .iter()
        .map(|v| match &backend {
            Backend::Gpu(ctx) => render(ctx, &target_gpu, &v.camera, [1.0; 3])
                .unwrap()
                .image(ctx),
            Backend::Cpu => unreachable!(),
        })
        .collect();
    let mut log = PsnrLog {
        inner: PhotometricObjective::new(targets, 0.2),
        log: Vec::new(),
    };
    let lrs = fit_lrs();
    let start: GaussianSet = random_scene(2, 60, 1);
    let mut trainer = Trainer::new(&backend, start, lrs.groups(), AdamHyper::default()).unwrap();
    let mut sampler = ViewSampler::batches(4, batch, BatchOrder::Shuffled, 9);
    let config = TrainConfig {
        steps,
        background: [1.0; 3],
    };
    let mut losses = Vec::new();
    let mut on_step = |r: &gs_core::train::StepReport| {
        losses.push(r.value.loss);
        ControlFlow::Continue(())
    };
    let result = if device_loss {
        let mut clamped = ClampedObjective::new(&mut log, RenderClamp::Unit);
        trainer.train(&views, &mut clamped, &mut sampler, &config, &mut on_step)
    } else {
        let mut host = OnTheHost(ClampedObjective::new(&mut log, RenderClamp::Unit));
        trainer.train(&views, &mut host, &mut sampler, &config, &mut on_step)
    };
    result.expect("training");
    (losses, log.log, trainer.into_model())
}

#[test]
fn training_with_the_loss_on_the_device_is_training_with_it_on_the_host() {
    if gpu().is_none() {
        return;
    }
    for batch in [1, 2] {
        let (device_losses, device_log, device_model) = train(true, batch, 30);
        let (host_losses, host_log, host_model) = train(false, batch, 30);
        for (step, (d, h)) in device_losses.iter().zip(&host_losses).enumerate() {
            assert!(
                (d - h).abs() <= 1e-4 * h.abs(),
                "batch {batch}, step {}: loss on the device {d}, on the host {h}",
                step + 1
            );
        }
        assert_eq!(device_log.len(), host_log.len());
        for ((dv, dp), (hv, hp)) in device_log.iter().zip(&host_log) {
            assert_eq!(dv, hv);
            assert!(
                (dp - hp).abs() < 1e-2,
                "PSNR on the device {dp}, on the host {hp}"
            );
        }
        for (name, (d, h)) in gs_core::gaussians::PARAM_NAMES
            .iter()
            .zip(device_model.arrays().into_iter().zip(host_model.arrays()))
        {
            assert_close(&format!("batch {batch}: {name}"), h, d, 1e-3);
        }
    }
}

#[test]
fn a_target_of_another_size_is_refused_as_on_the_host() {
    let Some(ctx) = gpu_with(GpuOptions::default()) else {
        return;
    };
    let backend = Backend::Gpu(std::sync::Arc::new(ctx));
    let views = ring_views(2, 16);
    let targets = vec![
        Image::filled(16, 16, [0.5; 3]),
        Image::filled(12, 16, [0.5; 3]),
    ];
    let mut objective = PhotometricObjective::new(targets, 0.2);
    let start: GaussianSet = random_scene(2, 10, 0);
    let groups = GaussianLrs {
        means: LrSchedule::Constant(0.0),
        scales: 0.0,
        rotations: 0.0,
        opacities: 0.0,
        feature: 0.0,
    }
    .groups();
    let mut trainer = Trainer::new(&backend, start, groups, AdamHyper::default()).unwrap();
    let mut sampler = ViewSampler::batches(2, 2, BatchOrder::Consecutive, 0);
    let e = trainer
        .step(&views, sampler.next_batch(), [0.0; 3], &mut objective)
        .unwrap_err()
        .to_string();
    let host = GsError::SizeMismatch {
        view: 1,
        render_w: 16,
        render_h: 16,
        target_w: 12,
        target_h: 16,
    }
    .to_string();
    assert!(e.contains(&host), "{e}");
}

#[test]
fn a_non_finite_image_gradient_stops_the_step_as_on_the_cpu() {
    // A Gaussian of colour 2.8e18: its squares (7.9e36) stay finite, SSIM's denominator does not,
    // so the loss is finite and SSIM's gradient NaN where it shows.
    let Some(ctx) = gpu_with(GpuOptions::default()) else {
        return;
    };
    let views = ring_views(2, 24);
    let mut start: GaussianSet = random_scene(4, 20, 0);
    start.sh_dc[..3].fill(1e19);
    start.opacity_logits[0] = 5.0;
    let groups = GaussianLrs {
        means: LrSchedule::Constant(0.001),
        scales: 0.01,
        rotations: 0.01,
        opacities: 0.01,
        feature: 0.01,
    }
    .groups();
    let targets = vec![Image::filled(24, 24, [0.5; 3]); 2];
    let mut errors = Vec::new();
    for backend in [Backend::Cpu, Backend::Gpu(std::sync::Arc::new(ctx))] {
        let mut trainer = Trainer::new(
            &backend,
            start.clone(),
            groups.clone(),
            AdamHyper::default(),
        )
        .unwrap();
        let mut objective = PhotometricObjective::new(targets.clone(), 0.2);
        let mut sampler = ViewSampler::batches(2, 2, BatchOrder::Consecutive, 0);
        let e = trainer
            .step(&views, sampler.next_batch(), [0.0; 3], &mut objective)
            .expect_err("a NaN gradient of the image");
        errors.push(e.to_string());
        assert_eq!(trainer.step_count(), 0, "the parameters stay");
    }
    assert!(errors[0].contains("dL/dimage"), "{}", errors[0]);
    assert_eq!(errors[0], errors[1], "cpu and GPU stop alike");
}
