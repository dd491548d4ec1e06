//! A tiny scene on disk for the integration tests: a random Gaussian set as an ascii PLY with an
//! extra property, RGBA renders of it in the NeRF-synthetic layout, and the tiny CLIP fixture of
//! style-loss with CLIP's full vocabulary (so the real tokenizer's ids fit).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use candle_core::{Device, Tensor};
use gs_core::ply::{write_ply, PlyFormat, PlyGaussians};
use gs_core::ply::{ExtraProperty, ScalarType};
use gs_core::raster::render;
use gs_core::{Camera, GaussianSet};
use rand::{Rng, SeedableRng};

/// Width and height of the views, pixels.
pub const SIZE: u32 = 48;
/// Number of views.
pub const VIEWS: usize = 4;
/// Horizontal field of view of every view, radians.
pub const FOV_X: f64 = 0.9;

/// A file of style-loss's test fixtures.
pub fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../style-loss/tests/fixtures")
        .join(name)
}

/// 80 random Gaussians of SH degree 1 around the origin (seeded).
pub fn random_set() -> GaussianSet {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let mut g = GaussianSet::zeros(80, 1);
    for v in &mut g.means {
        *v = rng.random_range(-0.7..0.7);
    }
    for v in &mut g.log_scales {
        *v = rng.random_range(-2.2..-1.4);
    }
    for v in &mut g.quats {
        *v = rng.random_range(-1.0..1.0);
    }
    for v in &mut g.opacity_logits {
        *v = rng.random_range(0.0..3.0);
    }
    for v in &mut g.sh_dc {
        *v = rng.random_range(-0.5..0.5);
    }
    g
}

