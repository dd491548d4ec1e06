//! The `eval` preprocess against the authors' evaluation (OpenAI CLIP's PIL preprocess of 8-bit
//! PNG files), from `scripts/make_eval_preprocess_fixtures.py`: Pillow's bicubic resize bit for
//! bit, the centre crop, `ToTensor` and `Normalize`, and how far the old non-antialiased bicubic
//! squash was from it.

mod common;

use candle_core::{DType, Device, Tensor};
use common::{load, load_json, max_abs_diff};
use style_loss::clip::{CLIP_MEAN, CLIP_STD};
use style_loss::metrics::evaluation_preprocess;
use style_loss::pil_resize::pil_bicubic_resize;
use style_loss::resize::{resize, ResizeKernel};

const FIXTURE: &str = "eval_preprocess_reference";

/// One step of 8 bits after CLIP's normalization is `1 / (255 std) >= 0.0142`; exact pixels
/// agree to float rounding.
const TOLERANCE: f64 = 1e-5;

/// The script's `hash_noise`: a multiplicative hash of the coordinates in wrapping 32 bits.
fn hash_noise(c: u32, y: u32, x: u32, seed: u32) -> u8 {
    let key = x.wrapping_mul(73_856_093)
        ^ y.wrapping_mul(19_349_663)
        ^ c.wrapping_mul(83_492_791)
        ^ seed.wrapping_mul(2_246_822_519);
    (key.wrapping_mul(2_654_435_761) >> 24) as u8
}

/// The script's `pattern`: a procedural 8-bit image `[3, h, w]`, row-major.
fn pattern(kind: &str, h: usize, w: usize, seed: u32) -> Vec<u8> {
    let mut out = Vec::with_capacity(3 * h * w);
    for c in 0..3 {
        for y in 0..h {
            for x in 0..w {
                let on = |b: bool| if b { 255 } else { 0 };
                let hashed = || hash_noise(c as u32, y as u32, x as u32, seed);
                let v = match kind {
                    "noise" => hashed(),
                    "flat" => [200, 100, 30][c],
                    "edges" => [on(x % 2 == 1), on((y / 3 + x / 3) % 2 == 1), on(x >= w / 2)][c],
                    "mix" if x >= w / 2 && y < h / 2 => hashed(),
                    "mix" if x < w / 2 && y >= h / 2 => on((x + c) % 2 == 1),
                    "mix" => [
                        (x * 255 / (w - 1)) as u8,
                        (y * 255 / (h - 1)) as u8,
                        on((x / 37 + y / 37) % 2 == 1),
                    ][c],
                    other => panic!("unknown pattern {other}"),
                };
                out.push(v);
            }
        }
    }
    out
}

fn fnv1a64(bytes: &[u8]) -> String {
    let hash = bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    });
    format!("{hash:016x}")
}

/// The case's input, checked against the script's hash so that both formulas agree.
fn input_of(name: &str, case: &serde_json::Value) -> (Vec<u8>, usize, usize) {
    let dims = case["input"].as_array().unwrap();
    let (h, w) = (
        dims[0].as_u64().unwrap() as usize,
        dims[1].as_u64().unwrap() as usize,
    );
    let seed = case["seed"].as_u64().unwrap() as u32;
    let bytes = pattern(case["kind"].as_str().unwrap(), h, w, seed);
    assert_eq!(
        fnv1a64(&bytes),
        case["input_fnv1a64"].as_str().unwrap(),
        "{name}: the Rust pattern differs from the script's"
    );
    (bytes, h, w)
}

/// An 8-bit image as the `eval` command loads it: `k / 255` in f32, `[3, h, w]`.
fn as_image(bytes: &[u8], h: usize, w: usize) -> Tensor {
    let values: Vec<f32> = bytes.iter().map(|&b| f32::from(b) / 255.0).collect();
    Tensor::from_vec(values, (3, h, w), &Device::Cpu).unwrap()
}

