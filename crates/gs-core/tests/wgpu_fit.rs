//! Fitting on the GPU: the test of tests/fit.rs (a random set trained with L1 + D-SSIM towards
//! renders of another scene) with parameters, gradients and Adam moments on the GPU and only
//! the image and dL/dimage crossing; it must converge as on the cpu backend. Needs a GPU adapter
//! (lavapipe in CI).
#![cfg(feature = "wgpu")]

mod common;

use common::{gpu, random_scene};
use gs_core::adam::{AdamHyper, LrSchedule};
use gs_core::image_loss::PhotometricObjective;
use gs_core::model::{BaseModel, GaussianLrs};
use gs_core::raster::{GradMask, OutputGrads};
use gs_core::train::{Objective, ViewSampler};
use gs_core::wgpu::{backward, render, GpuAdam, GpuContext, GpuGaussians};
use gs_core::{Camera, GaussianSet};

fn ring_views(count: usize, size: u32) -> Vec<Camera> {
    (0..count)
        .map(|i| {
            let a = i as f64 / count as f64 * std::f64::consts::TAU;
            let eye = [3.5 * a.cos(), -0.8, 3.5 * a.sin()];
            Camera::look_at(eye, [0.0; 3], [0.0, -1.0, 0.0], 0.9, size, size).unwrap()
        })
        .collect()
}

fn mean_loss(
    ctx: &GpuContext,
    model: &GpuGaussians,
    views: &[Camera],
    obj: &mut PhotometricObjective,
) -> f32 {
    let total: f32 = views
        .iter()
        .enumerate()
        .map(|(i, cam)| {
            let image = render(ctx, model, cam, [0.0; 3]).unwrap().image(ctx);
            obj.evaluate(i, &image).unwrap().loss
        })
        .sum();
    total / views.len() as f32
}

#[test]
fn fitting_a_random_set_to_another_scene_lowers_the_loss_tenfold() {
    let ctx = gpu();
    let bg = [0.0; 3];
    let views = ring_views(8, 40);
    let target: GaussianSet = random_scene(1, 40, 1);
    let target_gpu = GpuGaussians::upload(ctx, &target).unwrap();
    let targets = views
        .iter()
        .map(|cam| render(ctx, &target_gpu, cam, bg).unwrap().image(ctx))
        .collect();
    let mut objective = PhotometricObjective {
        targets,
        lambda: 0.2,
    };
    let initial: GaussianSet = random_scene(2, 150, 1);
    let model = GpuGaussians::upload(ctx, &initial).unwrap();
    let before = mean_loss(ctx, &model, &views, &mut objective);

    let lrs = GaussianLrs {
        means: LrSchedule::Constant(0.004),
        scales: 0.01,
        rotations: 0.01,
        opacities: 0.05,
        feature: 0.05,
    };
    let mut adam = GpuAdam::new(
        ctx,
        lrs.groups(),
        &initial.group_lens(),
        AdamHyper::default(),
    )
    .unwrap();
    let mut sampler = ViewSampler::new(views.len(), 5);
    for _ in 0..800 {
        let v = sampler.next_view();
        let rendered = render(ctx, &model, &views[v], bg).unwrap();
        let value = objective.evaluate(v, &rendered.image(ctx)).unwrap();
        assert!(value.loss.is_finite());
        let out = OutputGrads {
            rgb: &value.grad,
            alpha: None,
            depth: None,
        };
        let grads = backward(ctx, &model, &rendered, &out, GradMask::ALL).unwrap();
        adam.step(ctx, &model.buffers(), &grads.buffers());
    }
    let after = mean_loss(ctx, &model, &views, &mut objective);
    assert!(after * 10.0 < before, "loss {before} -> {after}");
}
