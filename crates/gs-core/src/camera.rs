//! Pinhole cameras in OpenCV axes (x right, y down, z forward), intrinsics in pixels.

use crate::mat::{self, M3, V3};
use crate::GsError;

/// A pinhole camera: world-to-camera rigid transform (OpenCV axes) and intrinsics in pixels.
/// Pixel centres lie at `+0.5`: the pixel `(0, 0)` covers `[0, 1) x [0, 1)`.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    /// World-to-camera rotation, row-major.
    pub rotation: M3<f64>,
    /// World-to-camera translation.
    pub translation: V3<f64>,
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
}

/// Largest deviation from orthonormality a pose's rotation may have (of the dot products of its
/// rows from the identity's): pose files print about seven digits.
pub const ROTATION_TOLERANCE: f64 = 1e-4;

/// The largest picture side a camera may have, pixels: the rasterizer's tile lists index tiles
/// and Gaussians with `u32`, and no GPU texture is larger.
pub const MAX_SIDE: u32 = 1 << 16;

/// The most pixels a camera's picture may have (268 megapixels, e.g. 16384 x 16384): a render
/// holds about 12 bytes a pixel several times over, 3 GB each at this size.
pub const MAX_PIXELS: u64 = 1 << 28;

/// Checks that `m` (a 4x4 pose, row-major, camera-to-world or world-to-camera) is rigid: the
/// last row `0 0 0 1`, the rotation orthonormal within [`ROTATION_TOLERANCE`] with determinant
/// `+1`, every value finite; the error says which it is not.
pub fn check_rigid(m: &[[f64; 4]; 4]) -> Result<(), GsError> {
    if m[3] != [0.0, 0.0, 0.0, 1.0] {
        return Err(GsError::InvalidCamera(format!(
            "the last row of the pose is {:?}, expected [0, 0, 0, 1]",
            m[3]
        )));
    }
    if !m.iter().flatten().all(|v| v.is_finite()) {
        return Err(GsError::InvalidCamera("the pose is not finite".into()));
    }
    let mut worst = 0.0f64;
    for i in 0..3 {
        for j in 0..3 {
            let dot: f64 = (0..3).map(|k| m[i][k] * m[j][k]).sum();
            let expected = if i == j { 1.0 } else { 0.0 };
            worst = worst.max((dot - expected).abs());
        }
    }
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    if !(worst <= ROTATION_TOLERANCE && det > 0.0) {
        return Err(GsError::InvalidCamera(format!(
            "the rotation of the pose is not orthonormal with determinant 1 (rows off by \
             {worst:.2e}, determinant {det:.4}): a pose is a rotation and a translation"
        )));
    }
    Ok(())
}

/// Focal length in pixels that gives the field of view `fov` (radians) over `pixels`.
pub fn fov_to_focal(fov: f64, pixels: u32) -> f64 {
    0.5 * pixels as f64 / (0.5 * fov).tan()
}

/// The intrinsics `[f, f, cx, cy]` of a `width x height` picture with focal length `focal`
/// along both axes and the principal point at its centre.
fn centred(focal: f64, width: u32, height: u32) -> [f64; 4] {
    [focal, focal, 0.5 * width as f64, 0.5 * height as f64]
}

impl Camera {
    /// A camera from a world-to-camera transform (OpenCV axes) and intrinsics; checks that the
    /// size is non-zero, the focal lengths positive and everything finite.
    pub fn new(
        rotation: M3<f64>,
        translation: V3<f64>,
        [fx, fy, cx, cy]: [f64; 4],
        width: u32,
        height: u32,
    ) -> Result<Self, GsError> {
        let cam = Self {
            rotation,
            translation,
            fx,
            fy,
            cx,
            cy,
            width,
            height,
        };
        cam.validate()?;
        Ok(cam)
    }

