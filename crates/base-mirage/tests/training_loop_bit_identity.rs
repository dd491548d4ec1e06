//! The training loop through `BaseModel` (forward -> tape -> backward) on the cpu gives, bit for
//! bit, the numbers of the same step composed by hand from the primitives (render, rasterizer
//! backward, the model's own transform and its gradient, Adam): for plain 3D Gaussians and for
//! MiraGe's flat ones, with a frozen group. Any change to the loop's arithmetic shows here.

use base_mirage::flat::{add_scale_grads, FlatGaussians};
use base_mirage::init::initial_gaussians;
use base_mirage::mirror::{mirror_views, plane_half_size};
use gs_core::adam::{Adam, AdamHyper, GroupConfig, LrSchedule};
use gs_core::image_loss::PhotometricObjective;
use gs_core::model::{BaseModel, GaussianLrs, View};
use gs_core::raster::{backward, render, GradMask, OutputGrads};
use gs_core::sampler::ViewSampler;
use gs_core::train::{CpuTrainer, Objective};
use gs_core::{GaussianSet, Image};

const W: u32 = 36;
const H: u32 = 28;
const STEPS: u64 = 12;
const BACKGROUND: [f32; 3] = [0.1, 0.0, 0.3];

/// Adam groups with one frozen (rotations).
fn groups() -> Vec<GroupConfig> {
    let mut groups = GaussianLrs {
        means: LrSchedule::Constant(0.002),
        scales: 0.01,
        rotations: 0.01,
        opacities: 0.05,
        feature: 0.03,
    }
    .groups();
    groups[2].frozen = true;
    groups
}

fn objective(views: &[View]) -> PhotometricObjective {
    let target = Image {
        width: W,
        height: H,
        data: (0..3 * W * H).map(|i| (i % 17) as f32 / 17.0).collect(),
    };
    PhotometricObjective::new(vec![target; views.len()], 0.2)
}

/// The model after `STEPS` steps of the loop.
fn through_the_loop<M: BaseModel>(model: M, views: &[View]) -> M {
    let adam = Adam::new(groups(), &model.group_lens(), AdamHyper::default());
    let mut trainer = CpuTrainer::new(model, adam).unwrap();
    let mut sampler = ViewSampler::new(views.len(), 3);
    let mut objective = objective(views);
    for _ in 0..STEPS {
        let batch = sampler.next_batch();
        trainer
            .step(views, batch, BACKGROUND, &mut objective)
            .unwrap();
    }
    trainer.into_model()
}

/// The same steps composed by hand: `rendered` builds the Gaussians from the parameters,
/// `to_params` turns their gradient into the parameters' (adding into zeroed groups).
fn by_hand(
    mut params: GaussianSet,
    views: &[View],
    rendered: impl Fn(&GaussianSet) -> GaussianSet,
    to_params: impl Fn(&GaussianSet, &GaussianSet, &mut [Vec<f32>]),
) -> GaussianSet {
    let groups = groups();
    let trained: Vec<bool> = groups.iter().map(|g| !g.frozen).collect();
    let lens: Vec<usize> = params.arrays().iter().map(|a| a.len()).collect();
    let mut adam = Adam::new(groups, &lens, AdamHyper::default());
    let mut objective = objective(views);
    let mut sampler = ViewSampler::new(views.len(), 3);
    let mask = GradMask {
        rotations: false,
        ..GradMask::ALL
    };
    for _ in 0..STEPS {
        let v = sampler.next_view();
        let gaussians = rendered(&params);
        let r = render(&gaussians, &views[v].camera, BACKGROUND);
        let value = objective.evaluate(v, &r.image).unwrap();
        let out = OutputGrads {
            rgb: &value.grad,
            alpha: None,
            depth: None,
        };
        let grads = backward(&gaussians, &views[v].camera, &r, &out, mask);
        let mut group_grads: Vec<Vec<f32>> = lens
            .iter()
            .zip(&trained)
            .map(|(&n, &t)| if t { vec![0.0; n] } else { Vec::new() })
            .collect();
        to_params(&params, &grads.gaussians, &mut group_grads);
        let refs: Vec<&[f32]> = group_grads.iter().map(|g| g.as_slice()).collect();
        let mut arrays: Vec<&mut [f32]> = params
            .arrays_mut()
            .into_iter()
            .map(|a| a.as_mut_slice())
            .collect();
        adam.step(&mut arrays, &refs);
    }
    params
}

/// `src` added to every trained group except `skip`.
fn add_groups(src: &GaussianSet, out: &mut [Vec<f32>], skip: Option<usize>) {
    for (k, (s, d)) in src.arrays().iter().zip(out.iter_mut()).enumerate() {
        if Some(k) != skip && !d.is_empty() {
            for (d, s) in d.iter_mut().zip(s.iter()) {
                *d += *s;
            }
        }
    }
}

fn start() -> (FlatGaussians, [View; 2]) {
    let (hw, hh) = plane_half_size(W, H, 1.0);
    (
        initial_gaussians(120, 1, hw, hh, 5),
        mirror_views(W, H, 1.0).unwrap(),
    )
}

#[test]
fn plain_gaussians_train_bit_for_bit_as_composed_by_hand() {
    let (flat, views) = start();
    let set = flat.into_params();
    let looped = through_the_loop(set.clone(), &views);
    let composed = by_hand(set.clone(), &views, Clone::clone, |_, g, out| {
        add_groups(g, out, None)
    });
    assert_eq!(looped, composed);
    assert_ne!(looped, set, "training moved the parameters");
}

#[test]
fn flat_gaussians_train_bit_for_bit_as_composed_by_hand() {
    let (flat, views) = start();
    let looped = through_the_loop(flat.clone(), &views).into_params();
    let composed = by_hand(
        flat.params().clone(),
        &views,
        base_mirage::flat::renderable,
        |params, g, out| {
            add_groups(g, out, Some(1));
            add_scale_grads(&params.log_scales, &g.log_scales, &mut out[1]);
        },
    );
    assert_eq!(looped, composed);
    assert_ne!(&looped, flat.params(), "training moved the parameters");
}