/// `ToTensor` and `Normalize` of 8-bit pixels `[3, n, n]`, in f32 as torchvision computes them.
fn normalized(pixels: &Tensor) -> Tensor {
    let x = (pixels.to_dtype(DType::F32).unwrap() / 255.0).unwrap();
    let mean = Tensor::new(&CLIP_MEAN, &Device::Cpu)
        .unwrap()
        .reshape((3, 1, 1))
        .unwrap();
    let std = Tensor::new(&CLIP_STD, &Device::Cpu)
        .unwrap()
        .reshape((3, 1, 1))
        .unwrap();
    x.broadcast_sub(&mean)
        .unwrap()
        .broadcast_div(&std)
        .unwrap()
        .unsqueeze(0)
        .unwrap()
}

/// The 8-bit pixels behind a preprocessed image (inverse of [`normalized`], rounded).
fn pixels_of(preprocessed: &Tensor) -> Vec<u8> {
    let values = preprocessed
        .flatten_all()
        .unwrap()
        .to_vec1::<f32>()
        .unwrap();
    let plane = values.len() / 3;
    values
        .iter()
        .enumerate()
        .map(|(i, &v)| {
            let c = i / plane;
            ((v * CLIP_STD[c] + CLIP_MEAN[c]) * 255.0).round() as u8
        })
        .collect()
}

/// The preprocess this crate had before: non-antialiased bicubic on floats (the training
/// loss's resize), same sizes, crop and normalization.
fn old_preprocess(image: &Tensor, size: usize) -> Tensor {
    let (_, h, w) = image.dims3().unwrap();
    let long = size * h.max(w) / h.min(w);
    let (oh, ow) = if h <= w { (size, long) } else { (long, size) };
    let resized = resize(
        &image.unsqueeze(0).unwrap(),
        (oh, ow),
        ResizeKernel::Bicubic,
    )
    .unwrap();
    let offset = |extent: usize| ((extent - size) as f64 / 2.0).round_ties_even() as usize;
    let cropped = resized
        .narrow(2, offset(oh), size)
        .unwrap()
        .narrow(3, offset(ow), size)
        .unwrap();
    let mean = Tensor::new(&CLIP_MEAN, &Device::Cpu)
        .unwrap()
        .reshape((1, 3, 1, 1))
        .unwrap();
    let std = Tensor::new(&CLIP_STD, &Device::Cpu)
        .unwrap()
        .reshape((1, 3, 1, 1))
        .unwrap();
    cropped
        .broadcast_sub(&mean)
        .unwrap()
        .broadcast_div(&std)
        .unwrap()
}

/// Mean and largest absolute difference of two preprocessed images, in [0, 1] pixel units
/// (the normalization undone per channel).
fn pixel_difference(a: &Tensor, b: &Tensor) -> (f64, f64) {
    let std = Tensor::new(&CLIP_STD, &Device::Cpu)
        .unwrap()
        .reshape((1, 3, 1, 1))
        .unwrap();
    let diff = (a - b)
        .unwrap()
        .broadcast_mul(&std)
        .unwrap()
        .abs()
        .unwrap()
        .to_dtype(DType::F64)
        .unwrap();
    let values = diff.flatten_all().unwrap().to_vec1::<f64>().unwrap();
    let mean = values.iter().sum::<f64>() / values.len() as f64;
    (mean, values.iter().copied().fold(0.0, f64::max))
}

#[test]
fn preprocess_matches_the_authors_clip_preprocess() {
    let tensors = load(&format!("{FIXTURE}.safetensors"));
    let meta = load_json(&format!("{FIXTURE}.json"));
    let cases = meta["preprocess"].as_object().unwrap();
    assert_eq!(cases.len(), 10);
    for (name, case) in cases {
        let (bytes, h, w) = input_of(name, case);
        let size = case["size"].as_u64().unwrap() as usize;
        let got = evaluation_preprocess(&as_image(&bytes, h, w), size).unwrap();
        assert_eq!(got.dims(), &[1, 3, size, size], "{name}");
        let pixels = &tensors[&format!("preprocess.{name}.pixels")];
        assert_eq!(
            pixels_of(&got),
            pixels.flatten_all().unwrap().to_vec1::<u8>().unwrap(),
            "{name}: pixels differ from PIL"
        );
        let want = normalized(pixels);
        let err = max_abs_diff(&got, &want);
        assert!(err < TOLERANCE, "{name}: max error {err}");
        if let Some(output) = tensors.get(&format!("preprocess.{name}.output")) {
            // The stored torchvision output and this test's ToTensor + Normalize agree.
            assert!(max_abs_diff(&want, output) < TOLERANCE, "{name}");
            let err = max_abs_diff(&got, output);
            assert!(
                err < TOLERANCE,
                "{name}: max error {err} against torchvision"
            );
        }
    }
}

