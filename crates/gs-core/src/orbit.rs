//! Cameras made from a Gaussian set alone, for a model that comes without the cameras it was
//! trained from: where the Gaussians are ([`RobustBounds`]: the opacity-weighted median and
//! the radius holding 95 % of the opacity, so stray floaters do not move or swell it) and
//! views of them ([`orbit`]), either from outside looking in ([`OrbitKind::Object`]) or from
//! the centre looking out ([`OrbitKind::Inside`], a room or garden seen from within).
//!
//! The view directions are a golden-angle spiral over the sphere without its polar caps
//! (elevations within ±[`MAX_ELEVATION_DEGREES`] of the plane across `up`), the same for both
//! kinds, so the views are spread evenly and each has a well-defined up.

use crate::mat::{self, V3};
use crate::{Camera, GaussianSet};

/// Horizontal field of view of the object orbit, degrees: NeRF-synthetic's cameras' (0.6911
/// rad).
pub const OBJECT_FOV_DEGREES: f64 = 39.6;
/// Horizontal field of view of the inside orbit, degrees.
pub const INSIDE_FOV_DEGREES: f64 = 90.0;
/// The highest and lowest elevation of a view direction, degrees.
pub const MAX_ELEVATION_DEGREES: f64 = 75.0;
/// The share of the opacity the robust radius holds.
pub const RADIUS_SHARE: f64 = 0.95;
/// How far outside the robust sphere the object orbit stands: the sphere fills this share of
/// the narrower field of view.
const FILL: f64 = 1.0 / 1.1;
/// The inside orbit is chosen when less than this share of the opacity lies within
/// [`HOLLOW_RADIUS`] of the robust radius around the centre.
pub const HOLLOW_SHARE: f64 = 0.005;
/// See [`HOLLOW_SHARE`].
pub const HOLLOW_RADIUS: f64 = 0.25;

/// How the cameras of an orbit see the Gaussians.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OrbitKind {
    /// From outside the robust sphere, looking at its centre (an object, a captured thing).
    Object,
    /// From the centre, looking out (a room or garden captured from within).
    Inside,
}

impl OrbitKind {
    /// Both kinds, in the order the help lists them.
    pub const ALL: [Self; 2] = [Self::Object, Self::Inside];

    /// The name a configuration and the command line use.
    pub fn name(self) -> &'static str {
        match self {
            Self::Object => "object",
            Self::Inside => "inside",
        }
    }

    /// The kind called `name`.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }
}

/// Where a Gaussian set is: the centre and radius its opacity says, outliers apart.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobustBounds {
    /// The opacity-weighted median of the means, axis by axis, world units.
    pub centre: V3<f64>,
    /// The distance from the centre within which [`RADIUS_SHARE`] of the opacity lies, world
    /// units; positive.
    pub radius: f64,
    /// The share of the opacity within [`HOLLOW_RADIUS`] of the radius around the centre.
    pub central_share: f64,
    /// How many Gaussians were weighed: those with a finite mean and opacity.
    pub counted: usize,
}

