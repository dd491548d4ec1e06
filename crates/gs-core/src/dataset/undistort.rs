//! Lens distortion undone once at load: a distorted picture is resampled to a pinhole camera
//! and cropped to the rectangle where every pixel comes from inside the picture, as gsplat's
//! COLMAP parser does with OpenCV (`getOptimalNewCameraMatrix` at `alpha = 0`, then
//! `initUndistortRectifyMap` and a bilinear `remap`).
//!
//! Coordinates: OpenCV's, pixel centres at whole numbers. COLMAP and nerfstudio put the first
//! pixel's centre at 0.5; their intrinsics are passed to the distortion model unshifted, as
//! gsplat passes them to OpenCV (half a pixel in where the lens centre is, which moves the
//! distortion by far less than a pixel). Normalized coordinates are `x = X / Z`, `y = Y / Z`.

/// A lens distortion in normalized camera coordinates, with OpenCV's conventions (which
/// COLMAP's camera models and nerfstudio's `k1..k4, p1, p2` share).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LensDistortion {
    /// OpenCV's perspective model: a point `(x, y)` at squared radius `r2` moves to
    /// `x * radial + 2 p1 x y + p2 (r2 + 2 x^2)`, `y * radial + p1 (r2 + 2 y^2) + 2 p2 x y`, with
    /// `radial = (1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + k5 r2^2 + k6 r2^3)`. COLMAP's
    /// SIMPLE_RADIAL, RADIAL, OPENCV and FULL_OPENCV are this model with some terms zero.
    Perspective {
        /// `k1..k6`: `k1..k3` the numerator's, `k4..k6` the denominator's.
        k: [f64; 6],
        /// Tangential `p1, p2`.
        p: [f64; 2],
    },
    /// OpenCV's fisheye (equidistant) model, COLMAP's OPENCV_FISHEYE: a ray at angle `theta`
    /// from the axis lands at normalized radius `theta (1 + k1 theta^2 + k2 theta^4 +
    /// k3 theta^6 + k4 theta^8)`.
    Fisheye {
        /// `k1..k4`.
        k: [f64; 4],
    },
}

/// Iterations of OpenCV's `undistortPoints` at its default termination (a count of 5).
const PERSPECTIVE_ITERATIONS: usize = 5;
/// Newton iterations and tolerance of OpenCV's `fisheye::undistortPoints`.
const FISHEYE_ITERATIONS: usize = 10;
const FISHEYE_EPS: f64 = 1e-8;
/// Points per side of the grid whose undistorted border gives the valid rectangle (OpenCV's
/// `getUndistortRectangles`).
const GRID: usize = 9;

impl LensDistortion {
    /// Whether every coefficient is zero (the lens is a pinhole already; a fisheye never is).
    pub fn is_none(&self) -> bool {
        match self {
            Self::Perspective { k, p } => k.iter().chain(p).all(|&v| v == 0.0),
            Self::Fisheye { .. } => false,
        }
    }

    /// Whether every coefficient is finite.
    pub fn is_finite(&self) -> bool {
        match self {
            Self::Perspective { k, p } => k.iter().chain(p).all(|v| v.is_finite()),
            Self::Fisheye { k } => k.iter().all(|v| v.is_finite()),
        }
    }

