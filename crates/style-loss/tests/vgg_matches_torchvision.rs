//! VGG-19 features against torchvision's VGG (vgg19 layer list, channels / 16, random weights).

mod common;

use candle_core::{Device, Tensor, Var};
use common::{fixture, load, load_json, relative_error, values};
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

/// The content loss `mse(relu4_2) + mse(relu5_2)` of `render` against `gt` and its image
/// gradient.
fn content_loss_and_grad(vgg: &Vgg19Features, render: &Tensor, gt: &Tensor) -> (f64, Tensor) {
    let gt = vgg.forward(gt).unwrap().detach();
    let render = Var::from_tensor(render).unwrap();
    let f = vgg.forward(render.as_tensor()).unwrap();
    let mse = |a: &Tensor, b: &Tensor| (a - b).unwrap().sqr().unwrap().mean_all().unwrap();
    let loss = (mse(&f.relu4_2, &gt.relu4_2) + mse(&f.relu5_2, &gt.relu5_2)).unwrap();
    let grad = loss
        .backward()
        .unwrap()
        .get(render.as_tensor())
        .unwrap()
        .clone();
    (values(&loss)[0], grad)
}

/// Asserts that the content loss of fixture case `name` (its `render` against its `gt`) matches
/// the fixture's `loss` to 1e-5 and its image gradient `grad` to 1e-4, relative.
fn assert_content_case_matches(
    vgg: &Vgg19Features,
    fixtures: &std::collections::HashMap<String, Tensor>,
    name: &str,
) {
    let t = |what: &str| fixtures[&format!("{name}.{what}")].clone();
    let (loss, grad) = content_loss_and_grad(vgg, &t("render"), &t("gt"));
    let reference = values(&t("loss"))[0];
    assert!(
        (loss - reference).abs() <= 1e-5 * reference.abs(),
        "{name}: loss {loss} vs {reference}"
    );
    let err = relative_error(&grad, &t("grad"));
    assert!(err < 1e-4, "{name}: gradient relative error {err}");
}

/// Flat regions (white backgrounds, constant borders, flat fields) tie in every 2x2 pooling
/// window, and torchvision's initialisation (zero biases) gives pre-activations of exactly 0:
/// the gradient must go to the first maximum of a window and stop at a ReLU of 0, as PyTorch's.
#[test]
fn content_gradient_matches_at_ties_and_zeros() {
    let weights = |name: &str| {
        let file = match name {
            "random_bias" => "tiny_vgg19.safetensors",
            "torchvision_init" => "tiny_vgg19_torchvision_init.safetensors",
            other => panic!("unknown weights {other}"),
        };
        Vgg19Features::load(&fixture(file), TINY_WIDTHS, &Device::Cpu).unwrap()
    };
    let r = load("vgg_ties_reference.safetensors");
    let cases = load_json("vgg_ties_reference.json");
    let cases = cases.as_object().unwrap();
    assert_eq!(cases.len(), 5);
    for (name, weight_set) in cases {
        assert_content_case_matches(&weights(weight_set.as_str().unwrap()), &r, name);
    }
}

/// Near every border, flat regions whose conv1_1 pre-activation is, exactly, a hair from 0
/// (`scripts/make_vgg_border_ties_fixture.py`): the ReLU must decide as the exact sum does, as
/// PyTorch's float32 does on these cases, or whole regions open or close and the gradient moves
/// by 1e-2.
#[test]
fn content_gradient_matches_where_relus_sit_a_hair_from_zero() {
    let vgg = Vgg19Features::load(
        &fixture("tiny_vgg19_torchvision_init.safetensors"),
        TINY_WIDTHS,
        &Device::Cpu,
    )
    .unwrap();
    let r = load("vgg_border_ties_reference.safetensors");
    for name in ["128x96", "61x45", "97x131"] {
        assert_content_case_matches(&vgg, &r, name);
    }
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
