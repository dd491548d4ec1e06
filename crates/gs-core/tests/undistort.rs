//! Undistortion against OpenCV: for cameras of every distorted COLMAP model this reader takes
//! (fixture `fixtures/undistort_opencv.json`, written by `scripts/make_undistort_fixture.py` with
//! opencv-python-headless), the undistorted points of `undistortPoints` and
//! `fisheye::undistortPoints`, the camera and crop of `getOptimalNewCameraMatrix` at alpha 0,
//! the maps of `initUndistortRectifyMap` and the pixels of a bilinear `remap`.

use gs_core::dataset::colmap::ColmapCamera;
use gs_core::dataset::undistort::{LensDistortion, Undistortion};
use serde_json::Value;

fn fixture() -> Value {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/undistort_opencv.json"
    );
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn floats(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap_or(f64::NAN))
        .collect()
}

/// Each fixture camera: its name for messages, size, intrinsics and lens as the COLMAP reader
/// maps its parameters, and its json.
fn cameras() -> Vec<(String, u32, u32, [f64; 4], LensDistortion, Value)> {
    let fixture = fixture();
    let cameras = fixture["cameras"].as_array().unwrap().clone();
    assert!(cameras.len() >= 8);
    cameras
        .into_iter()
        .enumerate()
        .map(|(i, c)| {
            let model = c["model"].as_str().unwrap().to_string();
            let (width, height) = (
                c["width"].as_u64().unwrap() as u32,
                c["height"].as_u64().unwrap() as u32,
            );
            let camera = ColmapCamera {
                id: i as i64,
                model: model.clone(),
                width,
                height,
                params: floats(&c["params"]),
            };
            let (k, lens) = camera.intrinsics().expect("a model the reader undistorts");
            let name = format!("{model} {width}x{height}");
            (name, width, height, k, lens.expect("a distorted camera"), c)
        })
        .collect()
}

fn close(a: f64, b: f64, tolerance: f64) -> bool {
    (a - b).abs() <= tolerance * (1.0 + b.abs())
}

#[test]
fn undistorted_points_are_opencvs() {
    let mut invalid = 0;
    for (name, _, _, [fx, fy, cx, cy], lens, c) in cameras() {
        for p in c["undistorted_points"].as_array().unwrap() {
            let [u, v, x, y] = floats(p)[..] else {
                panic!("{p}")
            };
            let got = lens.undistort([(u - cx) / fx, (v - cy) / fy]);
            if x == -1e6 && y == -1e6 {
                assert_eq!(got, None, "{name} ({u}, {v}): OpenCV marks it invalid");
                invalid += 1;
                continue;
            }
            let [gx, gy] = got.unwrap_or_else(|| panic!("{name} ({u}, {v}): no point"));
            assert!(
                close(gx, x, 1e-12) && close(gy, y, 1e-12),
                "{name} ({u}, {v}): ({gx}, {gy}) vs OpenCV ({x}, {y})"
            );
        }
    }
    // Every OpenCV point converged: none of the fixture's is marked invalid.
    assert_eq!(invalid, 0);
}

#[test]
fn the_pinhole_camera_and_crop_are_getoptimalnewcameramatrixs() {
    let mut checked = 0;
    for (name, width, height, k, lens, c) in cameras() {
        if matches!(lens, LensDistortion::Fisheye { .. }) {
            continue;
        }
        let u = Undistortion::new(k, lens, width, height).unwrap();
        let roi: Vec<u32> = floats(&c["roi"]).iter().map(|&v| v as u32).collect();
        assert_eq!(u.crop.to_vec(), roi, "{name}");
        assert_eq!((u.width, u.height), (roi[2], roi[3]), "{name}");
        let want = floats(&c["new_k"]);
        let shifted = [
            want[0],
            want[1],
            want[2] - f64::from(roi[0]),
            want[3] - f64::from(roi[1]),
        ];
        for (got, want) in u.intrinsics.iter().zip(shifted) {
            assert!(
                close(*got, want, 1e-12),
                "{name}: {:?} vs {want:?}",
                u.intrinsics
            );
        }
        checked += 1;
    }
    assert_eq!(checked, 6);
}

