//! Fitting a small generated dynamic scene (24 frames of 64 pixels, from files in the D-NeRF
//! layout) reaches a stated PSNR at held-out times and views, through D-MiSo's three stages and
//! its densification; the model trains alike on the cpu and on wgpu.

mod common;

use std::ops::ControlFlow;

use base_dmiso::densify::DensifySettings;
use base_dmiso::fit::{fit, mean_psnr, render_views, DynamicSceneFitSettings};
use candle_core::Device;
use gs_core::dataset::nerf_synthetic::{load_with_times, Split};
use gs_core::dataset::{Background, LoadOptions};
use gs_wgpu::backend::Backend;

#[test]
fn a_fit_reproduces_held_out_times() {
    let dir = tempfile::tempdir().unwrap();
    common::write_scene(dir.path(), 24, 6, 64);
    let options = LoadOptions {
        background: Background::White,
        downscale: 1,
        ..LoadOptions::default()
    };
    let train = load_with_times(dir.path(), Split::Train, &options).unwrap();
    let test = load_with_times(dir.path(), Split::Test, &options).unwrap();
    assert!(test.views.iter().all(|v| v.time > 0.0 && v.time < 1.0));
    let settings = DynamicSceneFitSettings {
        points: 600,
        steps: 1200,
        warm_up: 200,
        subs_from: 700,
        // Every core that survives the densification gets its sub-Gaussians.
        sub_cores: 100_000,
        subs_per_core: 4,
        batch: 2,
        deform_width: 64,
        seed: 3,
        // D-MiSo's densification, on this short run's scale: from step 100, every 100 steps,
        // one opacity reset at step 100 (white background).
        densify: Some(DensifySettings {
            from: 100,
            every: 100,
            opacity_reset_every: 10_000,
            ..DensifySettings::default()
        }),
        ..DynamicSceneFitSettings::default()
    };
    let mut losses = Vec::new();
    let mut model = fit(
        &train.views,
        &train.images,
        train.extent,
        &settings,
        &Backend::Cpu,
        &Device::Cpu,
        |r| {
            losses.push(r.value.loss);
            ControlFlow::Continue(())
        },
    )
    .unwrap();
    assert_eq!(losses.len(), 1200);
    assert_eq!(model.subs_per_core(), 4);
    // The densification changed the 600 random starting cores.
    println!("{} cores after the densification", model.cores());
    assert_ne!(model.cores(), 600);
    let renders = render_views(&mut model, &test.views, [1.0; 3], &Backend::Cpu).unwrap();
    let psnr = mean_psnr(&renders, &test.images);
    let blank = mean_psnr(
        &vec![gs_core::Image::filled(64, 64, [1.0; 3]); test.images.len()],
        &test.images,
    );
    // The same cameras a quarter of the time away: the model moves with time.
    let shifted: Vec<_> = test
        .views
        .iter()
        .map(|v| gs_core::model::View {
            time: (v.time + 0.25) % 1.0,
            ..v.clone()
        })
        .collect();
    let elsewhen = render_views(&mut model, &shifted, [1.0; 3], &Backend::Cpu).unwrap();
    let wrong_time = mean_psnr(&elsewhen, &test.images);
    println!(
        "held-out PSNR {psnr:.2} dB (a quarter of the time away: {wrong_time:.2} dB, a white \
         image: {blank:.2} dB)"
    );
    assert!(psnr > 30.0, "held-out PSNR {psnr:.2} dB");
    assert!(
        psnr > wrong_time + 6.0,
        "{psnr:.2} dB vs {wrong_time:.2} dB elsewhen"
    );
}

/// D-MiSo trains alike on the cpu and on wgpu (lavapipe in CI) through gs-core's provided host
/// construction: the same steps of batches of two views, every group.
#[test]
fn a_model_trains_alike_on_the_cpu_and_on_wgpu() {
    use std::sync::Arc;

    use base_dmiso::deform_net::NetShape;
    use base_dmiso::init::{initial_model, with_sub_gaussians};
    use base_dmiso::stylize::{stylize_groups, DynamicSceneStylizeConfig};
    use gs_core::adam::AdamHyper;
    use gs_core::image_loss::PhotometricObjective;
    use gs_core::sampler::{BatchOrder, ViewSampler};
    use gs_core::train::TrainConfig;
    use gs_stylize::rates::GroupRate;
    use gs_wgpu::backend::Trainer;
    use gs_wgpu::{test_context, GpuOptions};

    let views = common::views(4, 0.0, 32);
    let targets: Vec<_> = views.iter().map(|v| common::render(v, [1.0; 3])).collect();
    let base = initial_model(120, NetShape { width: 16 }, 1, &Device::Cpu).unwrap();
    let model = with_sub_gaussians(&base, 60, 3, 1).unwrap();
    let Some(ctx) = test_context(GpuOptions::default()) else {
        return;
    };
    let mut results = Vec::new();
    for backend in [Backend::Cpu, Backend::Gpu(Arc::new(ctx))] {
        let mut config = DynamicSceneStylizeConfig::default();
        // Rates large enough for every group to move visibly in a few steps.
        let rates = &mut config.learning_rates;
        let decay = |start, times_extent| GroupRate::Decay {
            start,
            end: 1e-6,
            steps: 5000,
            times_extent,
        };
        rates.set("pseudomesh", decay(1e-3, true));
        rates.set("attached_features_dc", GroupRate::Constant(0.05));
        rates.set("attached_features_rest", GroupRate::Constant(0.05));
        rates.set("deform", decay(1e-3, false));
        let mut trainer = Trainer::new(
            &backend,
            model.clone(),
            stylize_groups(&config.learning_rates, 3.0).unwrap(),
            AdamHyper::default(),
        )
        .unwrap();
        trainer
            .train(
                &views,
                &mut PhotometricObjective::new(targets.clone(), 0.2),
                &mut ViewSampler::batches(4, 2, BatchOrder::Consecutive, 0),
                &TrainConfig {
                    steps: 3,
                    background: [1.0; 3],
                },
                |_| ControlFlow::Continue(()),
            )
            .unwrap();
        results.push(trainer.into_model());
    }
    let (cpu, gpu) = (&results[0], &results[1]);
    for (g, name) in base_dmiso::GROUP_NAMES.iter().enumerate() {
        let (a, b, start) = (
            &cpu.params().groups[g],
            &gpu.params().groups[g],
            &model.params().groups[g],
        );
        let worst = |x: &[f32], y: &[f32]| {
            x.iter()
                .zip(y)
                .map(|(p, q)| (p - q).abs())
                .fold(0.0f32, f32::max)
        };
        let moved = worst(a, start);
        assert!(moved > 0.0, "{name} moved");
        // Adam turns the rounding differences of near-zero gradients into steps of the
        // learning rate's size: the bound is a tenth of how far the group moved.
        let apart = worst(a, b);
        assert!(
            apart <= 0.1 * moved + 1e-6,
            "{name}: cpu and wgpu differ by {apart}, the group moved by {moved}"
        );
    }
}
