//! The gradient where a splat's alpha is capped at 0.99: INRIA's rasterizer (and so the code of
//! every modality's authors) differentiates `opacity * exp(-sigma)` as if uncapped, where the
//! exact derivative is zero. One opaque Gaussian whose centre falls on a pixel centre, and a
//! loss that reads that pixel only: alpha there is `min(0.99, sigmoid(9)) = 0.99`.

mod common;

use gs_core::raster::{backward, render, GradMask, OutputGrads};
use gs_core::sh::C0;
use gs_core::GaussianSet;

/// An odd image size, so the principal point (the Gaussian's projection) is a pixel centre.
const SIZE: u32 = 25;
const CENTRE: usize = (SIZE as usize / 2) * SIZE as usize + SIZE as usize / 2;
const LOGIT: f64 = 9.0;
const DC: [f64; 3] = [0.4, -0.3, 1.1];

fn opaque_gaussian() -> GaussianSet<f64> {
    GaussianSet::from_arrays(
        vec![0.0; 3],
        vec![-1.0; 3],
        vec![1.0, 0.2, -0.1, 0.3],
        vec![LOGIT],
        &DC,
    )
    .unwrap()
}

/// dL/d(RGB) of `L = r + g + b` at the centre pixel.
fn centre_pixel_upstream() -> Vec<f64> {
    let mut upstream = vec![0.0; 3 * (SIZE * SIZE) as usize];
    upstream[3 * CENTRE..3 * CENTRE + 3].fill(1.0);
    upstream
}

#[test]
fn the_opacity_gradient_passes_the_cap_as_inria_computes_it() {
    let g = opaque_gaussian();
    let camera = common::front_camera(SIZE, SIZE);
    let rendered = render(&g, &camera, [0.0; 3]);
    let opacity = 1.0 / (1.0 + (-LOGIT).exp());
    let colours = DC.map(|dc| C0 * dc + 0.5);
    for (ch, c) in colours.iter().enumerate() {
        // The cap is hit: the pixel is 0.99 of the colour, not sigmoid(9) of it.
        let value = rendered.image.data[3 * CENTRE + ch];
        assert!((value - 0.99 * c).abs() < 1e-12, "{value} vs {}", 0.99 * c);
    }
    let upstream = centre_pixel_upstream();
    let grads = backward(
        &g,
        &camera,
        &rendered,
        &OutputGrads {
            rgb: &upstream,
            alpha: None,
            depth: None,
        },
        GradMask::ALL,
    );
    // dL/dalpha = r + g + b (nothing behind, black background), d alpha / d opacity = exp(0)
    // = 1 as if uncapped, d opacity / d logit = s (1 - s).
    let expected = opacity * (1.0 - opacity) * colours.iter().sum::<f64>();
    let got = grads.gaussians.opacity_logits[0];
    assert!(
        (got - expected).abs() <= 1e-9 * expected,
        "dL/dlogit {got}, INRIA's rule gives {expected} (the exact derivative is 0)"
    );
    // The centre's offset is 0, so the geometry gets nothing from this pixel.
    assert!(grads.gaussians.means.iter().all(|&v| v.abs() < 1e-9));
}

/// On the cpu and on wgpu, one Adam step of the loss moves the capped opacity by the full rate
/// (it would stay where it is with a zero gradient).
#[test]
fn a_capped_opacity_moves_on_both_backends() {
    use std::ops::ControlFlow;
    use std::sync::Arc;

    use gs_core::adam::{AdamHyper, GroupConfig, LrSchedule};
    use gs_core::model::{BaseModel, View};
    use gs_core::sampler::ViewSampler;
    use gs_core::train::{Objective, ObjectiveValue, TrainConfig};
    use gs_core::Image;
    use gs_wgpu::backend::{Backend, Trainer};
    use gs_wgpu::{test_context, GpuOptions};

    struct CentrePixel;
    impl Objective for CentrePixel {
        type Error = std::convert::Infallible;
        fn evaluate(&mut self, _: usize, image: &Image) -> Result<ObjectiveValue, Self::Error> {
            Ok(ObjectiveValue {
                loss: image.data[3 * CENTRE..3 * CENTRE + 3].iter().sum(),
                terms: Vec::new(),
                grad: centre_pixel_upstream()
                    .into_iter()
                    .map(|v| v as f32)
                    .collect(),
            })
        }
    }

    let rate = 0.01;
    let Some(ctx) = test_context(GpuOptions::default()) else {
        return;
    };
    let backends = [Backend::Cpu, Backend::Gpu(Arc::new(ctx))];
    for backend in backends {
        let model: GaussianSet = opaque_gaussian().cast();
        let groups = model
            .group_names()
            .iter()
            .map(|n| GroupConfig::new(n.clone(), LrSchedule::Constant(rate)))
            .collect();
        let views = vec![View::still(common::front_camera(SIZE, SIZE))];
        let mut trainer = Trainer::new(&backend, model, groups, AdamHyper::default()).unwrap();
        trainer
            .train(
                &views,
                &mut CentrePixel,
                &mut ViewSampler::new(1, 0),
                &TrainConfig {
                    steps: 1,
                    background: [0.0; 3],
                },
                |_| ControlFlow::Continue(()),
            )
            .unwrap();
        let logit = f64::from(trainer.into_model().opacity_logits[0]);
        assert!(
            (logit - (LOGIT - rate)).abs() < 1e-4,
            "{}: the capped opacity's logit went from {LOGIT} to {logit}",
            backend.describe()
        );
    }
}
