//! The views of a run given a scene's model without its dataset (3D and 4D): cameras from a
//! cameras file ([`ModelViews::cameras`]), else from the INRIA `cameras.json` beside the model,
//! else an orbit made from the model ([`gs_core::orbit`]). The modality renders the model
//! from them as each view's ground truth ([`model_picture`]) and refuses views that all show
//! nothing ([`all_empty`]). [`ModelViewFlags`] are the flags that set them.

use std::path::{Path, PathBuf};

use gs_core::dataset::inria_cameras;
use gs_core::dataset::nerf_synthetic::{self, TrainSplits};
use gs_core::dataset::{
    colmap, scene_extent, Dataset, DatasetError, DatasetView, Layout, LoadOptions,
};
use gs_core::model::View;
use gs_core::orbit::{orbit, OrbitKind, RobustBounds};
use gs_core::Image;
use serde::{Deserialize, Serialize};

use crate::StylizeError;

/// The views of an orbit unless set.
pub const DEFAULT_ORBIT_VIEWS: usize = 64;
/// The width and height of an orbit's pictures unless set, pixels.
pub const DEFAULT_ORBIT_SIZE: u32 = 800;
/// A rendered view differing from the background by less than this anywhere is empty (it
/// would not change an 8-bit picture).
const EMPTY: f32 = 0.5 / 255.0;

/// Where the views of a run without data come from: configuration fields of the 3D and 4D
/// runs (flattened into them).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ModelViews {
    /// Without `data`, the cameras to train from: an INRIA `cameras.json`, a NeRF or
    /// nerfstudio transforms file or folder, or a COLMAP folder (or its `sparse/`); their
    /// pictures are not decoded (a picture's header is read where the file gives no size).
    pub cameras: Option<PathBuf>,
    /// Without `data` or `cameras`, cameras made from the model: `object` (around it, looking
    /// in) or `inside` (from its centre, looking out: a room or garden captured from within).
    /// When unset, a `cameras.json` beside the model is taken if there is one, else the orbit
    /// is `inside` where the model's centre is hollow (under 0.5 % of its opacity within a
    /// quarter of its radius) and `object` otherwise.
    pub orbit: Option<OrbitKind>,
    /// How many views the orbit has.
    pub orbit_views: usize,
    /// The orbit's picture width, pixels.
    pub width: u32,
    /// The orbit's picture height, pixels.
    pub height: u32,
    /// The world direction that is up in the orbit's pictures: `[0, -1, 0]` by default, as
    /// in 3DGS's frame (y down, as COLMAP scenes have it); `[0, 0, 1]` for a scene trained from
    /// Blender (NeRF-synthetic, D-NeRF) cameras.
    pub up: [f64; 3],
}

impl Default for ModelViews {
    fn default() -> Self {
        Self {
            cameras: None,
            orbit: None,
            orbit_views: DEFAULT_ORBIT_VIEWS,
            width: DEFAULT_ORBIT_SIZE,
            height: DEFAULT_ORBIT_SIZE,
            up: [0.0, -1.0, 0.0],
        }
    }
}

impl ModelViews {
    /// Checks the fields, and that `cameras` and `orbit` are left out of a run with data
    /// (`has_data`), naming the field and its flag.
    pub fn validate(&self, has_data: bool) -> Result<(), StylizeError> {
        let bad = |field: &str, why: String| Err(StylizeError::Config(format!("{field}: {why}")));
        for (field, set) in [
            ("cameras", self.cameras.is_some()),
            ("orbit", self.orbit.is_some()),
        ] {
            if has_data && set {
                return bad(
                    field,
                    format!(
                        "a run with data (--data) trains on the dataset's own cameras and \
                         pictures; leave out --{field} or --data"
                    ),
                );
            }
        }
        if self.cameras.is_some() && self.orbit.is_some() {
            return bad(
                "orbit",
                "the cameras (--cameras) are given; an orbit is made only without them: leave \
                 out --orbit or --cameras"
                    .into(),
            );
        }
        if self.orbit_views == 0 {
            return bad("orbit_views", "must be at least 1 (--orbit-views)".into());
        }
        for (field, value) in [("width", self.width), ("height", self.height)] {
            if value == 0 {
                return bad(field, format!("must be at least 1 pixel (--{field})"));
            }
        }
        if !(self.up.iter().all(|v| v.is_finite()) && self.up.iter().any(|v| *v != 0.0)) {
            return bad(
                "up",
                format!("{:?} is no direction (e.g. --set up=[0,-1,0])", self.up),
            );
        }
        Ok(())
    }

