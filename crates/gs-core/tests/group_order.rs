//! The optimizer's groups are matched to the model's by name: a list in another order trains
//! the groups it names with the rates it gives them, and a misspelt, repeated or missing group
//! is refused naming it.

mod common;

use common::random_scene;
use gs_core::adam::{AdamHyper, GroupConfig, LrSchedule};
use gs_core::image_loss::PhotometricObjective;
use gs_core::model::View;
use gs_core::raster::render;
use gs_core::sampler::ViewSampler;
use gs_core::train::TrainConfig;
use gs_core::{Camera, GaussianSet};
use gs_wgpu::backend::{Backend, DeviceError, Trainer};

/// Each of the model's groups with a rate of its own; the opacities frozen.
fn groups() -> Vec<GroupConfig> {
    vec![
        GroupConfig::new("means", LrSchedule::Constant(0.004)),
        GroupConfig::new("scales", LrSchedule::Constant(0.01)),
        GroupConfig::new("rotations", LrSchedule::Constant(0.02)),
        GroupConfig::frozen("opacities"),
        GroupConfig::new("sh_dc", LrSchedule::Constant(0.05)),
        GroupConfig::new("sh_rest", LrSchedule::Constant(0.0025)),
    ]
}

/// The model after 5 steps towards another scene with `groups`.
fn trained(groups: Vec<GroupConfig>) -> Result<GaussianSet, DeviceError> {
    let camera = Camera::look_at([0.0, -0.5, 3.5], [0.0; 3], [0.0, -1.0, 0.0], 0.9, 24, 24)
        .expect("a camera");
    let views = vec![View::still(camera)];
    let target: GaussianSet = random_scene(1, 20, 1);
    let mut objective =
        PhotometricObjective::new(vec![render(&target, &views[0].camera, [0.0; 3]).image], 0.2);
    let start: GaussianSet = random_scene(2, 30, 1);
    let mut trainer = Trainer::new(&Backend::Cpu, start, groups, AdamHyper::default())?;
    let config = TrainConfig {
        steps: 5,
        background: [0.0; 3],
    };
    trainer
        .train(
            &views,
            &mut objective,
            &mut ViewSampler::new(1, 0),
            &config,
            |_| std::ops::ControlFlow::Continue(()),
        )
        .expect("training");
    Ok(trainer.into_model())
}

#[test]
fn groups_in_another_order_train_the_same() {
    let names: Vec<String> = groups().iter().map(|g| g.name.clone()).collect();
    assert_eq!(names, gs_core::gaussians::PARAM_NAMES, "the model's order");
    let ordered = trained(groups()).unwrap();
    let mut reversed = groups();
    reversed.reverse();
    assert_eq!(trained(reversed).unwrap(), ordered);
    let start: GaussianSet = random_scene(2, 30, 1);
    assert_eq!(
        ordered.opacity_logits, start.opacity_logits,
        "the frozen group"
    );
    assert_ne!(ordered.means, start.means);
}

#[test]
fn unknown_repeated_or_missing_groups_are_named() {
    let message = |groups: Vec<GroupConfig>| trained(groups).unwrap_err().to_string();
    let mut misspelt = groups();
    misspelt[2].name = "rotation".into();
    let err = message(misspelt);
    assert!(
        err.contains("no parameter group \"rotation\"") && err.contains("rotations"),
        "{err}"
    );
    let mut twice = groups();
    twice[0] = GroupConfig::new("sh_dc", LrSchedule::Constant(0.1));
    let err = message(twice);
    assert!(err.contains("\"sh_dc\" is configured twice"), "{err}");
    let mut short = groups();
    short.pop();
    let err = message(short);
    assert!(
        err.contains("no configuration for parameter group(s) sh_rest"),
        "{err}"
    );
}
