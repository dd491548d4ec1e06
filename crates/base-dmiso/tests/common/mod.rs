//! A small generated dynamic scene in the D-NeRF layout: coloured blobs that move and turn
//! through time, seen by cameras on a circle, one time per frame, RGBA PNGs over a
//! transparent background; and a folder copy for tests that break files.

#![allow(dead_code)]

use std::path::Path;

use gs_core::model::View;
use gs_core::{Camera, GaussianSet, Image};

/// Horizontal field of view of the generated cameras, radians.
pub const FOV: f64 = 0.9;

/// The scene's Gaussians at time `t`: two blobs, one sliding along x, one circling the y axis.
pub fn ground_truth(t: f64) -> GaussianSet {
    let mut means = Vec::new();
    let mut colours = Vec::new();
    for k in 0..24 {
        let a = k as f64 * 0.7;
        let (blob, centre, colour) = if k % 2 == 0 {
            (0.25, [-0.5 + 0.8 * t, 0.0, 0.0], [0.9, 0.2, 0.1])
        } else {
            let angle = std::f64::consts::TAU * t;
            (
                0.2,
                [0.45 * angle.cos(), 0.3, 0.45 * angle.sin()],
                [0.1, 0.3, 0.9],
            )
        };
        means.extend([
            (centre[0] + blob * a.cos() * 0.6) as f32,
            (centre[1] + blob * (1.3 * a).sin() * 0.6) as f32,
            (centre[2] + blob * a.sin() * 0.6) as f32,
        ]);
        colours.push(colour);
    }
    let n = colours.len();
    let sh: Vec<f32> = colours
        .iter()
        .flat_map(|c| c.map(|v: f64| ((v - 0.5) / 0.28209479177387814) as f32))
        .collect();
    GaussianSet::from_arrays(
        means,
        vec![-2.3; 3 * n],
        [1.0, 0.0, 0.0, 0.0].repeat(n),
        vec![3.0; n],
        &sh,
    )
    .unwrap()
}

/// The camera of angle `angle` (radians) on a circle of radius 3 around the origin.
pub fn camera(angle: f64, size: u32) -> Camera {
    let eye = [3.0 * angle.cos(), -0.6, 3.0 * angle.sin()];
    Camera::look_at(eye, [0.0; 3], [0.0, -1.0, 0.0], FOV, size, size).unwrap()
}

/// `count` views: view `i` at time `(i + offset) / count` from the angle of that fraction of a
/// turn.
pub fn views(count: usize, offset: f64, size: u32) -> Vec<View> {
    (0..count)
        .map(|i| {
            let u = (i as f64 + offset) / count as f64;
            View {
                camera: camera(std::f64::consts::TAU * u, size),
                time: u.min(1.0),
            }
        })
        .collect()
}

/// The ground truth of `view` over `background`.
pub fn render(view: &View, background: [f32; 3]) -> Image {
    gs_core::raster::render(&ground_truth(view.time), &view.camera, background).image
}

/// The NeRF/Blender camera-to-world matrix (OpenGL axes) of `camera`.
pub fn blender_c2w(camera: &Camera) -> [[f64; 4]; 4] {
    let r = camera.rotation;
    let c = camera.centre();
    let mut m = [[0.0; 4]; 4];
    for row in 0..3 {
        // Columns of the camera-to-world rotation are the rows of world-to-camera; y and z
        // flip from OpenCV to OpenGL axes.
        m[row][0] = r[0][row];
        m[row][1] = -r[1][row];
        m[row][2] = -r[2][row];
        m[row][3] = c[row];
    }
    m[3][3] = 1.0;
    m
}

/// Writes `views` as the split `name` (`transforms_<name>.json` and `<name>/r_<i>.png`, RGBA
/// with the scene's coverage as alpha) of a D-NeRF scene in `dir`.
pub fn write_split(dir: &Path, name: &str, views: &[View]) {
    std::fs::create_dir_all(dir.join(name)).unwrap();
    let mut frames = Vec::new();
    for (i, view) in views.iter().enumerate() {
        let black = render(view, [0.0; 3]);
        let white = render(view, [1.0; 3]);
        let mut rgba = image::RgbaImage::new(black.width, black.height);
        for (p, (b, w)) in rgba
            .pixels_mut()
            .zip(black.data.chunks_exact(3).zip(white.data.chunks_exact(3)))
        {
            let alpha = (1.0 - (w[0] - b[0])).clamp(0.0, 1.0);
            let colour = |c: f32| {
                if alpha > 0.0 {
                    (c / alpha).clamp(0.0, 1.0)
                } else {
                    0.0
                }
            };
            *p = image::Rgba([
                (colour(b[0]) * 255.0).round() as u8,
                (colour(b[1]) * 255.0).round() as u8,
                (colour(b[2]) * 255.0).round() as u8,
                (alpha * 255.0).round() as u8,
            ]);
        }
        rgba.save(dir.join(name).join(format!("r_{i:03}.png")))
            .unwrap();
        frames.push(serde_json::json!({
            "file_path": format!("./{name}/r_{i:03}"),
            "time": view.time,
            "transform_matrix": blender_c2w(&view.camera),
        }));
    }
    let json = serde_json::json!({ "camera_angle_x": FOV, "frames": frames });
    std::fs::write(
        dir.join(format!("transforms_{name}.json")),
        serde_json::to_string_pretty(&json).unwrap(),
    )
    .unwrap();
}

/// A D-NeRF scene of `train` training and `test` test views of `size` pixels in `dir`.
pub fn write_scene(dir: &Path, train: usize, test: usize, size: u32) {
    write_split(dir, "train", &views(train, 0.0, size));
    write_split(dir, "test", &views(test, 0.5, size));
}