/// Camera-to-world (Blender axes: z up, the camera looks along its -z) of a camera on a circle
/// of radius 3 around the origin, looking at it.
pub fn c2w(k: usize) -> [[f64; 4]; 4] {
    let a = k as f64 * std::f64::consts::TAU / VIEWS as f64;
    let eye = [3.0 * a.cos(), 3.0 * a.sin(), 0.5];
    let norm = |v: [f64; 3]| {
        let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        [v[0] / n, v[1] / n, v[2] / n]
    };
    let cross = |a: [f64; 3], b: [f64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let z = norm(eye);
    let x = norm(cross([0.0, 0.0, 1.0], z));
    let y = cross(z, x);
    [
        [x[0], y[0], z[0], eye[0]],
        [x[1], y[1], z[1], eye[1]],
        [x[2], y[2], z[2], eye[2]],
        [0.0, 0.0, 0.0, 1.0],
    ]
}

/// The scene folder: `scene.ply` (ascii, with a `confidence` extra) and `data/` with
/// `transforms_train.json` and RGBA renders (alpha from the render's opacity).
pub fn write_scene(root: &Path) -> (PathBuf, PathBuf) {
    let set = random_set();
    let data = root.join("data");
    std::fs::create_dir_all(data.join("train")).unwrap();
    let mut frames = Vec::new();
    for k in 0..VIEWS {
        let camera = Camera::from_nerf(c2w(k), FOV_X, SIZE, SIZE).unwrap();
        let r = render(&set, &camera, [0.0; 3]);
        let mut img = image::RgbaImage::new(SIZE, SIZE);
        for (i, p) in img.pixels_mut().enumerate() {
            let a = r.alpha[i].clamp(0.0, 1.0);
            let c = |ch: usize| {
                let v = if a > 0.0 {
                    r.image.data[3 * i + ch] / a
                } else {
                    0.0
                };
                (v.clamp(0.0, 1.0) * 255.0).round() as u8
            };
            *p = image::Rgba([c(0), c(1), c(2), (a * 255.0).round() as u8]);
        }
        img.save(data.join(format!("train/r_{k}.png"))).unwrap();
        frames.push(serde_json::json!({
            "file_path": format!("./train/r_{k}"),
            "transform_matrix": c2w(k),
        }));
    }
    let transforms = serde_json::json!({"camera_angle_x": FOV_X, "frames": frames});
    std::fs::write(
        data.join("transforms_train.json"),
        serde_json::to_string(&transforms).unwrap(),
    )
    .unwrap();
    let ply = root.join("scene.ply");
    let n = set.len();
    let mut file = PlyGaussians::new(set);
    file.extras.push(ExtraProperty {
        name: "confidence".into(),
        ty: ScalarType::Float32,
        values: (0..n).map(|i| i as f64 * 0.5).collect(),
    });
    write_ply(&ply, &file, PlyFormat::Ascii).unwrap();
    (ply, data)
}

/// The tiny CLIP fixture with CLIP's real vocabulary size (a random token embedding), so the
/// real tokenizer's ids fit: `(config.json, model.safetensors)` in `dir`.
pub fn write_tiny_clip(dir: &Path) -> (PathBuf, PathBuf) {
    let device = Device::Cpu;
    let mut tensors: HashMap<String, Tensor> =
        candle_core::safetensors::load(fixture("tiny_clip/model.safetensors"), &device).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let values: Vec<f32> = (0..49408 * 32)
        .map(|_| rng.random_range(-0.05..0.05))
        .collect();
    tensors.insert(
        "text_model.embeddings.token_embedding.weight".into(),
        Tensor::from_vec(values, (49408, 32), &device).unwrap(),
    );
    let weights = dir.join("clip.safetensors");
    candle_core::safetensors::save(&tensors, &weights).unwrap();
    let text = std::fs::read_to_string(fixture("tiny_clip/config.json")).unwrap();
    let mut config: serde_json::Value = serde_json::from_str(&text).unwrap();
    config["text_config"]["vocab_size"] = 49408.into();
    config["text_config"]["eos_token_id"] = 49407.into();
    let config_path = dir.join("clip_config.json");
    std::fs::write(&config_path, config.to_string()).unwrap();
    (config_path, weights)
}

/// The same views as [`write_scene`]'s in the COLMAP layout: `colmap/sparse/0/{cameras,images,
/// points3D}.txt` (one PINHOLE camera, poses converted from the NeRF cameras) and RGB pictures
/// in `colmap/images/` composited on black. Returns the dataset folder.
pub fn write_colmap_scene(root: &Path) -> PathBuf {
    let set = random_set();
    let data = root.join("colmap");
    let sparse = data.join("sparse/0");
    std::fs::create_dir_all(&sparse).unwrap();
    std::fs::create_dir_all(data.join("images")).unwrap();
    let mut images = String::new();
    let mut intrinsics = [0.0; 4];
    for k in 0..VIEWS {
        let camera = Camera::from_nerf(c2w(k), FOV_X, SIZE, SIZE).unwrap();
        intrinsics = [camera.fx, camera.fy, camera.cx, camera.cy];
        let q = rotation_to_quaternion(&camera.rotation);
        let t = camera.translation;
        images += &format!(
            "{} {} {} {} {} {} {} {} 1 r_{k}.png\n\n",
            k + 1,
            q[0],
            q[1],
            q[2],
            q[3],
            t[0],
            t[1],
            t[2]
        );
        render(&set, &camera, [0.0; 3])
            .image
            .save_png(&data.join(format!("images/r_{k}.png")))
            .unwrap();
    }
    let [fx, fy, cx, cy] = intrinsics;
    std::fs::write(
        sparse.join("cameras.txt"),
        format!("1 PINHOLE {SIZE} {SIZE} {fx} {fy} {cx} {cy}\n"),
    )
    .unwrap();
    std::fs::write(sparse.join("images.txt"), images).unwrap();
    std::fs::write(
        sparse.join("points3D.txt"),
        "1 0.1 0.2 0.3 200 100 50 0.5\n",
    )
    .unwrap();
    data
}

/// The unit quaternion `(w, x, y, z)` of a rotation matrix (Shepperd's method).
fn rotation_to_quaternion(r: &[[f64; 3]; 3]) -> [f64; 4] {
    let trace = r[0][0] + r[1][1] + r[2][2];
    if trace > 0.0 {
        let s = 2.0 * (trace + 1.0).sqrt();
        [
            0.25 * s,
            (r[2][1] - r[1][2]) / s,
            (r[0][2] - r[2][0]) / s,
            (r[1][0] - r[0][1]) / s,
        ]
    } else if r[0][0] > r[1][1] && r[0][0] > r[2][2] {
        let s = 2.0 * (1.0 + r[0][0] - r[1][1] - r[2][2]).sqrt();
        [
            (r[2][1] - r[1][2]) / s,
            0.25 * s,
            (r[0][1] + r[1][0]) / s,
            (r[0][2] + r[2][0]) / s,
        ]
    } else if r[1][1] > r[2][2] {
        let s = 2.0 * (1.0 + r[1][1] - r[0][0] - r[2][2]).sqrt();
        [
            (r[0][2] - r[2][0]) / s,
            (r[0][1] + r[1][0]) / s,
            0.25 * s,
            (r[1][2] + r[2][1]) / s,
        ]
    } else {
        let s = 2.0 * (1.0 + r[2][2] - r[0][0] - r[1][1]).sqrt();
        [
            (r[1][0] - r[0][1]) / s,
            (r[0][2] + r[2][0]) / s,
            (r[1][2] + r[2][1]) / s,
            0.25 * s,
        ]
    }
}