    /// Where the lens puts the ray through undistorted normalized `(x, y)` (`z = 1`).
    pub fn distort(&self, [x, y]: [f64; 2]) -> [f64; 2] {
        match *self {
            Self::Perspective { k, p } => {
                let r2 = x * x + y * y;
                let radial = (1.0 + ((k[2] * r2 + k[1]) * r2 + k[0]) * r2)
                    / (1.0 + ((k[5] * r2 + k[4]) * r2 + k[3]) * r2);
                [
                    x * radial + 2.0 * p[0] * x * y + p[1] * (r2 + 2.0 * x * x),
                    y * radial + p[0] * (r2 + 2.0 * y * y) + 2.0 * p[1] * x * y,
                ]
            }
            Self::Fisheye { k } => {
                let r = (x * x + y * y).sqrt();
                let theta = r.atan();
                let t2 = theta * theta;
                let theta_d = theta * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))));
                let scale = if r == 0.0 { 1.0 } else { theta_d / r };
                [x * scale, y * scale]
            }
        }
    }

    /// The undistorted normalized point whose ray the lens puts at `(xd, yd)`, as OpenCV's
    /// `undistortPoints` computes it at its default termination: perspective, exactly 5
    /// fixed-point steps (not converged for strong lenses; OpenCV's result, which its
    /// `getOptimalNewCameraMatrix` and so gsplat use), back to the start where the radial factor
    /// turns negative; fisheye (`fisheye::undistortPoints`), Newton on the angle from the
    /// distorted radius clamped to `pi / 2`, at most 10 steps to a change below 1e-8. `None`
    /// where the fisheye iteration does not converge or flips the side of the axis (OpenCV's
    /// `-1e6` marker).
    pub fn undistort(&self, [xd, yd]: [f64; 2]) -> Option<[f64; 2]> {
        match *self {
            Self::Perspective { k, p } => {
                let (mut x, mut y) = (xd, yd);
                for _ in 0..PERSPECTIVE_ITERATIONS {
                    let r2 = x * x + y * y;
                    let inverse_radial = (1.0 + ((k[5] * r2 + k[4]) * r2 + k[3]) * r2)
                        / (1.0 + ((k[2] * r2 + k[1]) * r2 + k[0]) * r2);
                    if inverse_radial < 0.0 {
                        return Some([xd, yd]);
                    }
                    let dx = 2.0 * p[0] * x * y + p[1] * (r2 + 2.0 * x * x);
                    let dy = p[0] * (r2 + 2.0 * y * y) + 2.0 * p[1] * x * y;
                    x = (xd - dx) * inverse_radial;
                    y = (yd - dy) * inverse_radial;
                }
                Some([x, y])
            }
            Self::Fisheye { k } => {
                let half_pi = std::f64::consts::FRAC_PI_2;
                let theta_d = (xd * xd + yd * yd).sqrt().clamp(-half_pi, half_pi);
                if theta_d <= FISHEYE_EPS {
                    return Some([0.0, 0.0]);
                }
                let mut theta = theta_d;
                let mut converged = false;
                for _ in 0..FISHEYE_ITERATIONS {
                    let t2 = theta * theta;
                    let (t4, t6, t8) = (t2 * t2, t2 * t2 * t2, t2 * t2 * t2 * t2);
                    let step = (theta * (1.0 + k[0] * t2 + k[1] * t4 + k[2] * t6 + k[3] * t8)
                        - theta_d)
                        / (1.0
                            + 3.0 * k[0] * t2
                            + 5.0 * k[1] * t4
                            + 7.0 * k[2] * t6
                            + 9.0 * k[3] * t8);
                    theta -= step;
                    if step.abs() < FISHEYE_EPS {
                        converged = true;
                        break;
                    }
                }
                if !converged || theta < 0.0 {
                    return None;
                }
                let scale = theta.tan() / theta_d;
                Some([xd * scale, yd * scale])
            }
        }
    }
}

/// Samples of the undistorted radius from the axis to a corner's, when checking a lens.
const RAY_STEPS: usize = 2048;
/// Samples of the distorted radius when checking OpenCV's undistortion along a ray.
const INVERSE_STEPS: usize = 256;
/// The furthest undistorted radius a corner may need: `tan 89.94°`.
const MAX_RADIUS: f64 = 1e3;
/// How far OpenCV's undistortion of a corner may be from the lens's own inverse (a factor).
const CORNER_FACTOR: f64 = 2.0;
/// The largest focal length a dataset camera may have, in multiples of its picture's longer
/// side (a field of view of 0.006 degrees).
pub const MAX_FOCAL_SIDES: f64 = 1e4;