    /// Checks the size, intrinsics and pose (the constructors do; cameras built field by field
    /// should be checked before use).
    pub fn validate(&self) -> Result<(), GsError> {
        let bad =
            |what: &str, value: String| Err(GsError::InvalidCamera(format!("{what} is {value}")));
        if self.width == 0 || self.height == 0 {
            return bad("the image size", format!("{}x{}", self.width, self.height));
        }
        if self.width > MAX_SIDE
            || self.height > MAX_SIDE
            || u64::from(self.width) * u64::from(self.height) > MAX_PIXELS
        {
            return bad(
                "the image size",
                format!(
                    "{}x{}, whose render alone needs {:.1} GB; at most {MAX_SIDE} pixels a side \
                     and {} megapixels are rendered (render smaller: a resolution divisor -r \
                     for a dataset, a smaller width and height for a camera or a video)",
                    self.width,
                    self.height,
                    // The render's RGB and alpha, f32.
                    u64::from(self.width) as f64 * u64::from(self.height) as f64 * 16.0 / 1e9,
                    MAX_PIXELS / 1_000_000
                ),
            );
        }
        for (name, v) in [("fx", self.fx), ("fy", self.fy)] {
            if !(v.is_finite() && v > 0.0) {
                return bad(name, v.to_string());
            }
        }
        for (name, v) in [("cx", self.cx), ("cy", self.cy)] {
            if !v.is_finite() {
                return bad(name, v.to_string());
            }
        }
        let finite = self.rotation.iter().flatten().all(|v| v.is_finite())
            && self.translation.iter().all(|v| v.is_finite());
        if !finite {
            return bad("the pose", "not finite".into());
        }
        Ok(())
    }

    /// A camera from a NeRF / Blender camera-to-world matrix (OpenGL axes: x right, y up,
    /// z backward) and the horizontal field of view `fov_x` in radians, as in
    /// `transforms_*.json`. The focal length is the same along both axes and the principal
    /// point is the image centre, as INRIA 3DGS reads these files.
    pub fn from_nerf(
        c2w: [[f64; 4]; 4],
        fov_x: f64,
        width: u32,
        height: u32,
    ) -> Result<Self, GsError> {
        let focal = fov_to_focal(fov_x, width);
        Self::from_nerf_intrinsics(c2w, centred(focal, width, height), width, height)
    }

    /// A camera from a NeRF/Blender camera-to-world matrix (OpenGL axes) with its own
    /// intrinsics `[fx, fy, cx, cy]` in pixels (nerfstudio's and instant-ngp's `fl_x`, `fl_y`,
    /// `cx`, `cy`). The matrix must be rigid ([`check_rigid`]).
    pub fn from_nerf_intrinsics(
        c2w: [[f64; 4]; 4],
        intrinsics: [f64; 4],
        width: u32,
        height: u32,
    ) -> Result<Self, GsError> {
        check_rigid(&c2w)?;
        // OpenGL to OpenCV axes: negate the camera's y and z axes (columns 1 and 2).
        let r_c2w: M3<f64> = [
            [c2w[0][0], -c2w[0][1], -c2w[0][2]],
            [c2w[1][0], -c2w[1][1], -c2w[1][2]],
            [c2w[2][0], -c2w[2][1], -c2w[2][2]],
        ];
        let centre = [c2w[0][3], c2w[1][3], c2w[2][3]];
        Self::from_centre(r_c2w, centre, intrinsics, width, height)
    }

    /// A camera from a COLMAP image pose: `qvec` `(w, x, y, z)` and `tvec` are the
    /// world-to-camera rotation and translation (OpenCV axes), intrinsics in pixels.
    pub fn from_colmap(
        qvec: [f64; 4],
        tvec: [f64; 3],
        intrinsics: [f64; 4],
        width: u32,
        height: u32,
    ) -> Result<Self, GsError> {
        let (q, n) = normalize4(qvec);
        if !(n > 0.0 && n.is_finite()) {
            return Err(GsError::InvalidCamera(format!(
                "the COLMAP quaternion {qvec:?} has no direction"
            )));
        }
        Self::new(mat::quat_to_rotation(q), tvec, intrinsics, width, height)
    }

