//! Resizes against `F.interpolate` / torchvision `resize`, the perspective warp against
//! torchvision `perspective`: outputs and input gradients.

mod common;

use candle_core::{Tensor, Var};
use common::{load, load_json, max_abs_diff, relative_error};
use style_loss::perspective::{
    gather_taps, image_corners, perspective_coefficients, Corners, SourceWindow, Taps,
};
use style_loss::resize::{resize, resize_matrix, ResizeKernel};
use style_loss::window_warp::{warp_windows, WindowWarp};

/// Output and gradient of `sum(f(x) * upstream)` for the fixture case `name`.
fn run_case(
    fixtures: &std::collections::HashMap<String, Tensor>,
    name: &str,
    f: impl Fn(&Tensor) -> Tensor,
) -> (Tensor, Tensor) {
    let x = Var::from_tensor(&fixtures[&format!("{name}.input")]).unwrap();
    let y = f(x.as_tensor());
    let loss = (&y * &fixtures[&format!("{name}.upstream")])
        .unwrap()
        .sum_all()
        .unwrap();
    let grads = loss.backward().unwrap();
    let grad = grads
        .get(x.as_tensor())
        .expect("gradient reaches the input")
        .clone();
    (y, grad)
}

/// Asserts that case `name`'s output and input gradient match the fixture's to 1e-5 (largest
/// difference of the output, relative error of the gradient).
fn assert_case_matches(
    fixtures: &std::collections::HashMap<String, Tensor>,
    name: &str,
    (y, grad): (Tensor, Tensor),
) {
    let out_err = max_abs_diff(&y, &fixtures[&format!("{name}.output")]);
    let grad_err = relative_error(&grad, &fixtures[&format!("{name}.grad")]);
    assert!(out_err < 1e-5, "{name}: output max error {out_err}");
    assert!(
        grad_err < 1e-5,
        "{name}: gradient relative error {grad_err}"
    );
}

/// Every perspective fixture case through `warp` (the image `[1, c, h, w]`, torchvision's
/// coefficients for the case) against torchvision's output and gradient.
fn check_perspective_cases(warp: impl Fn(&Tensor, [f32; 8]) -> Tensor) {
    let r = load("perspective_reference.safetensors");
    let cases = load_json("perspective_reference.json");
    let cases = cases.as_object().unwrap();
    assert_eq!(cases.len(), 5);
    for (name, end) in cases {
        let end: Corners = serde_json::from_value(end.clone()).unwrap();
        let (_, _, h, w) = r[&format!("{name}.input")].dims4().unwrap();
        let coeffs = perspective_coefficients(&image_corners(w, h), &end).unwrap();
        assert_case_matches(&r, name, run_case(&r, name, |x| warp(x, coeffs)));
    }
}

#[test]
fn resizes_match_torch_forward_and_backward() {
    let r = load("resize_reference.safetensors");
    let cases = load_json("resize_reference.json");
    let cases = cases.as_object().unwrap();
    assert_eq!(cases.len(), 5);
    for (name, case) in cases {
        let size = case["size"].as_array().unwrap();
        let size = (
            size[0].as_u64().unwrap() as usize,
            size[1].as_u64().unwrap() as usize,
        );
        let kernel = match case["mode"].as_str().unwrap() {
            "bicubic" => ResizeKernel::Bicubic,
            "bilinear_aa" => ResizeKernel::BilinearAntialias,
            other => panic!("unknown mode {other}"),
        };
        assert_case_matches(
            &r,
            name,
            run_case(&r, name, |x| resize(x, size, kernel).unwrap()),
        );
    }
}

#[test]
fn same_size_resize_is_the_identity_matrix() {
    for kernel in [ResizeKernel::Bicubic, ResizeKernel::BilinearAntialias] {
        let m = resize_matrix(kernel, 7, 7);
        for i in 0..7 {
            for j in 0..7 {
                let expected = if i == j { 1.0 } else { 0.0 };
                assert!(
                    (m[i * 7 + j] - expected).abs() < 1e-7,
                    "{kernel:?} [{i},{j}]"
                );
            }
        }
    }
}

#[test]
fn perspective_matches_torchvision_forward_and_backward() {
    check_perspective_cases(|x, coeffs| {
        let (_, c, h, w) = x.dims4().unwrap();
        let mut taps = Taps::default();
        taps.push_perspective(
            &coeffs,
            SourceWindow {
                width: w,
                height: h,
                left: 0,
                top: 0,
                source_width: w,
            },
        );
        let flat = x.reshape((c, h * w)).unwrap();
        gather_taps(&flat, &taps)
            .unwrap()
            .reshape((1, c, h, w))
            .unwrap()
    });
}

/// The device form of the warp (taps computed as tensors, backward a gather) on the same cases.
#[test]
fn window_warp_matches_torchvision_forward_and_backward() {
    check_perspective_cases(|x, coeffs| {
        let (_, _, h, w) = x.dims4().unwrap();
        let warp = WindowWarp {
            left: 0,
            top: 0,
            coeffs,
        };
        warp_windows(&x.squeeze(0).unwrap(), &[warp], w, h).unwrap()
    });
}

#[test]
fn degenerate_corners_are_an_error() {
    let start = image_corners(8, 8);
    let collapsed: Corners = [[3, 3], [3, 3], [3, 3], [3, 3]];
    assert!(perspective_coefficients(&start, &collapsed).is_err());
}
