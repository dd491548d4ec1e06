//! A small NeRF-synthetic scene rendered from a known Gaussian set, for the 3D fit's tests and
//! benchmarks (`scripts/make_fit_scene.sh` writes one with `examples/make_fit_scene.rs`, which
//! includes this file): `transforms_train.json` and `transforms_test.json` with RGBA pictures
//! (the render over black with its alpha), cameras on a sphere around the origin.

use std::path::Path;

use gs_core::raster::render;
use gs_core::{Camera, GaussianSet};
use rand::{Rng, SeedableRng};

/// The scene's shape: its Gaussians, views and picture size.
#[derive(Clone, Copy, Debug)]
pub struct FitScene {
    /// Seed of the Gaussians and the cameras.
    pub seed: u64,
    /// Known Gaussians.
    pub gaussians: usize,
    /// Training views.
    pub train: usize,
    /// Test views.
    pub test: usize,
    /// Width and height of the pictures, pixels.
    pub size: u32,
}

/// Horizontal field of view of every view, radians.
pub const FOV_X: f64 = 0.8;

/// `count` Gaussians of SH degree 0 in a ball of radius 0.7 (seeded): opaque blobs of random
/// colours a few hundredths to a tenth of the scene wide.
pub fn known_gaussians(count: usize, seed: u64) -> GaussianSet {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut g = GaussianSet::zeros(count, 0);
    for i in 0..count {
        loop {
            let p = [0; 3].map(|_| rng.random_range(-0.7f32..0.7));
            if p.iter().map(|x| x * x).sum::<f32>() <= 0.49 {
                g.means[3 * i..3 * i + 3].copy_from_slice(&p);
                break;
            }
        }
        for a in 0..3 {
            g.log_scales[3 * i + a] = rng.random_range(-3.0..-1.8);
            g.sh_dc[3 * i + a] = rng.random_range(-1.5..1.5);
        }
        for a in 0..4 {
            g.quats[4 * i + a] = rng.random_range(-1.0..1.0);
        }
        g.opacity_logits[i] = rng.random_range(1.0..4.0);
    }
    g
}

/// Camera-to-world in Blender axes (the camera looks along its -z) of `camera`: the inverse
/// of its world-to-camera pose, its y and z axes turned.
fn blender_c2w(camera: &Camera) -> [[f64; 4]; 4] {
    let r = camera.rotation;
    let c = camera.centre();
    let axis = |a: usize, sign: f64| [0, 1, 2].map(|i| sign * r[a][i]);
    let (x, y, z) = (axis(0, 1.0), axis(1, -1.0), axis(2, -1.0));
    [
        [x[0], y[0], z[0], c[0]],
        [x[1], y[1], z[1], c[1]],
        [x[2], y[2], z[2], c[2]],
        [0.0, 0.0, 0.0, 1.0],
    ]
}

/// Writes the scene into `root` (created): `train/`, `test/`, the two transforms files.
/// Returns the known Gaussians.
pub fn write_fit_scene(root: &Path, scene: FitScene) -> GaussianSet {
    let set = known_gaussians(scene.gaussians, scene.seed);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(scene.seed ^ 0xCA3E);
    for (split, count) in [("train", scene.train), ("test", scene.test)] {
        std::fs::create_dir_all(root.join(split)).unwrap();
        let mut frames = Vec::new();
        for k in 0..count {
            // A direction away from the poles (z within +-0.8 of the unit sphere), radius 3.
            let z: f64 = rng.random_range(-0.8..0.8);
            let a: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            let r = (1.0 - z * z).sqrt();
            let eye = [3.0 * r * a.cos(), 3.0 * r * a.sin(), 3.0 * z];
            let looking = Camera::look_at(
                eye,
                [0.0; 3],
                [0.0, 0.0, 1.0],
                FOV_X,
                scene.size,
                scene.size,
            )
            .unwrap();
            let m = blender_c2w(&looking);
            // The camera as the NeRF-synthetic reader makes it from the file.
            let camera = Camera::from_nerf(m, FOV_X, scene.size, scene.size).unwrap();
            let rendered = render(&set, &camera, [0.0; 3]);
            let mut img = image::RgbaImage::new(scene.size, scene.size);
            for (i, p) in img.pixels_mut().enumerate() {
                let alpha = rendered.alpha[i].clamp(0.0, 1.0);
                let c = |ch: usize| {
                    let v = rendered.image.data[3 * i + ch];
                    (v.clamp(0.0, 1.0) * 255.0).round() as u8
                };
                *p = image::Rgba([c(0), c(1), c(2), (alpha * 255.0).round() as u8]);
            }
            img.save(root.join(format!("{split}/r_{k}.png"))).unwrap();
            frames.push(serde_json::json!({
                "file_path": format!("./{split}/r_{k}"),
                "transform_matrix": m,
            }));
        }
        let transforms = serde_json::json!({"camera_angle_x": FOV_X, "frames": frames});
        std::fs::write(
            root.join(format!("transforms_{split}.json")),
            serde_json::to_string(&transforms).unwrap(),
        )
        .unwrap();
    }
    set
}
