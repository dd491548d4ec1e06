//! Fitting a small generated dynamic scene (24 frames of 64 pixels, from files in the D-NeRF
//! layout) reaches a stated PSNR at held-out times and views, through D-MiSo's three stages.

mod common;

use std::ops::ControlFlow;

use base_dmiso::fit::{fit, mean_psnr, render_views, FitSettings};
use candle_core::Device;
use gs_core::backend::Backend;
use gs_core::dataset::nerf_synthetic::{load_with_times, Split};
use gs_core::dataset::{Background, LoadOptions};

#[test]
fn a_fit_reproduces_held_out_times() {
    let dir = tempfile::tempdir().unwrap();
    common::write_scene(dir.path(), 24, 6, 64);
    let options = LoadOptions {
        background: Background::White,
        downscale: 1,
    };
    let train = load_with_times(dir.path(), Split::Train, &options).unwrap();
    let test = load_with_times(dir.path(), Split::Test, &options).unwrap();
    assert!(test.views.iter().all(|v| v.time > 0.0 && v.time < 1.0));
    let settings = FitSettings {
        points: 600,
        steps: 1200,
        warm_up: 200,
        subs_from: 700,
        sub_cores: 300,
        subs_per_core: 4,
        batch: 2,
        deform_width: 64,
        seed: 3,
        ..FitSettings::default()
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
    assert_eq!((model.cores(), model.subs_per_core()), (300, 4));
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