/// Refuses dataset intrinsics `[fx, fy, cx, cy]` of a `width x height` picture that no camera
/// has: a focal length above [`MAX_FOCAL_SIDES`] times the longer side (the scene would
/// collapse to a point), or a principal point more than a picture away from it.
pub fn check_intrinsics([fx, fy, cx, cy]: [f64; 4], width: u32, height: u32) -> Result<(), String> {
    let (w, h) = (f64::from(width), f64::from(height));
    let most = MAX_FOCAL_SIDES * w.max(h);
    for (name, f) in [("fx", fx), ("fy", fy)] {
        if !(f.is_finite() && f > 0.0 && f <= most) {
            return Err(format!(
                "{name} = {}: a focal length in (0, {most}] pixels is expected for a \
                 {width}x{height} picture",
                number(f)
            ));
        }
    }
    for (name, c, side) in [("cx", cx, w), ("cy", cy, h)] {
        if !(c.is_finite() && (-side..=2.0 * side).contains(&c)) {
            return Err(format!(
                "{name} = {}: the principal point is more than a picture away from the \
                 {width}x{height} picture",
                number(c)
            ));
        }
    }
    Ok(())
}

/// `v` as a message prints it: plainly, or in scientific notation when very large or small.
fn number(v: f64) -> String {
    if v != 0.0 && v.is_finite() && !(1e-4..1e6).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

impl LensDistortion {
    /// The coefficients with their names (OpenCV's `k1..k6, p1, p2`; fisheye `k1..k4`).
    fn named(&self) -> Vec<(&'static str, f64)> {
        match *self {
            Self::Perspective { k, p } => ["k1", "k2", "k3", "k4", "k5", "k6", "p1", "p2"]
                .into_iter()
                .zip(k.into_iter().chain(p))
                .collect(),
            Self::Fisheye { k } => ["k1", "k2", "k3", "k4"].into_iter().zip(k).collect(),
        }
    }

    /// The coefficient whose term is largest at undistorted radius `r`: the one an error
    /// names.
    fn dominant(&self, r: f64) -> (&'static str, f64) {
        let powers: Vec<f64> = match self {
            Self::Perspective { .. } => {
                let r2 = r * r;
                vec![r2, r2 * r2, r2 * r2 * r2, r2, r2 * r2, r2 * r2 * r2, r, r]
            }
            Self::Fisheye { .. } => {
                let t2 = r.atan().powi(2);
                vec![t2, t2 * t2, t2 * t2 * t2, t2 * t2 * t2 * t2]
            }
        };
        let size = |c: f64, power: f64| match (c * power).abs() {
            t if t.is_nan() => f64::INFINITY,
            t => t,
        };
        self.named()
            .into_iter()
            .zip(powers)
            .max_by(|(a, pa), (b, pb)| size(a.1, *pa).total_cmp(&size(b.1, *pb)))
            .map_or(("k1", 0.0), |(named, _)| named)
    }

    /// Refuses this lens on a `width x height` picture of intrinsics `[fx, fy, cx, cy]` when
    /// its undistortion is not monotone over the picture: toward each corner, the lens's
    /// distorted radius must grow with the undistorted one until it reaches the corner, OpenCV's
    /// iterated undistortion ([`LensDistortion::undistort`]) must grow with the distorted radius,
    /// and its undistortion of the corner must lie within a factor of 2 of the lens's own
    /// inverse. A lens that fails renders as a pinhole or black; the error names the corner and
    /// the coefficient whose term dominates where it fails.
    pub fn check_over_picture(
        &self,
        [fx, fy, cx, cy]: [f64; 4],
        width: u32,
        height: u32,
    ) -> Result<(), String> {
        let (w, h) = (f64::from(width) - 1.0, f64::from(height) - 1.0);
        let fisheye = matches!(self, Self::Fisheye { .. });
        for [u, v] in [[0.0, 0.0], [w, 0.0], [0.0, h], [w, h]] {
            let corner = [(u - cx) / fx, (v - cy) / fy];
            let reach = corner[0].hypot(corner[1]);
            if reach == 0.0 {
                continue;
            }
            let dir = corner.map(|c| c / reach);
            // OpenCV's fisheye undistortion clamps the distorted radius to pi / 2.
            let target = if fisheye {
                reach.min(std::f64::consts::FRAC_PI_2)
            } else {
                reach
            };
            let along = |p: [f64; 2]| p[0] * dir[0] + p[1] * dir[1];
            let blame = |r: f64, what: String| {
                let (name, value) = self.dominant(r);
                format!(
                    "the lens is not monotone over the picture toward its corner ({u}, {v}): \
                     {what} ({name} = {} dominates there)",
                    number(value)
                )
            };
            // The lens: the distorted radius finite and strictly growing up to the corner.
            let (mut r, mut last, mut step) = (0.0, 0.0, 0);
            let reached = loop {
                step += 1;
                r = if step <= RAY_STEPS {
                    target * step as f64 / RAY_STEPS as f64
                } else {
                    r * 1.005
                };
                let distorted = along(self.distort(dir.map(|d| d * r)));
                if !(distorted.is_finite() && distorted > last) {
                    return Err(blame(
                        r,
                        format!(
                            "the distorted radius stops growing at radius {r:.4} ({distorted})"
                        ),
                    ));
                }
                if distorted >= target {
                    break r;
                }
                if r > MAX_RADIUS {
                    return Err(blame(
                        r,
                        format!(
                            "no ray within 89.9 degrees of the axis reaches radius {target:.4}"
                        ),
                    ));
                }
                last = distorted;
            };
            // The inverse the maps use: OpenCV's iteration, growing along the ray.
            let mut last = 0.0;
            for step in 1..=INVERSE_STEPS {
                let q = target * step as f64 / INVERSE_STEPS as f64;
                let undistorted = self.undistort(dir.map(|d| d * q)).map_or(f64::NAN, along);
                if !(undistorted.is_finite() && undistorted > last) {
                    return Err(blame(
                        reached,
                        format!("OpenCV's undistortion stops growing at distorted radius {q:.4}"),
                    ));
                }
                last = undistorted;
            }
            if !(reached / CORNER_FACTOR..=reached * CORNER_FACTOR).contains(&last) {
                return Err(blame(
                    reached,
                    format!(
                        "OpenCV's undistortion puts the corner at radius {last:.4}, the lens at \
                         {reached:.4}"
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// A distorted camera's picture resampled to a pinhole camera: the pinhole camera and crop,
/// and where each pixel of the undistorted, cropped picture lies in the stored one (computed
/// when asked: building one costs a 9 x 9 grid, so a caller that needs only the camera pays
/// nothing per pixel).
#[derive(Clone, Debug, PartialEq)]
pub struct Undistortion {
    /// Pinhole intrinsics `[fx, fy, cx, cy]` of the undistorted picture, crop included, pixels.
    pub intrinsics: [f64; 4],
    /// Width of the undistorted picture, pixels.
    pub width: u32,
    /// Height of the undistorted picture, pixels.
    pub height: u32,
    /// The crop `[x, y, width, height]` of the full undistorted picture that is kept, pixels.
    pub crop: [u32; 4],
    /// Size of the stored (distorted) picture, pixels.
    stored_width: u32,
    stored_height: u32,
    /// Intrinsics `[fx, fy, cx, cy]` of the stored picture, pixels.
    stored_intrinsics: [f64; 4],
    /// The lens undone.
    lens: LensDistortion,
    /// Pinhole intrinsics of the full undistorted picture, before the crop, pixels.
    uncropped: [f64; 4],
}

/// What undistorting a view's picture did: the camera model undone, the stored size, the crop
/// kept and the pinhole intrinsics of the result.
#[derive(Clone, Debug, PartialEq)]
pub struct Undistorted {
    /// The distorted camera's model (COLMAP's or nerfstudio's name).
    pub model: String,
    /// Width and height of the stored picture, pixels.
    pub stored: (u32, u32),
    /// The kept rectangle `[x, y, width, height]` of the undistorted picture, pixels.
    pub crop: [u32; 4],
    /// Pinhole `[fx, fy, cx, cy]` of the kept picture, pixels.
    pub intrinsics: [f64; 4],
}

impl std::fmt::Display for Undistorted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let [x, y, w, h] = self.crop;
        let [fx, fy, cx, cy] = self.intrinsics;
        write!(
            f,
            "{} {}x{} undistorted and cropped to {w}x{h} at ({x}, {y}); pinhole fx {fx:.2}, \
             fy {fy:.2}, cx {cx:.2}, cy {cy:.2}",
            self.model, self.stored.0, self.stored.1
        )
    }
}

impl Undistortion {
    /// The undistortion of a `width x height` picture taken with intrinsics `[fx, fy, cx, cy]`
    /// and `lens`: OpenCV's `getOptimalNewCameraMatrix` at `alpha = 0` gives the pinhole
    /// camera whose picture holds only valid pixels (the inner rectangle of the undistorted
    /// border of a 9 x 9 grid), and its valid rectangle is the crop, the principal point moved
    /// with it. An error says why no such camera exists (coefficients so strong the border
    /// folds over).
    pub fn new(
        [fx, fy, cx, cy]: [f64; 4],
        lens: LensDistortion,
        width: u32,
        height: u32,
    ) -> Result<Self, String> {
        if !lens.is_finite() {
            return Err(format!(
                "the distortion coefficients {lens:?} are not all finite"
            ));
        }
        lens.check_over_picture([fx, fy, cx, cy], width, height)?;
        let to_normalized = |[u, v]: [f64; 2]| [(u - cx) / fx, (v - cy) / fy];
        let inner = inner_rectangle(|p| lens.undistort(to_normalized(p)), width, height)
            .ok_or_else(|| {
                format!(
                    "the distortion {lens:?} folds the picture's border over itself; no \
                     undistorted picture holds only valid pixels"
                )
            })?;
        let new_fx = f64::from(width - 1) / inner[2];
        let new_fy = f64::from(height - 1) / inner[3];
        let new = [new_fx, new_fy, -new_fx * inner[0], -new_fy * inner[1]];
        let to_new_pixels = |[x, y]: [f64; 2]| [new[0] * x + new[2], new[1] * y + new[3]];
        let roi = inner_rectangle(
            |p| lens.undistort(to_normalized(p)).map(to_new_pixels),
            width,
            height,
        )
        .ok_or("the undistorted border folds over itself")?;
        let crop = valid_pixels(roi, width, height).ok_or_else(|| {
            format!("no pixel of the {width}x{height} picture stays valid once undistorted")
        })?;
        let [x0, y0, w, h] = crop;
        Ok(Self {
            intrinsics: [
                new[0],
                new[1],
                new[2] - f64::from(x0),
                new[3] - f64::from(y0),
            ],
            width: w,
            height: h,
            crop,
            stored_width: width,
            stored_height: height,
            stored_intrinsics: [fx, fy, cx, cy],
            lens,
            uncropped: new,
        })
    }

    /// What this undistortion does, for a run to report: `model` names the distorted camera.
    pub fn report(&self, model: &str) -> Undistorted {
        Undistorted {
            model: model.to_string(),
            stored: (self.stored_width, self.stored_height),
            crop: self.crop,
            intrinsics: self.intrinsics,
        }
    }

    /// Where undistorted pixel `(x, y)` (of the cropped picture) lies in the stored picture.
    pub fn source(&self, x: u32, y: u32) -> [f32; 2] {
        let new = self.uncropped;
        let normalized = [
            (f64::from(x + self.crop[0]) - new[2]) / new[0],
            (f64::from(y + self.crop[1]) - new[3]) / new[1],
        ];
        let [xd, yd] = self.lens.distort(normalized);
        let [fx, fy, cx, cy] = self.stored_intrinsics;
        [(fx * xd + cx) as f32, (fy * yd + cy) as f32]
    }

    /// `picture` (the stored one, RGBA) resampled: each undistorted pixel bilinear between its
    /// four stored neighbours, neighbours outside the picture counting as 0 (OpenCV's
    /// `remap` with `INTER_LINEAR` and a zero constant border, with exact weights as OpenCV 5
    /// computes them; OpenCV 4 rounds the position to 1/32 pixel first).
    pub fn apply(&self, picture: &image::Rgba32FImage) -> image::Rgba32FImage {
        let (w, h) = (picture.width() as i64, picture.height() as i64);
        let texel = |x: i64, y: i64| {
            if (0..w).contains(&x) && (0..h).contains(&y) {
                picture.get_pixel(x as u32, y as u32).0
            } else {
                [0.0; 4]
            }
        };
        image::Rgba32FImage::from_fn(self.width, self.height, |x, y| {
            let [u, v] = self.source(x, y);
            let (u0, v0) = (u.floor(), v.floor());
            let (fu, fv) = (u - u0, v - v0);
            let (x0, y0) = (u0 as i64, v0 as i64);
            let corners = [
                (texel(x0, y0), (1.0 - fu) * (1.0 - fv)),
                (texel(x0 + 1, y0), fu * (1.0 - fv)),
                (texel(x0, y0 + 1), (1.0 - fu) * fv),
                (texel(x0 + 1, y0 + 1), fu * fv),
            ];
            let mut out = [0.0f32; 4];
            for (value, weight) in corners {
                for c in 0..4 {
                    out[c] += weight * value[c];
                }
            }
            image::Rgba(out)
        })
    }
}

/// The inner rectangle `[x, y, width, height]` of the border of a 9 x 9 grid over a
/// `width x height` picture (pixels `0..=width - 1`, `0..=height - 1`) mapped by `map` (OpenCV's
/// `icvGetRectangles`: the largest left-column x, smallest right-column x, largest top-row y and
/// smallest bottom-row y, in `f64`); `None` where a point does not map or the rectangle is
/// empty.
fn inner_rectangle(
    map: impl Fn([f64; 2]) -> Option<[f64; 2]>,
    width: u32,
    height: u32,
) -> Option<[f64; 4]> {
    let (mut left, mut right) = (f64::NEG_INFINITY, f64::INFINITY);
    let (mut top, mut bottom) = (f64::NEG_INFINITY, f64::INFINITY);
    let step_x = f64::from(width - 1) / (GRID - 1) as f64;
    let step_y = f64::from(height - 1) / (GRID - 1) as f64;
    for row in 0..GRID {
        for column in 0..GRID {
            let [x, y] = map([column as f64 * step_x, row as f64 * step_y])?;
            if column == 0 {
                left = left.max(x);
            }
            if column == GRID - 1 {
                right = right.min(x);
            }
            if row == 0 {
                top = top.max(y);
            }
            if row == GRID - 1 {
                bottom = bottom.min(y);
            }
        }
    }
    let rectangle = [left, top, right - left, bottom - top];
    (rectangle.iter().all(|v| v.is_finite()) && rectangle[2] > 0.0 && rectangle[3] > 0.0)
        .then_some(rectangle)
}

/// The whole-pixel rectangle of `rectangle` as OpenCV converts it (`x`, `y`, `width` and
/// `height` each rounded to the nearest integer, ties to even), cut to the picture; `None` where
/// nothing is left. At `alpha = 0` it is `[0, 0, width - 1, height - 1]`: the last column and
/// row are dropped, as gsplat's crop drops them.
fn valid_pixels([x, y, w, h]: [f64; 4], width: u32, height: u32) -> Option<[u32; 4]> {
    let round = |v: f64| v.round_ties_even() as i64;
    let (x0, y0) = (round(x).max(0), round(y).max(0));
    let x1 = (round(x) + round(w)).min(i64::from(width));
    let y1 = (round(y) + round(h)).min(i64::from(height));
    (x1 > x0 && y1 > y0).then(|| [x0, y0, x1 - x0, y1 - y0].map(|v| v as u32))
}