    /// A camera at `eye` looking at `target`, with `up` the world direction that appears
    /// upwards in the image, horizontal field of view `fov_x` (radians), principal point at the
    /// centre.
    pub fn look_at(
        eye: V3<f64>,
        target: V3<f64>,
        up: V3<f64>,
        fov_x: f64,
        width: u32,
        height: u32,
    ) -> Result<Self, GsError> {
        let (forward, nf) =
            mat::normalize3([target[0] - eye[0], target[1] - eye[1], target[2] - eye[2]]);
        let (right, nr) = mat::normalize3(cross(forward, up));
        if nf == 0.0 || nr == 0.0 {
            return Err(GsError::InvalidCamera(format!(
                "look_at from {eye:?} to {target:?} with up {up:?} has no orientation"
            )));
        }
        let down = cross(forward, right);
        // Camera-to-world rotation: columns are the camera's x (right), y (down), z (forward).
        let r_c2w = [
            [right[0], down[0], forward[0]],
            [right[1], down[1], forward[1]],
            [right[2], down[2], forward[2]],
        ];
        let focal = fov_to_focal(fov_x, width);
        Self::from_centre(r_c2w, eye, centred(focal, width, height), width, height)
    }

    /// The camera at world point `centre` whose camera-to-world rotation (OpenCV axes) is
    /// `r_c2w`, with `intrinsics`.
    fn from_centre(
        r_c2w: M3<f64>,
        centre: V3<f64>,
        intrinsics: [f64; 4],
        width: u32,
        height: u32,
    ) -> Result<Self, GsError> {
        let rotation = mat::transpose(&r_c2w);
        let rc = mat::mul_vec(&rotation, &centre);
        Self::new(
            rotation,
            [-rc[0], -rc[1], -rc[2]],
            intrinsics,
            width,
            height,
        )
    }

    /// The camera centre in world coordinates.
    pub fn centre(&self) -> V3<f64> {
        let c = mat::mul_t_vec(&self.rotation, &self.translation);
        [-c[0], -c[1], -c[2]]
    }

    /// A world point in camera coordinates.
    pub fn to_camera(&self, p: V3<f64>) -> V3<f64> {
        let r = mat::mul_vec(&self.rotation, &p);
        [
            r[0] + self.translation[0],
            r[1] + self.translation[1],
            r[2] + self.translation[2],
        ]
    }

    /// The pixel coordinates `(u, v)` (continuous, pixel centres at `+0.5`) and depth of a world
    /// point, or `None` when it is not in front of the camera.
    pub fn project(&self, p: V3<f64>) -> Option<([f64; 2], f64)> {
        let c = self.to_camera(p);
        (c[2] > 0.0).then(|| {
            (
                [
                    self.fx * c[0] / c[2] + self.cx,
                    self.fy * c[1] / c[2] + self.cy,
                ],
                c[2],
            )
        })
    }

    /// Number of pixels.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// The same camera for an image downscaled by `factor` (intrinsics and size divided, size
    /// rounded as 3DGS's `-r` option does: Python's `round`, halves to even).
    pub fn downscaled(&self, factor: f64) -> Result<Self, GsError> {
        if !(factor.is_finite() && factor >= 1.0) {
            return Err(GsError::InvalidCamera(format!(
                "the downscale factor is {factor}; it must be a finite number of at least 1"
            )));
        }
        let width = (self.width as f64 / factor).round_ties_even() as u32;
        let height = (self.height as f64 / factor).round_ties_even() as u32;
        self.resized(width, height)
    }

    /// The same camera for the image resized to `width x height` (the field of view kept: the
    /// intrinsics scaled by the ratio of the sizes on each axis).
    pub fn resized(&self, width: u32, height: u32) -> Result<Self, GsError> {
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        Self::new(
            self.rotation,
            self.translation,
            [self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy],
            width,
            height,
        )
    }
}