impl RobustBounds {
    /// The bounds of `set`, each Gaussian weighed by its opacity `sigmoid(logit)`; an error
    /// when no Gaussian has a finite mean and a non-zero opacity, or they all sit at one point.
    pub fn of(set: &GaussianSet) -> Result<Self, String> {
        let mut points = Vec::new();
        for (mean, &logit) in set.means.chunks_exact(3).zip(&set.opacity_logits) {
            let p = [mean[0], mean[1], mean[2]].map(f64::from);
            let weight = 1.0 / (1.0 + (-f64::from(logit)).exp());
            if p.iter().all(|v| v.is_finite()) && weight.is_finite() && weight > 0.0 {
                points.push((p, weight));
            }
        }
        let total: f64 = points.iter().map(|(_, w)| w).sum();
        if points.is_empty() || total <= 0.0 {
            return Err(format!(
                "none of the {} Gaussians has a finite position and an opacity above 0: there \
                 is nothing to place cameras around",
                set.len()
            ));
        }
        let centre = [0, 1, 2].map(|k| {
            let mut axis: Vec<(f64, f64)> = points.iter().map(|(p, w)| (p[k], *w)).collect();
            weighted_quantile(&mut axis, 0.5)
        });
        let mut distances: Vec<(f64, f64)> = points
            .iter()
            .map(|(p, w)| {
                let d = (0..3).map(|k| (p[k] - centre[k]).powi(2)).sum::<f64>();
                (d.sqrt(), *w)
            })
            .collect();
        let radius = weighted_quantile(&mut distances, RADIUS_SHARE);
        if !(radius > 0.0 && radius.is_finite()) {
            return Err(format!(
                "the Gaussians' opacity lies at one point ({centre:?}): there is no extent to \
                 place cameras around"
            ));
        }
        let central: f64 = distances
            .iter()
            .filter(|(d, _)| *d < HOLLOW_RADIUS * radius)
            .map(|(_, w)| w)
            .sum();
        Ok(Self {
            centre,
            radius,
            central_share: central / total,
            counted: points.len(),
        })
    }

    /// The orbit a model of these bounds gets by default: [`OrbitKind::Inside`] when its
    /// centre is hollow (less than [`HOLLOW_SHARE`] of the opacity within [`HOLLOW_RADIUS`] of
    /// the radius: Gaussians around a viewer, as a room's walls), [`OrbitKind::Object`]
    /// otherwise.
    pub fn default_kind(&self) -> OrbitKind {
        if self.central_share < HOLLOW_SHARE {
            OrbitKind::Inside
        } else {
            OrbitKind::Object
        }
    }
}

/// The value below which `share` of the total weight lies, of `(value, weight)` pairs (sorted
/// here by value): the smallest value whose cumulative weight reaches `share` of the total.
fn weighted_quantile(pairs: &mut [(f64, f64)], share: f64) -> f64 {
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let total: f64 = pairs.iter().map(|(_, w)| w).sum();
    let mut sum = 0.0;
    for &(value, weight) in pairs.iter() {
        sum += weight;
        if sum >= share * total {
            return value;
        }
    }
    pairs.last().map_or(0.0, |p| p.0)
}

/// The `count` view directions: a golden-angle spiral over the sphere between the elevations
/// ±[`MAX_ELEVATION_DEGREES`] about `up` (unit vectors, world axes).
fn directions(count: usize, up: V3<f64>) -> Vec<V3<f64>> {
    // Two axes across `up`: the world axis least along it, made orthogonal.
    let (up, _) = mat::normalize3(up);
    let least = (0..3)
        .min_by(|&a, &b| up[a].abs().total_cmp(&up[b].abs()))
        .unwrap_or(0);
    let mut axis = [0.0; 3];
    axis[least] = 1.0;
    let (e1, _) = mat::normalize3(cross(up, axis));
    let e2 = cross(up, e1);
    let top = MAX_ELEVATION_DEGREES.to_radians().sin();
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..count)
        .map(|i| {
            let h = top * (1.0 - 2.0 * (i as f64 + 0.5) / count as f64);
            let across = (1.0 - h * h).sqrt();
            let (s, c) = (golden * i as f64).sin_cos();
            [0, 1, 2].map(|k| h * up[k] + across * (c * e1[k] + s * e2[k]))
        })
        .collect()
}

