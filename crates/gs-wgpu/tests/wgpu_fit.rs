//! Training on the GPU with gs-wgpu's `Trainer`: the test of tests/fit.rs (a random set
//! trained with L1 + D-SSIM towards renders of another scene) with parameters, gradients and
//! Adam moments on the GPU; it must converge as on the cpu backend, and a non-finite gradient
//! must stop it as on the cpu, the parameters unchanged. Needs a GPU adapter (lavapipe in CI).

/// The scenes and GPU contexts of gs-core's rasterizer tests, shared with them.
#[path = "../../gs-core/tests/common/mod.rs"]
mod common;

use std::ops::ControlFlow;

use common::{fit_lrs, gpu, random_scene, ring_views};
use gs_core::adam::AdamHyper;
use gs_core::image_loss::PhotometricObjective;
use gs_core::model::View;
use gs_core::sampler::ViewSampler;
use gs_core::train::{Objective, ObjectiveValue, TrainConfig, TrainError};
use gs_core::{GaussianSet, Image};
use gs_wgpu::backend::{Backend, Trainer};
use gs_wgpu::{render, GpuContext, GpuGaussians, GpuOptions};

/// The training device: a GPU context of its own (a [`Backend`] shares its context).
fn gpu_backend() -> Backend {
    let ctx = common::gpu_with(GpuOptions::default()).expect("an adapter, as gpu() found");
    Backend::Gpu(std::sync::Arc::new(ctx))
}

fn mean_loss(
    ctx: &GpuContext,
    model: &GaussianSet,
    views: &[View],
    obj: &mut PhotometricObjective,
) -> f32 {
    let uploaded = GpuGaussians::upload(ctx, model).unwrap();
    let total: f32 = views
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let image = render(ctx, &uploaded, &v.camera, [0.0; 3])
                .unwrap()
                .image(ctx);
            obj.evaluate(i, &image).unwrap().loss
        })
        .sum();
    total / views.len() as f32
}

#[test]
fn fitting_a_random_set_to_another_scene_lowers_the_loss_tenfold() {
    let Some(ctx) = gpu() else { return };
    let bg = [0.0; 3];
    let views = ring_views(8, 40);
    let target: GaussianSet = random_scene(1, 40, 1);
    let target_gpu = GpuGaussians::upload(ctx, &target).unwrap();
    let targets = views
        .iter()
        .map(|v| render(ctx, &target_gpu, &v.camera, bg).unwrap().image(ctx))
        .collect();
    let mut objective = PhotometricObjective::new(targets, 0.2);
    let model: GaussianSet = random_scene(2, 150, 1);
    let before = mean_loss(ctx, &model, &views, &mut objective);

    let backend = gpu_backend();
    let mut trainer =
        Trainer::new(&backend, model, fit_lrs().groups(), AdamHyper::default()).unwrap();
    let mut sampler = ViewSampler::new(views.len(), 5);
    let mut reports = 0;
    let config = TrainConfig {
        steps: 800,
        background: bg,
    };
    trainer
        .train(&views, &mut objective, &mut sampler, &config, |r| {
            reports += 1;
            assert_eq!(r.step, reports);
            ControlFlow::Continue(())
        })
        .unwrap();
    assert_eq!((trainer.step_count(), reports), (800, 800));
    let model = trainer.into_model();
    let after = mean_loss(ctx, &model, &views, &mut objective);
    assert!(after * 10.0 < before, "loss {before} -> {after}");
}

/// An objective whose gradient turns NaN at a chosen call.
struct PoisonAt(usize, usize);

impl Objective for PoisonAt {
    type Error = std::io::Error;
    fn evaluate(&mut self, _view: usize, image: &Image) -> Result<ObjectiveValue, Self::Error> {
        self.0 += 1;
        Ok(ObjectiveValue {
            loss: 1.0,
            terms: Vec::new(),
            grad: vec![if self.0 == self.1 { f32::NAN } else { 0.01 }; image.data.len()],
        })
    }
}

#[test]
fn a_non_finite_gradient_stops_the_run_with_the_parameters_of_the_step_before() {
    if gpu().is_none() {
        return;
    }
    let views = ring_views(2, 16);
    let start: GaussianSet = random_scene(3, 20, 0);
    let backend = gpu_backend();
    let run = |steps: u64, poison: usize| {
        let mut trainer = Trainer::new(
            &backend,
            start.clone(),
            fit_lrs().groups(),
            AdamHyper::default(),
        )
        .unwrap();
        let mut sampler = ViewSampler::new(2, 0);
        let mut objective = PoisonAt(0, poison);
        let result = (0..steps).try_for_each(|_| {
            trainer
                .step(&views, sampler.next_batch(), [0.0; 3], &mut objective)
                .map(drop)
        });
        (trainer.step_count(), trainer.into_model(), result)
    };
    let (taken, poisoned, result) = run(10, 3);
    let err = result.unwrap_err();
    assert!(
        matches!(
            err,
            TrainError::NonFinite {
                step: 3,
                what: "dL/dimage",
                ..
            }
        ),
        "{err}"
    );
    assert_eq!(taken, 2);
    let (_, clean, result) = run(2, usize::MAX);
    result.unwrap();
    assert_eq!(poisoned, clean);
    assert_ne!(clean, start, "two steps must have moved the parameters");
}
