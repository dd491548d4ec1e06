//! The mirror camera pair of Gaussians on the plane `y = 0` (MiraGe's pictures, VeGaS's video
//! frames): the picture seen from `(0, -d, 0)` looking along `+y` (image right = world `+x`,
//! image up = world `+z`) and its horizontal mirror seen from `(0, +d, 0)` looking along `-y`.
//! Both have MiraGe's horizontal field of view (VeGaS uses the same) and the same focal length
//! along both axes, so the vertical field of view follows from the aspect ratio.

use crate::model::View;
use crate::{Camera, GsError, Image};

/// The horizontal field of view, radians (`camera_angle_x` of MiraGe's and VeGaS's readers).
pub const FOV_X: f64 = 0.6911112070083618;

/// The default camera distance `d` (MiraGe's and VeGaS's `--distance`), world units.
pub const DEFAULT_DISTANCE: f64 = 1.0;

/// The NeRF/Blender camera-to-world matrix MiraGe and VeGaS build for a camera at signed distance
/// `signed` (negative: the front camera at `(0, signed, 0)`; positive: the mirror camera).
fn camera_to_world(signed: f64) -> [[f64; 4]; 4] {
    let s = signed.signum();
    [
        [-s, 0.0, 0.0, 0.0],
        [0.0, 0.0, s, signed],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ]
}

/// The camera that sees the picture (`mirrored == false`) or its mirror image, for a picture
/// of `width x height` pixels at distance `distance` (> 0) from the plane.
pub fn plane_camera(
    width: u32,
    height: u32,
    distance: f64,
    mirrored: bool,
) -> Result<Camera, GsError> {
    if !(distance.is_finite() && distance > 0.0) {
        return Err(GsError::InvalidCamera(format!(
            "the camera distance is {distance}; it must be finite and > 0"
        )));
    }
    let signed = if mirrored { distance } else { -distance };
    Camera::from_nerf(camera_to_world(signed), FOV_X, width, height)
}

/// The two training views, `[picture, mirror]`.
pub fn mirror_views(width: u32, height: u32, distance: f64) -> Result<[View; 2], GsError> {
    Ok([
        View::still(plane_camera(width, height, distance, false)?),
        View::still(plane_camera(width, height, distance, true)?),
    ])
}

/// The picture flipped left to right: the target of the mirror camera.
pub fn mirrored(image: &Image) -> Image {
    let (w, h) = (image.width as usize, image.height as usize);
    let mut data = vec![0.0; image.data.len()];
    for y in 0..h {
        for x in 0..w {
            let src = 3 * (y * w + (w - 1 - x));
            let dst = 3 * (y * w + x);
            data[dst..dst + 3].copy_from_slice(&image.data[src..src + 3]);
        }
    }
    Image {
        width: image.width,
        height: image.height,
        data,
    }
}

/// The scene extent of the camera pair as 3DGS's `getNerfppNorm` computes it: the cameras sit
/// at `±d` around their mean (the origin), so the radius is `1.1 d`.
pub fn extent(distance: f64) -> f64 {
    1.1 * distance
}

/// Half the width and half the height (world units) of the picture on the plane `y = 0` as
/// the front camera frames it: `top = d tan(fov_y / 2)`, `right = top * width / height`.
pub fn plane_half_size(width: u32, height: u32, distance: f64) -> (f64, f64) {
    let focal = crate::camera::fov_to_focal(FOV_X, width);
    let top = distance * 0.5 * height as f64 / focal;
    (top * width as f64 / height as f64, top)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn front_camera_sees_world_x_to_the_right_and_z_up() {
        let cam = plane_camera(64, 32, 1.0, false).unwrap();
        let centre = cam.project([0.0, 0.0, 0.0]).unwrap().0;
        assert!((centre[0] - 32.0).abs() < 1e-9 && (centre[1] - 16.0).abs() < 1e-9);
        let right = cam.project([0.1, 0.0, 0.0]).unwrap().0;
        let up = cam.project([0.0, 0.0, 0.1]).unwrap().0;
        assert!(right[0] > 32.0 && (right[1] - 16.0).abs() < 1e-9);
        assert!(up[1] < 16.0 && (up[0] - 32.0).abs() < 1e-9);
    }

    #[test]
    fn mirror_camera_sees_the_plane_flipped_left_to_right() {
        let (front, back) = (
            plane_camera(64, 32, 1.0, false).unwrap(),
            plane_camera(64, 32, 1.0, true).unwrap(),
        );
        for p in [[0.13, 0.0, 0.05], [-0.2, 0.0, -0.07]] {
            let (a, da) = front.project(p).unwrap();
            let (b, db) = back.project(p).unwrap();
            assert!((a[0] + b[0] - 64.0).abs() < 1e-9, "x mirrored: {a:?} {b:?}");
            assert!((a[1] - b[1]).abs() < 1e-9, "y kept: {a:?} {b:?}");
            assert!((da - 1.0).abs() < 1e-12 && (db - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn the_plane_rectangle_fills_the_front_view() {
        let (w, h) = (80, 50);
        let (right, top) = plane_half_size(w, h, 2.0);
        let cam = plane_camera(w, h, 2.0, false).unwrap();
        let corner = cam.project([right, 0.0, top]).unwrap().0;
        assert!((corner[0] - 80.0).abs() < 1e-9 && corner[1].abs() < 1e-9);
    }

    #[test]
    fn a_distance_that_is_not_positive_is_refused() {
        for d in [0.0, -1.0, f64::NAN] {
            assert!(plane_camera(8, 8, d, false).is_err());
        }
    }

    #[test]
    fn mirrored_twice_is_the_picture() {
        let img = Image {
            width: 3,
            height: 2,
            data: (0..18).map(|v| v as f32).collect(),
        };
        let m = mirrored(&img);
        assert_eq!(&m.data[0..3], &img.data[6..9]);
        assert_eq!(mirrored(&m).data, img.data);
    }
}