fn cross(a: V3<f64>, b: V3<f64>) -> V3<f64> {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// `count` cameras of `width` x `height` pixels around `bounds` as `kind` says, with `up`
/// (world) upwards in every picture:
/// - [`OrbitKind::Object`]: on the sphere around the centre at the distance where the robust
///   sphere fills [`FILL`] of the narrower field of view ([`OBJECT_FOV_DEGREES`] across),
///   looking at the centre;
/// - [`OrbitKind::Inside`]: at the centre, looking out along each direction
///   ([`INSIDE_FOV_DEGREES`] across).
///
/// An error for no cameras, an empty picture or an `up` of no direction.
pub fn orbit(
    bounds: &RobustBounds,
    kind: OrbitKind,
    count: usize,
    (width, height): (u32, u32),
    up: V3<f64>,
) -> Result<Vec<Camera>, String> {
    if count == 0 || width == 0 || height == 0 {
        return Err(format!(
            "an orbit of {count} views of {width}x{height} pixels has nothing to see"
        ));
    }
    if !(up.iter().all(|v| v.is_finite()) && up.iter().any(|v| *v != 0.0)) {
        return Err(format!("up {up:?} is no direction"));
    }
    let c = bounds.centre;
    directions(count, up)
        .into_iter()
        .map(|d| {
            match kind {
                OrbitKind::Object => {
                    let fov_x = OBJECT_FOV_DEGREES.to_radians();
                    let half_narrow = ((fov_x / 2.0).tan() * f64::from(width.min(height))
                        / f64::from(width))
                    .atan();
                    let distance = bounds.radius / (FILL * half_narrow.sin());
                    let eye = [0, 1, 2].map(|k| c[k] + distance * d[k]);
                    Camera::look_at(eye, c, up, fov_x, width, height)
                }
                OrbitKind::Inside => {
                    let target = [0, 1, 2].map(|k| c[k] + d[k]);
                    Camera::look_at(
                        c,
                        target,
                        up,
                        INSIDE_FOV_DEGREES.to_radians(),
                        width,
                        height,
                    )
                }
            }
            .map_err(|e| e.to_string())
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Gaussians spread over a ball (`hollow` false; evenly in radius, so denser inwards, as
    /// an object's inner surfaces) or a shell (true) of radius 1 around `centre`, opaque, and
    /// `floaters` further out and faint.
    fn cloud(centre: V3<f64>, hollow: bool, floaters: usize) -> GaussianSet {
        let n = 400;
        let mut set = GaussianSet::zeros(n + floaters, 0);
        for (i, d) in directions(n, [0.0, -1.0, 0.0]).into_iter().enumerate() {
            let r = if hollow {
                1.0
            } else {
                0.05 + 0.95 * ((i as f64 * 0.618_034) % 1.0)
            };
            for k in 0..3 {
                set.means[3 * i + k] = (centre[k] + r * d[k]) as f32;
            }
            set.opacity_logits[i] = 3.0;
        }
        // Faint floaters two to three radii out, in directions of their own.
        for (j, d) in directions(floaters, [0.3, 1.0, 0.2])
            .into_iter()
            .enumerate()
        {
            let i = n + j;
            for k in 0..3 {
                set.means[3 * i + k] = (centre[k] + (2.0 + j as f64 / 4.0) * d[k]) as f32;
            }
            set.opacity_logits[i] = -1.0;
        }
        set
    }

    #[test]
    fn the_bounds_keep_to_the_opaque_gaussians() {
        let set = cloud([2.0, -1.0, 0.5], false, 8);
        let b = RobustBounds::of(&set).unwrap();
        for k in 0..3 {
            assert!((b.centre[k] - [2.0, -1.0, 0.5][k]).abs() < 0.1, "{b:?}");
        }
        assert!(b.radius > 0.8 && b.radius <= 1.0, "floaters cut: {b:?}");
        assert_eq!(b.default_kind(), OrbitKind::Object, "{b:?}");
        let shell = RobustBounds::of(&cloud([0.0; 3], true, 0)).unwrap();
        assert_eq!(shell.default_kind(), OrbitKind::Inside, "{shell:?}");
    }

    #[test]
    fn a_set_with_nothing_to_see_is_refused() {
        let mut set = GaussianSet::zeros(3, 0);
        set.means.fill(f32::NAN);
        assert!(RobustBounds::of(&set)
            .unwrap_err()
            .to_string()
            .contains("3 Gaussians"));
        let mut point = GaussianSet::zeros(3, 0);
        point.opacity_logits.fill(2.0);
        assert!(RobustBounds::of(&point)
            .unwrap_err()
            .to_string()
            .contains("one point"));
        let mut transparent = cloud([0.0; 3], false, 0);
        transparent.opacity_logits.fill(f32::NEG_INFINITY);
        assert!(RobustBounds::of(&transparent).is_err());
    }

    /// The weighted quantile at its thresholds: a cumulative weight exactly at the share takes
    /// that value, just below it the next.
    #[test]
    fn the_weighted_quantile_takes_the_first_value_reaching_the_share() {
        let mut pairs = [(3.0, 1.0), (1.0, 1.0), (2.0, 2.0)];
        assert_eq!(weighted_quantile(&mut pairs, 0.25), 1.0);
        assert_eq!(weighted_quantile(&mut pairs, 0.26), 2.0);
        assert_eq!(weighted_quantile(&mut pairs, 0.75), 2.0);
        assert_eq!(weighted_quantile(&mut pairs, 0.76), 3.0);
    }

    /// Every Gaussian's centre projects into at least one view, floaters included; an object's
    /// cameras stand outside the robust sphere and see all of it in every view.
    #[test]
    fn the_orbits_see_every_gaussian() {
        for (hollow, kind) in [
            (false, OrbitKind::Object),
            (true, OrbitKind::Inside),
            (false, OrbitKind::Inside),
        ] {
            let set = cloud([1.0, 2.0, -3.0], hollow, 4);
            let bounds = RobustBounds::of(&set).unwrap();
            for (count, size) in [(24, (64, 48)), (32, (40, 80))] {
                let cameras = orbit(&bounds, kind, count, size, [0.0, -1.0, 0.0]).unwrap();
                assert_eq!(cameras.len(), count);
                let seen = |p: V3<f64>, c: &Camera| {
                    c.project(p).is_some_and(|([x, y], _)| {
                        (0.0..f64::from(c.width)).contains(&x)
                            && (0.0..f64::from(c.height)).contains(&y)
                    })
                };
                for (i, m) in set.means.chunks_exact(3).enumerate() {
                    let p = [m[0], m[1], m[2]].map(f64::from);
                    let views = cameras.iter().filter(|c| seen(p, c)).count();
                    assert!(
                        views > 0,
                        "{kind:?}, {count} views: Gaussian {i} at {p:?} unseen"
                    );
                    let within = (0..3)
                        .map(|k| (p[k] - bounds.centre[k]).powi(2))
                        .sum::<f64>()
                        .sqrt()
                        <= bounds.radius;
                    if kind == OrbitKind::Object && within {
                        assert_eq!(views, count, "an object's views each see all of it");
                    }
                }
                for c in &cameras {
                    let e = c.centre();
                    let d = (0..3)
                        .map(|k| (e[k] - bounds.centre[k]).powi(2))
                        .sum::<f64>()
                        .sqrt();
                    match kind {
                        OrbitKind::Object => {
                            assert!(d > bounds.radius, "a camera inside the object")
                        }
                        OrbitKind::Inside => assert!(d < 1e-9),
                    }
                    // `up` is up in the picture: a point above the centre projects above it.
                    let above = [0, 1, 2].map(|k| bounds.centre[k] - [0.0, 0.1, 0.0][k]);
                    if let (Some((a, _)), Some((b, _))) =
                        (c.project(above), c.project(bounds.centre))
                    {
                        assert!(a[1] < b[1] + 1e-9, "up is down in the picture");
                    }
                }
            }
        }
    }

    #[test]
    fn impossible_orbits_are_refused() {
        let bounds = RobustBounds::of(&cloud([0.0; 3], false, 0)).unwrap();
        assert!(orbit(&bounds, OrbitKind::Object, 0, (8, 8), [0.0, 1.0, 0.0]).is_err());
        assert!(orbit(&bounds, OrbitKind::Object, 3, (0, 8), [0.0, 1.0, 0.0]).is_err());
        assert!(orbit(&bounds, OrbitKind::Object, 3, (8, 8), [0.0; 3]).is_err());
        assert!(orbit(&bounds, OrbitKind::Object, 3, (8, 8), [f64::NAN, 1.0, 0.0]).is_err());
    }
}