#[test]
fn the_old_non_antialiased_preprocess_fails_the_tolerance() {
    let tensors = load(&format!("{FIXTURE}.safetensors"));
    let meta = load_json(&format!("{FIXTURE}.json"));
    let cases = meta["preprocess"].as_object().unwrap();
    for name in [
        "noise_landscape",
        "noise_portrait",
        "noise_small",
        "noise_large_factor",
        "edges",
        "mix",
    ] {
        let (bytes, h, w) = input_of(name, &cases[name]);
        let size = cases[name]["size"].as_u64().unwrap() as usize;
        let want = normalized(&tensors[&format!("preprocess.{name}.pixels")]);
        let old = old_preprocess(&as_image(&bytes, h, w), size);
        let err = max_abs_diff(&old, &want);
        let (mean, max) = pixel_difference(&old, &want);
        eprintln!(
            "{name}: old preprocess vs PIL: max {err:.4} normalized, pixels mean {mean:.4} \
             max {max:.4}"
        );
        assert!(err > 100.0 * TOLERANCE, "{name}: {err}");
    }
}

#[test]
fn resize_alone_matches_pillow() {
    let tensors = load(&format!("{FIXTURE}.safetensors"));
    let meta = load_json(&format!("{FIXTURE}.json"));
    let cases = meta["resize"].as_object().unwrap();
    assert_eq!(cases.len(), 3);
    for (name, case) in cases {
        let (bytes, h, w) = input_of(name, case);
        let size = case["size"].as_array().unwrap();
        let (oh, ow) = (
            size[0].as_u64().unwrap() as usize,
            size[1].as_u64().unwrap() as usize,
        );
        let got = pil_bicubic_resize(&bytes, 3, (h, w), (oh, ow)).unwrap();
        let want = tensors[&format!("resize.{name}.output")]
            .flatten_all()
            .unwrap()
            .to_vec1::<u8>()
            .unwrap();
        assert_eq!(got, want, "{name}");
    }
}

#[test]
fn a_600_by_800_view_at_224_matches_pillow() {
    let tensors = load(&format!("{FIXTURE}.safetensors"));
    let meta = load_json(&format!("{FIXTURE}.json"));
    let case = &meta["large"];
    let (bytes, h, w) = input_of("large", case);
    let size = case["size"].as_u64().unwrap() as usize;
    let image = as_image(&bytes, h, w);
    let got = evaluation_preprocess(&image, size).unwrap();
    let pixels = pixels_of(&got);
    let as_i64 = Tensor::from_vec(
        pixels.iter().map(|&v| i64::from(v)).collect::<Vec<_>>(),
        (3, size, size),
        &Device::Cpu,
    )
    .unwrap();
    for (key, dim) in [("row_sums", 2), ("col_sums", 1)] {
        let sums = as_i64.sum(dim).unwrap().to_vec2::<i64>().unwrap();
        let want = tensors[&format!("large.{key}")].to_vec2::<i64>().unwrap();
        assert_eq!(sums, want, "{key}");
    }
    assert_eq!(fnv1a64(&pixels), case["output_fnv1a64"].as_str().unwrap());
    // The pixels are exact, so the old squash's distance to this output is its distance to PIL.
    let old = old_preprocess(&image, size);
    let (mean, max) = pixel_difference(&old, &got);
    eprintln!(
        "600x800 -> 224: old preprocess vs PIL: max {:.4} normalized, pixels mean {mean:.4} \
         max {max:.4}",
        max_abs_diff(&old, &got)
    );
    assert!(mean > 0.01, "{mean}");
}
