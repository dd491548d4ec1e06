//! `gs_core::pil_resize` against Pillow's `Image.resize` (bicubic) of an RGBA picture and of its
//! RGB part, shrunk and enlarged (`fixtures/pil_resize.*`, written by
//! `scripts/make_pil_resize_fixture.py`): every byte equal. The RGBA picture holds every alpha
//! level, colours under alpha 0 and sharp opaque/transparent edges, where Pillow's premultiplied
//! resize differs most from resizing the stored colours. And the NeRF-synthetic loader shrinks a
//! picture wider than `max_width` as INRIA 3DGS's `loadCam` does: its size rule, then Pillow.

mod common;

use std::path::PathBuf;

use gs_core::dataset::nerf_synthetic::{self, Split};
use gs_core::dataset::{GroundTruth, LoadOptions};
use gs_core::pil_resize::{pil_bicubic_resize, pil_rgba_resize};

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

/// Interleaved `[h, w, c]` as planar `[c, h, w]`.
fn planar(pixels: &[u8], channels: usize) -> Vec<u8> {
    let n = pixels.len() / channels;
    (0..channels)
        .flat_map(|c| (0..n).map(move |p| pixels[p * channels + c]))
        .collect()
}

/// The fixture's bytes and its cases.
fn cases() -> (Vec<u8>, serde_json::Value) {
    let blob = std::fs::read(fixture("pil_resize.bin")).unwrap();
    let text = std::fs::read_to_string(fixture("pil_resize.json")).unwrap();
    (blob, serde_json::from_str(&text).unwrap())
}

#[test]
fn rgba_and_rgb_resizes_equal_pillows() {
    let (blob, cases) = cases();
    let mut premultiplied_matters = false;
    for case in cases.as_array().unwrap() {
        let size = |key: &str| {
            let v = &case[key];
            (
                v[0].as_u64().unwrap() as usize,
                v[1].as_u64().unwrap() as usize,
            )
        };
        let (input, output) = (size("input"), size("output"));
        let channels = if case["mode"] == "RGBA" { 4 } else { 3 };
        let at = |key: &str, (h, w): (usize, usize)| {
            let start = case[key].as_u64().unwrap() as usize;
            &blob[start..start + channels * h * w]
        };
        let (pixels, expected) = (at("input_offset", input), at("output_offset", output));
        let name = case["name"].as_str().unwrap();
        if channels == 4 {
            let ours = pil_rgba_resize(pixels, input, output).unwrap();
            let differing = ours.iter().zip(expected).filter(|(a, b)| a != b).count();
            assert_eq!(
                differing, 0,
                "{name}: {differing} bytes differ from Pillow's"
            );
            // Resizing the stored colours as planes (no premultiplying) would not do.
            let plain = pil_bicubic_resize(&planar(pixels, 4), 4, input, output).unwrap();
            premultiplied_matters |= plain != planar(expected, 4);
        } else {
            let ours = pil_bicubic_resize(&planar(pixels, 3), 3, input, output).unwrap();
            assert_eq!(ours, planar(expected, 3), "{name}");
        }
    }
    assert!(premultiplied_matters);
}

#[test]
fn bad_rgba_sizes_are_errors() {
    assert!(pil_rgba_resize(&[0; 7], (1, 2), (2, 2)).is_err());
    assert!(pil_rgba_resize(&[0; 8], (1, 2), (0, 2)).is_err());
}

#[test]
fn a_wide_picture_is_shrunk_as_inrias_loader_shrinks_it() {
    // The fixture's 53 x 37 RGBA picture as the only frame of a NeRF-synthetic scene.
    let (blob, cases) = cases();
    let case = cases
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["name"] == "rgba_19x13")
        .unwrap();
    let (w, h) = (53u32, 37u32);
    let start = case["input_offset"].as_u64().unwrap() as usize;
    let picture =
        image::RgbaImage::from_raw(w, h, blob[start..start + (4 * w * h) as usize].to_vec())
            .unwrap();
    let dir = tempfile::tempdir().unwrap();
    picture.save(dir.path().join("r_0.png")).unwrap();
    common::write_one_frame_transforms(dir.path());
    let load = |max_width: u32, downscale: u32| {
        let options = LoadOptions {
            ground_truth: GroundTruth::FileColour,
            downscale,
            max_width,
            ..LoadOptions::default()
        };
        nerf_synthetic::load(dir.path(), Split::Train, &options).unwrap()
    };
    let full = load(0, 1);
    assert_eq!((full.images[0].width, full.images[0].height), (w, h));
    // 53 / (53 / 19) = 19 wide, int(37 / 2.789...) = 13 high: Pillow's 19 x 13 resize.
    let shrunk = load(19, 1);
    let (image, camera) = (&shrunk.images[0], &shrunk.views[0].camera);
    assert_eq!((image.width, image.height), (19, 13));
    assert_eq!((camera.width, camera.height), (19, 13));
    let full_camera = &full.views[0].camera;
    assert!((camera.fx - full_camera.fx * 19.0 / 53.0).abs() < 1e-9);
    assert!((camera.fy - full_camera.fy * 13.0 / 37.0).abs() < 1e-9);
    let start = case["output_offset"].as_u64().unwrap() as usize;
    let pillow = &blob[start..start + 4 * 19 * 13];
    for (p, rgb) in image.data.chunks_exact(3).enumerate() {
        for c in 0..3 {
            assert_eq!(rgb[c], f32::from(pillow[4 * p + c]) / 255.0, "pixel {p}");
        }
    }
    // A picture no wider than max_width, or any with a resolution divisor, keeps INRIA's -r
    // rule: 53 / 2 = 26.5 and 37 / 2 = 18.5 round to even (Python's round).
    assert_eq!(load(53, 1).images[0].width, 53);
    let halved = load(19, 2);
    assert_eq!((halved.images[0].width, halved.images[0].height), (26, 18));
}