fn cross(a: V3<f64>, b: V3<f64>) -> V3<f64> {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn normalize4(q: [f64; 4]) -> ([f64; 4], f64) {
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    if n > 0.0 {
        ([q[0] / n, q[1] / n, q[2] / n, q[3] / n], n)
    } else {
        (q, 0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: [f64; 2], b: [f64; 2]) -> bool {
        (a[0] - b[0]).abs() < 1e-9 && (a[1] - b[1]).abs() < 1e-9
    }

    #[test]
    fn nerf_camera_projects_known_points() {
        // Blender camera at z = 4 looking down -z (identity rotation in OpenGL axes).
        let c2w = [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 4.0],
            [0.0, 0.0, 0.0, 1.0],
        ];
        let fov = 2.0 * (0.5f64).atan(); // focal = width
        let cam = Camera::from_nerf(c2w, fov, 100, 80).unwrap();
        assert!((cam.fx - 100.0).abs() < 1e-9 && (cam.fy - 100.0).abs() < 1e-9);
        let (uv, depth) = cam.project([0.0, 0.0, 0.0]).unwrap();
        assert!(close(uv, [50.0, 40.0]) && (depth - 4.0).abs() < 1e-12);
        // World +x is image right, world +y (OpenGL up) is image up, i.e. smaller v.
        let (uv, _) = cam.project([1.0, 0.5, 0.0]).unwrap();
        assert!(close(uv, [75.0, 27.5]), "{uv:?}");
        assert!(cam.project([0.0, 0.0, 5.0]).is_none());
        let c = cam.centre();
        assert!((c[2] - 4.0).abs() < 1e-12 && c[0].abs() < 1e-12);
    }

    #[test]
    fn colmap_camera_projects_known_points() {
        // A 90 degree turn about y: world +x becomes the camera's -z... choose q for R = Ry(90).
        let half = std::f64::consts::FRAC_PI_4;
        let q = [half.cos(), 0.0, half.sin(), 0.0];
        let cam =
            Camera::from_colmap(q, [0.0, 0.0, 2.0], [200.0, 150.0, 64.0, 48.0], 128, 96).unwrap();
        // R = Ry(90deg) maps world (-1,0,0) to (0,0,1); plus t gives camera (0,0,3).
        let (uv, depth) = cam.project([-1.0, 0.0, 0.0]).unwrap();
        assert!(
            close(uv, [64.0, 48.0]) && (depth - 3.0).abs() < 1e-12,
            "{uv:?} {depth}"
        );
        // World (-1, 0.3, 0.6) -> Ry: (z, y, -x) = (0.6, 0.3, 1) + t -> (0.6, 0.3, 3).
        let (uv, _) = cam.project([-1.0, 0.3, 0.6]).unwrap();
        assert!(
            close(uv, [64.0 + 200.0 * 0.2, 48.0 + 150.0 * 0.1]),
            "{uv:?}"
        );
    }

    #[test]
    fn look_at_centres_the_target_and_keeps_up_up() {
        let cam = Camera::look_at([3.0, 0.0, 0.0], [0.0; 3], [0.0, 0.0, 1.0], 1.0, 64, 64).unwrap();
        let (uv, depth) = cam.project([0.0; 3]).unwrap();
        assert!(close(uv, [32.0, 32.0]) && (depth - 3.0).abs() < 1e-12);
        let (uv, _) = cam.project([0.0, 0.0, 0.5]).unwrap();
        assert!(uv[1] < 32.0, "up must be towards smaller v, got {uv:?}");
        assert!(Camera::look_at([0.0; 3], [0.0; 3], [0.0, 0.0, 1.0], 1.0, 8, 8).is_err());
    }

    #[test]
    fn downscaling_divides_size_and_intrinsics_and_rejects_bad_factors() {
        let id = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let cam = Camera::new(id, [0.0; 3], [100.0, 90.0, 50.0, 40.0], 100, 80).unwrap();
        let half = cam.downscaled(2.0).unwrap();
        assert_eq!((half.width, half.height), (50, 40));
        assert_eq!(
            [half.fx, half.fy, half.cx, half.cy],
            [50.0, 45.0, 25.0, 20.0]
        );
        for bad in [0.0, 0.5, f64::NAN, f64::INFINITY] {
            let e = cam.downscaled(bad).unwrap_err().to_string();
            assert!(e.contains("downscale"), "{e}");
        }
    }

    #[test]
    fn invalid_intrinsics_are_rejected_by_name() {
        let id = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let e = Camera::new(id, [0.0; 3], [0.0, 1.0, 1.0, 1.0], 4, 4).unwrap_err();
        assert!(e.to_string().contains("fx"), "{e}");
        let e = Camera::new(id, [0.0; 3], [1.0, 1.0, 1.0, 1.0], 0, 4).unwrap_err();
        assert!(e.to_string().contains("0x4"), "{e}");
    }
}
