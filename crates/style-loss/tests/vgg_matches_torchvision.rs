//! VGG-19 features against torchvision's VGG (vgg19 layer list, channels / 16, random weights).

mod common;

use candle_core::{Device, Var};
use common::{fixture, load, relative_error};
use style_loss::vgg::{Vgg19Features, Vgg19Widths};

const TINY_WIDTHS: Vgg19Widths = Vgg19Widths([4, 8, 16, 32, 32]);

#[test]
fn features_and_input_gradient_match() {
    let vgg = Vgg19Features::load(
        &fixture("tiny_vgg19.safetensors"),
        TINY_WIDTHS,
        &Device::Cpu,
    )
    .unwrap();
    let r = load("vgg_reference.safetensors");
    let image = Var::from_tensor(&r["image"]).unwrap();
    let features = vgg.forward(image.as_tensor()).unwrap();
    // 36x52 -> 4x6 at conv4_2 (odd sizes on the way: 9x13 pooled with floor), 2x3 at conv5_2.
    assert_eq!(features.relu4_2.dims(), &[1, 32, 4, 6]);
    assert_eq!(features.relu5_2.dims(), &[1, 32, 2, 3]);
    let err4 = relative_error(&features.relu4_2, &r["relu4_2"]);
    let err5 = relative_error(&features.relu5_2, &r["relu5_2"]);
    assert!(err4 < 1e-5 && err5 < 1e-5, "features: {err4} {err5}");
    let loss = ((&features.relu4_2 * &r["upstream4_2"])
        .unwrap()
        .sum_all()
        .unwrap()
        + (&features.relu5_2 * &r["upstream5_2"])
            .unwrap()
            .sum_all()
            .unwrap())
    .unwrap();
    let grads = loss.backward().unwrap();
    let grad = grads
        .get(image.as_tensor())
        .expect("gradient reaches the image");
    let err = relative_error(grad, &r["grad"]);
    assert!(err < 1e-4, "gradient relative error {err}");
}

#[test]
fn wrong_widths_name_the_tensor() {
    let err = Vgg19Features::load(
        &fixture("tiny_vgg19.safetensors"),
        Vgg19Widths::default(),
        &Device::Cpu,
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("features.0.weight") && err.contains("tiny_vgg19"),
        "{err}"
    );
}

#[test]
fn too_small_images_are_rejected() {
    let vgg = Vgg19Features::load(
        &fixture("tiny_vgg19.safetensors"),
        TINY_WIDTHS,
        &Device::Cpu,
    )
    .unwrap();
    let image =
        candle_core::Tensor::zeros((1, 3, 15, 40), candle_core::DType::F32, &Device::Cpu).unwrap();
    assert!(vgg.forward(&image).is_err());
}