    /// The views for the model at `model_path` (of `bounds`), as the module documentation
    /// says, and where they came from, in words; camera files are read with `options`, a NeRF
    /// folder's splits as `splits` says. No picture is decoded.
    pub fn views(
        &self,
        model_path: &Path,
        bounds: &RobustBounds,
        splits: TrainSplits,
        options: &LoadOptions,
    ) -> Result<(Vec<DatasetView>, String), StylizeError> {
        if let Some(path) = &self.cameras {
            let views = camera_file(path, splits, options)?;
            return Ok((views, format!("from {}", path.display())));
        }
        let kind = match (self.orbit, inria_cameras::beside(model_path)) {
            (Some(kind), _) => kind,
            (None, Some(path)) => {
                let views = inria_cameras::read(&path, options).map_err(|e| dataset(&path, e))?;
                return Ok((views, format!("from {} (beside the model)", path.display())));
            }
            (None, None) => bounds.default_kind(),
        };
        let cameras = orbit(
            bounds,
            kind,
            self.orbit_views,
            (self.width, self.height),
            self.up,
        )
        .map_err(|e| StylizeError::Input(format!("orbit: {e}")))?;
        let how = match (kind, self.orbit) {
            (OrbitKind::Object, None) => {
                "an object orbit (chosen: the model's centre is filled; --orbit inside looks \
                 out from it)"
            }
            (OrbitKind::Inside, None) => {
                "an inside orbit (chosen: the model's centre is hollow; --orbit object looks \
                 in from around it)"
            }
            (OrbitKind::Object, Some(_)) => "an object orbit",
            (OrbitKind::Inside, Some(_)) => "an inside orbit",
        };
        let c = bounds.centre;
        let from = format!(
            "of {how}, {}x{} pixels, about the model's centre [{:.3}, {:.3}, {:.3}] of radius \
             {:.3}",
            self.width, self.height, c[0], c[1], c[2], bounds.radius
        );
        let views = cameras
            .into_iter()
            .map(|camera| DatasetView {
                view: View::still(camera),
                picture: PathBuf::new(),
            })
            .collect();
        Ok((views, from))
    }
}

/// The `stylize` flags of [`ModelViews`] (3D and 4D), serialized to the fields they set. The
/// binary's `--data` flag excludes `--cameras` and `--orbit`.
#[derive(clap::Args, Debug, Default, Serialize)]
pub struct ModelViewFlags {
    /// Without --data, the cameras to train from: an INRIA cameras.json, a NeRF or nerfstudio
    /// transforms file (or its folder), or a COLMAP folder (or its sparse/); their pictures
    /// are not decoded (where the file gives no size, a picture's header is read).
    #[arg(long, conflicts_with = "data")]
    #[serde(skip_serializing_if = "Option::is_none")]
    cameras: Option<PathBuf>,
    /// Without --data or --cameras, cameras made from the model: object (around it, looking
    /// in) or inside (from its centre, looking out: a room or garden captured from within).
    /// Default: a cameras.json beside the model when there is one, else inside where the
    /// model's centre is hollow and object otherwise.
    #[arg(long, value_parser = orbit_parser(), conflicts_with_all = ["data", "cameras"])]
    #[serde(skip_serializing_if = "Option::is_none")]
    orbit: Option<OrbitKind>,
    /// The number of views of the orbit (default 64).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    orbit_views: Option<usize>,
    /// The width of the orbit's pictures, pixels (default 800).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    width: Option<u32>,
    /// The height of the orbit's pictures, pixels (default 800).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    height: Option<u32>,
}

