//! A render clamped to `[0, 1]` before the loss ([`RenderClamp::Unit`], INRIA 3DGS's
//! `render()`), in the training loop on the cpu and on wgpu: the loss sees the clamped values,
//! and a Gaussian whose every pixel is above 1 gets no gradient (PyTorch's `clamp` backward), so
//! it does not move; without the clamp it does. Needs a GPU adapter (lavapipe in CI).

mod common;

use std::ops::ControlFlow;
use std::sync::Arc;

use gs_core::adam::{AdamHyper, GroupConfig, LrSchedule};
use gs_core::model::{BaseModel, View};
use gs_core::render_clamp::{ClampedObjective, RenderClamp};
use gs_core::sampler::ViewSampler;
use gs_core::train::{Objective, ObjectiveValue, TrainConfig};
use gs_core::{GaussianSet, Image};
use gs_wgpu::backend::{Backend, Trainer};
use gs_wgpu::{test_context, GpuOptions};

/// L = sum of the render; records the largest value it saw.
struct Sum {
    largest: f32,
}

impl Objective for Sum {
    type Error = std::convert::Infallible;
    fn evaluate(&mut self, _view: usize, image: &Image) -> Result<ObjectiveValue, Self::Error> {
        self.largest = image.data.iter().fold(f32::MIN, |m, &x| m.max(x));
        Ok(ObjectiveValue {
            loss: image.data.iter().sum(),
            terms: Vec::new(),
            grad: vec![1.0; image.data.len()],
        })
    }
}

/// One bright Gaussian (colour about 2.3 in every channel) in front of the camera: over a
/// white background every pixel it reaches is above 1, every other pixel exactly 1.
fn bright_gaussian() -> GaussianSet {
    GaussianSet::from_arrays(
        vec![0.0, 0.0, 0.0],
        vec![-1.2; 3],
        vec![1.0, 0.0, 0.0, 0.0],
        vec![1.5],
        &[6.5, 6.5, 6.5],
    )
    .unwrap()
}

/// The model after one step of `clamp` on `backend`, and the largest value the loss saw.
fn one_step(backend: &Backend, clamp: RenderClamp) -> (GaussianSet, f32) {
    let model = bright_gaussian();
    let groups = model
        .group_names()
        .iter()
        .map(|n| GroupConfig::new(n.clone(), LrSchedule::Constant(0.01)))
        .collect();
    let views = vec![View::still(common::front_camera(24, 20))];
    let mut trainer = Trainer::new(backend, model, groups, AdamHyper::default()).unwrap();
    let mut sum = Sum { largest: 0.0 };
    trainer
        .train(
            &views,
            &mut ClampedObjective::new(&mut sum, clamp),
            &mut ViewSampler::new(1, 0),
            &TrainConfig {
                steps: 1,
                background: [1.0; 3],
            },
            |_| ControlFlow::Continue(()),
        )
        .unwrap();
    (trainer.into_model(), sum.largest)
}

/// The cpu and wgpu backends, or `None` (the test is skipped) where there is no GPU adapter.
fn backends() -> Option<[Backend; 2]> {
    let ctx = test_context(GpuOptions::default())?;
    Some([Backend::Cpu, Backend::Gpu(Arc::new(ctx))])
}

#[test]
fn a_clamped_render_gives_no_gradient_above_1_on_the_cpu_and_on_wgpu() {
    let start = bright_gaussian();
    let Some(backends) = backends() else {
        return;
    };
    for backend in backends {
        let name = backend.describe();
        let (raw, largest_raw) = one_step(&backend, RenderClamp::Off);
        assert!(
            largest_raw > 1.5,
            "{name}: the render exceeds 1 ({largest_raw})"
        );
        assert_ne!(raw, start, "{name}: unclamped, the loss moves the Gaussian");

        let (clamped, largest) = one_step(&backend, RenderClamp::Unit);
        assert_eq!(largest, 1.0, "{name}: the loss sees the clamped render");
        assert_eq!(
            clamped, start,
            "{name}: every pixel of the Gaussian is above 1, so no gradient reaches it"
        );
    }
}
