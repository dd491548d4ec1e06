//! Fitting: a random Gaussian set trained with L1 + D-SSIM towards renders of another scene.

mod common;

use common::{fit_lrs, random_scene, ring_views};
use gs_core::adam::{Adam, AdamHyper};
use gs_core::image_loss::PhotometricObjective;
use gs_core::model::{BaseModel, View};
use gs_core::raster::render;
use gs_core::sampler::ViewSampler;
use gs_core::train::{CpuTrainer, Objective};
use gs_core::GaussianSet;

fn mean_loss(
    model: &GaussianSet,
    views: &[View],
    obj: &mut PhotometricObjective,
    bg: [f32; 3],
) -> f32 {
    let total: f32 = views
        .iter()
        .enumerate()
        .map(|(i, v)| {
            obj.evaluate(i, &render(model, &v.camera, bg).image)
                .unwrap()
                .loss
        })
        .sum();
    total / views.len() as f32
}

#[test]
fn fitting_a_random_set_to_another_scene_lowers_the_loss_tenfold() {
    let bg = [0.0; 3];
    let views = ring_views(8, 40);
    let target: GaussianSet = random_scene(1, 40, 1);
    let targets = views
        .iter()
        .map(|v| render(&target, &v.camera, bg).image)
        .collect();
    let mut objective = PhotometricObjective::new(targets, 0.2);
    let model: GaussianSet = random_scene(2, 150, 1);
    let before = mean_loss(&model, &views, &mut objective, bg);

    let lrs = fit_lrs();
    let adam = Adam::new(lrs.groups(), &model.group_lens(), AdamHyper::default());
    let mut trainer = CpuTrainer::new(model, adam).unwrap();
    let mut sampler = ViewSampler::new(views.len(), 5);
    for step in 1..=800 {
        let r = trainer
            .step(&views, sampler.next_batch(), bg, &mut objective)
            .unwrap();
        assert_eq!(r.step, step);
        assert!(r.value.loss.is_finite());
    }
    let model = trainer.into_model();
    assert_eq!(model.len(), 150, "the count never changes");
    let after = mean_loss(&model, &views, &mut objective, bg);
    assert!(after * 10.0 < before, "loss {before} -> {after}");
}