#[test]
fn the_maps_are_initundistortrectifymaps() {
    for (name, width, height, [fx, fy, cx, cy], lens, c) in cameras() {
        let new = floats(&c["new_k"]);
        let undistortion = match lens {
            LensDistortion::Perspective { .. } => {
                Some(Undistortion::new([fx, fy, cx, cy], lens, width, height).unwrap())
            }
            LensDistortion::Fisheye { .. } => None,
        };
        for p in c["map"].as_array().unwrap() {
            let [u, v, mx, my] = floats(p)[..] else {
                panic!("{p}")
            };
            // The fisheye fixture keeps K as the new camera: the lens model itself is checked.
            let [x, y] = lens.distort([(u - new[2]) / new[0], (v - new[3]) / new[1]]);
            let (gx, gy) = (fx * x + cx, fy * y + cy);
            // OpenCV stores the map in f32.
            assert!(
                (gx - mx).abs() < 1e-4 && (gy - my).abs() < 1e-4,
                "{name} ({u}, {v}): ({gx}, {gy}) vs OpenCV ({mx}, {my})"
            );
            if let Some(undistortion) = &undistortion {
                let [x0, y0, w, h] = undistortion.crop;
                let (i, j) = (u as u32, v as u32);
                if (x0..x0 + w).contains(&i) && (y0..y0 + h).contains(&j) {
                    let [sx, sy] = undistortion.source(i - x0, j - y0);
                    assert!(
                        (f64::from(sx) - mx).abs() < 1e-4 && (f64::from(sy) - my).abs() < 1e-4,
                        "{name} ({u}, {v}): ({sx}, {sy}) vs OpenCV ({mx}, {my})"
                    );
                }
            }
        }
    }
}

#[test]
fn remapped_pixels_match_opencvs_within_its_rounding() {
    let (name, width, height, k, lens, c) = cameras()
        .into_iter()
        .find(|c| c.5.get("remap").is_some())
        .unwrap();
    let remap = &c["remap"];
    let picture = image::Rgba32FImage::from_fn(width, height, |x, y| {
        let (x, y) = (f64::from(x), f64::from(y));
        image::Rgba([
            (0.5 + 0.4 * (0.21 * x + 0.05 * y).sin()) as f32,
            (0.5 + 0.4 * (0.13 * x - 0.17 * y).cos()) as f32,
            (0.5 + 0.3 * (0.09 * x + 0.11 * y + 1.0).sin()) as f32,
            1.0,
        ])
    });
    let undistortion = Undistortion::new(k, lens, width, height).unwrap();
    let out = undistortion.apply(&picture);
    let inside = remap["tolerance_inside"].as_f64().unwrap();
    let outside = remap["tolerance_outside"].as_f64().unwrap();
    let maps = c["map"].as_array().unwrap();
    let mut compared = 0;
    for (sample, map) in remap["samples"].as_array().unwrap().iter().zip(maps) {
        let s = floats(sample);
        let m = floats(map);
        let (i, j) = (s[0] as u32, s[1] as u32);
        if i >= out.width() || j >= out.height() {
            continue;
        }
        let within = (0.0..=f64::from(width - 1)).contains(&m[2])
            && (0.0..=f64::from(height - 1)).contains(&m[3]);
        let tolerance = if within { inside } else { outside };
        let got = out.get_pixel(i, j).0;
        for ch in 0..3 {
            assert!(
                (f64::from(got[ch]) - s[2 + ch]).abs() <= tolerance,
                "{name} ({i}, {j}) channel {ch}: {} vs OpenCV {}",
                got[ch],
                s[2 + ch]
            );
        }
        compared += 1;
    }
    assert!(compared > 50, "{compared}");
}

#[test]
fn a_lens_without_coefficients_is_none_and_bad_ones_are_refused() {
    let none = LensDistortion::Perspective {
        k: [0.0; 6],
        p: [0.0; 2],
    };
    assert!(none.is_none());
    assert_eq!(none.distort([0.3, -0.2]), [0.3, -0.2]);
    assert!(!LensDistortion::Fisheye { k: [0.0; 4] }.is_none());
    let nan = LensDistortion::Perspective {
        k: [f64::NAN, 0.0, 0.0, 0.0, 0.0, 0.0],
        p: [0.0; 2],
    };
    let e = Undistortion::new([50.0, 50.0, 32.0, 24.0], nan, 64, 48).unwrap_err();
    assert!(e.contains("not all finite"), "{e}");
    // A fisheye whose distorted radius peaks at 0.54 (theta (1 - theta^2 / 2)) cannot have put
    // the picture's border at radius 1.6: OpenCV marks those points invalid, and so no
    // undistorted picture exists.
    let folded = LensDistortion::Fisheye {
        k: [-0.5, 0.0, 0.0, 0.0],
    };
    assert_eq!(folded.undistort([1.6, 0.0]), None);
    let e = Undistortion::new([20.0, 20.0, 32.0, 24.0], folded, 64, 48).unwrap_err();
    assert!(
        e.contains("not monotone") && e.contains("stops growing") && e.contains("k1 = -0.5"),
        "{e}"
    );
}