/// `--orbit`'s values, by their names.
fn orbit_parser() -> impl clap::builder::TypedValueParser<Value = OrbitKind> {
    use clap::builder::TypedValueParser;
    clap::builder::PossibleValuesParser::new(OrbitKind::ALL.map(OrbitKind::name))
        .map(|name| OrbitKind::from_name(&name).expect("a name of OrbitKind::ALL"))
}

/// The dataset of a run without data: `views` with the model's renders `images` as their
/// pictures (named `view 000`, ...), no masks, over `background`; the extent INRIA's rule
/// gives the cameras, or the model's robust radius (`bounds`) where they all stand at one
/// point (the inside orbit).
pub fn model_dataset(
    views: Vec<View>,
    images: Vec<Image>,
    background: [f32; 3],
    bounds: &RobustBounds,
) -> Dataset {
    let n = views.len();
    let extent = match scene_extent(&views) {
        e if e > 1e-9 * bounds.radius => e,
        _ => bounds.radius,
    };
    Dataset {
        image_paths: (0..n)
            .map(|i| PathBuf::from(format!("view {i:03}")))
            .collect(),
        views,
        images,
        masks: vec![None; n],
        background,
        extent,
        points: None,
        undistorted: vec![None; n],
    }
}

/// A render as a view's ground truth: clamped to `[0, 1]` as a picture holds it (not rounded
/// to 8 bits).
pub fn model_picture(mut render: Image) -> Image {
    render.data.iter_mut().for_each(|v| *v = v.clamp(0.0, 1.0));
    render
}

/// Whether every picture of `images` is within half an 8-bit level of `background`
/// everywhere: views that see nothing of the model.
pub fn all_empty(images: &[Image], background: [f32; 3]) -> bool {
    images.iter().all(|image| {
        image
            .data
            .chunks_exact(3)
            .all(|p| (0..3).all(|k| (p[k] - background[k]).abs() < EMPTY))
    })
}

/// The error of a run whose views of the model at `model` (`count` of them, from `from`) all
/// show nothing.
pub fn nothing_seen(model: &Path, count: usize, from: &str) -> StylizeError {
    StylizeError::Input(format!(
        "model {}: none of the {count} view(s) {from} sees any of its Gaussians; give cameras \
         that see it with --cameras (an INRIA cameras.json, a transforms file or a COLMAP \
         folder)",
        model.display()
    ))
}

/// `source` as the run's error about the camera file `path`.
fn dataset(path: &Path, source: DatasetError) -> StylizeError {
    StylizeError::Dataset {
        path: path.to_path_buf(),
        source: Box::new(source),
    }
}

/// The cameras of `path`: an INRIA `cameras.json` (a JSON array), or the dataset folder it is
/// or is in (a transforms file's folder; a COLMAP folder, or its `sparse/` or `sparse/0`),
/// the NeRF splits as `splits` says. No picture is decoded.
fn camera_file(
    path: &Path,
    splits: TrainSplits,
    options: &LoadOptions,
) -> Result<Vec<DatasetView>, StylizeError> {
    let fail = |e| dataset(path, e);
    if path.is_file() && starts_as_array(path).map_err(fail)? {
        return inria_cameras::read(path, options).map_err(fail);
    }
    let start = if path.is_file() {
        path.parent()
    } else {
        Some(path)
    };
    let found = std::iter::successors(start, |p| p.parent())
        .take(3)
        .find_map(|folder| Layout::detect(folder).map(|layout| (folder, layout)));
    match found {
        Some((folder, Layout::NerfSynthetic)) => {
            nerf_synthetic::training_views(folder, splits, options).map_err(|e| dataset(folder, e))
        }
        Some((folder, Layout::Colmap)) => {
            colmap::views(folder, options).map_err(|e| dataset(folder, e))
        }
        None if !path.exists() => Err(StylizeError::Input(format!(
            "cameras {}: not found",
            path.display()
        ))),
        None => Err(StylizeError::Input(format!(
            "cameras {}: not cameras this reader knows: an INRIA cameras.json (a JSON array), \
             a NeRF or nerfstudio transforms file or its folder, or a COLMAP folder",
            path.display()
        ))),
    }
}