/// A nerfstudio scene of one 8x6 picture whose transforms.json has the fields `lens` besides a
/// frame; the error of loading it (none when it loads).
fn nerfstudio_load(dir: &std::path::Path, lens: serde_json::Value) -> Option<String> {
    image::RgbaImage::from_pixel(8, 6, image::Rgba([200, 100, 50, 255]))
        .save(dir.join("r_0.png"))
        .unwrap();
    let mut json = serde_json::json!({
        "w": 8, "h": 6, "fl_x": 6.0, "fl_y": 6.0, "cx": 4.0, "cy": 3.0,
        "frames": [{"file_path": "r_0",
            "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]}],
    });
    for (k, v) in lens.as_object().unwrap() {
        json[k] = v.clone();
    }
    std::fs::write(dir.join("transforms_train.json"), json.to_string()).unwrap();
    gs_core::dataset::nerf_synthetic::load(
        dir,
        gs_core::dataset::nerf_synthetic::Split::Train,
        &gs_core::dataset::LoadOptions::default(),
    )
    .err()
    .map(|e| e.to_string())
}

/// Lenses whose undistortion is not monotone over the picture (the fuzz campaign's: each once
/// rendered as a pinhole or black) and intrinsics no camera has are refused at load, naming the
/// file, the frame and the coefficient; lenses as strong as real wide-angle ones load, up to
/// the edge of monotonicity.
#[test]
fn absurd_lenses_and_intrinsics_are_refused_naming_the_coefficient() {
    use serde_json::json;
    let dir = tempfile::tempdir().unwrap();
    for (lens, said) in [
        (json!({"k1": -50.0}), "k1 = -50"),
        (json!({"k1": -1e308}), "k1 = -1e308"),
        (json!({"k2": 1e300}), "k2 = 1e300"),
        (json!({"p1": 1e3}), "p1 = 1000"),
        (
            json!({"camera_model": "OPENCV_FISHEYE", "k4": 1e308}),
            "k4 = 1e308",
        ),
        (json!({"fl_x": 1e308}), "fx = 1e308"),
        (json!({"cy": -1e308}), "cy = -1e308"),
        (json!({"fl_x": 6e5}), "a focal length in (0, 80000]"),
    ] {
        let e =
            nerfstudio_load(dir.path(), lens.clone()).unwrap_or_else(|| panic!("{lens} loaded"));
        assert!(
            e.contains("transforms_train.json") && e.contains("frame 0") && e.contains(said),
            "{lens}: {e}"
        );
    }
    // Real lenses load: barrel and pincushion as strong as wide-angle cameras, a fisheye, and
    // a focal length at the limit.
    for lens in [
        json!({"k1": -0.3, "k2": 0.1}),
        json!({"k1": 0.2, "p1": 0.01, "p2": -0.01}),
        json!({"camera_model": "OPENCV_FISHEYE", "k1": 0.05, "k2": -0.01}),
        json!({"fl_x": 8e4, "fl_y": 8e4}),
    ] {
        assert_eq!(nerfstudio_load(dir.path(), lens.clone()), None, "{lens}");
    }
    // At the edge: with k1 < 0 alone the distorted radius r (1 + k1 r^2) peaks at
    // r = 1 / sqrt(-3 k1), at (2/3) of that; it must reach the corner's, here 5/6 (0.8333),
    // so k1 >= -0.2133. k1 = -0.20 loads, k1 = -0.23 does not.
    assert_eq!(nerfstudio_load(dir.path(), json!({"k1": -0.2})), None);
    let e = nerfstudio_load(dir.path(), json!({"k1": -0.23})).unwrap();
    assert!(
        e.contains("k1 = -0.23") && e.contains("not monotone"),
        "{e}"
    );
}

/// COLMAP's lenses of the fuzz campaign, at the undistortion both readers build: OPENCV with
/// k1 -1e6 (the lens folds at once), SIMPLE_RADIAL with k 1e6 (monotone, but OpenCV's five
/// steps do not invert it), FULL_OPENCV whose denominator is zero at a corner.
#[test]
fn colmap_lenses_that_do_not_invert_are_refused() {
    let perspective = |k: [f64; 6]| LensDistortion::Perspective { k, p: [0.0; 2] };
    // The corner (0, 0) of this camera is at normalized (-0.64, -0.48): r^2 = 0.64.
    let intrinsics = [50.0, 50.0, 32.0, 24.0];
    for (lens, said) in [
        (perspective([-1e6, 0.0, 0.0, 0.0, 0.0, 0.0]), "k1 = -1e6"),
        (
            perspective([1e6, 0.0, 0.0, 0.0, 0.0, 0.0]),
            "OpenCV's undistortion",
        ),
        (
            perspective([0.0, 0.0, 0.0, -1.0 / 0.64, 0.0, 0.0]),
            "k4 = -1.5625",
        ),
    ] {
        let e = Undistortion::new(intrinsics, lens, 64, 48).unwrap_err();
        assert!(
            e.contains("not monotone") && e.contains(said),
            "{lens:?}: {e}"
        );
    }
}