/// Whether the file at `path` starts, after white space, with `[`.
fn starts_as_array(path: &Path) -> Result<bool, DatasetError> {
    let head = gs_core::fs::read_head(path, 4096).map_err(|source| DatasetError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    Ok(head.iter().find(|b| !b.is_ascii_whitespace()) == Some(&b'['))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_settings_are_checked_naming_the_field_and_flag() {
        let ok = ModelViews::default();
        assert!(ok.validate(false).is_ok() && ok.validate(true).is_ok());
        let cases = [
            (
                ModelViews {
                    cameras: Some("c.json".into()),
                    ..ModelViews::default()
                },
                true,
                "cameras: a run with data",
            ),
            (
                ModelViews {
                    orbit: Some(OrbitKind::Object),
                    ..ModelViews::default()
                },
                true,
                "--orbit or --data",
            ),
            (
                ModelViews {
                    cameras: Some("c.json".into()),
                    orbit: Some(OrbitKind::Inside),
                    ..ModelViews::default()
                },
                false,
                "leave out --orbit or --cameras",
            ),
            (
                ModelViews {
                    orbit_views: 0,
                    ..ModelViews::default()
                },
                false,
                "--orbit-views",
            ),
            (
                ModelViews {
                    width: 0,
                    ..ModelViews::default()
                },
                false,
                "--width",
            ),
            (
                ModelViews {
                    height: 0,
                    ..ModelViews::default()
                },
                false,
                "--height",
            ),
            (
                ModelViews {
                    up: [0.0; 3],
                    ..ModelViews::default()
                },
                false,
                "up: [0.0, 0.0, 0.0]",
            ),
            (
                ModelViews {
                    up: [f64::NAN, 1.0, 0.0],
                    ..ModelViews::default()
                },
                false,
                "no direction",
            ),
        ];
        for (views, has_data, said) in cases {
            let e = views.validate(has_data).unwrap_err().to_string();
            assert!(e.contains(said), "{said:?} not in {e:?}");
        }
    }

    /// The extent is INRIA's rule on spread cameras and the model's robust radius for
    /// cameras at one point (where INRIA's rule gives 0 and would freeze the means).
    #[test]
    fn the_extent_falls_back_to_the_radius_for_cameras_at_one_point() {
        let mut set = gs_core::GaussianSet::zeros(64, 0);
        for (i, v) in set.means.iter_mut().enumerate() {
            *v = ((i * 37 % 64) as f32 / 32.0) - 1.0;
        }
        set.opacity_logits.fill(2.0);
        let bounds = RobustBounds::of(&set).unwrap();
        for kind in [OrbitKind::Object, OrbitKind::Inside] {
            let cameras = orbit(&bounds, kind, 6, (8, 8), [0.0, -1.0, 0.0]).unwrap();
            let views: Vec<View> = cameras.into_iter().map(View::still).collect();
            let expected = match kind {
                OrbitKind::Object => scene_extent(&views),
                OrbitKind::Inside => bounds.radius,
            };
            let images = vec![
                Image {
                    width: 8,
                    height: 8,
                    data: vec![0.0; 192]
                };
                6
            ];
            let dataset = model_dataset(views, images, [0.0; 3], &bounds);
            assert!(expected > 0.0);
            assert_eq!(dataset.extent, expected, "{kind:?}");
            assert_eq!(dataset.image_paths[5], PathBuf::from("view 005"));
        }
    }

    #[test]
    fn a_view_is_empty_within_half_a_level_of_the_background() {
        let image = |v: f32| Image {
            width: 1,
            height: 1,
            data: vec![0.2, 0.2, v],
        };
        let background = [0.2; 3];
        assert!(all_empty(&[image(0.2 + 0.49 / 255.0)], background));
        assert!(!all_empty(
            &[image(0.2), image(0.2 + 0.51 / 255.0)],
            background
        ));
        let clamped = model_picture(Image {
            width: 1,
            height: 1,
            data: vec![-0.5, 0.5, 1.5],
        });
        assert_eq!(clamped.data, [0.0, 0.5, 1.0]);
    }
}
