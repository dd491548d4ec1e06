//! Rendering a Gaussian set from the cameras of a dataset, or from one camera described in a
//! small JSON file ([`CameraFile`]), to PNG files.
//!
//! Every input is read and checked (and the output names chosen) before the output folder is
//! created; each PNG is written under a temporary name and renamed.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use gs_core::{Camera, GaussianSet};
use gs_wgpu::backend::{Backend, DeviceError};
use serde::Deserialize;

use crate::dataset::nerf_synthetic::{self, Split};
use crate::dataset::{colmap, DatasetError, Layout, LoadOptions};

/// The file name of the picture rendered from a [`CameraFile`].
pub const CAMERA_RENDER_PNG: &str = "render.png";

/// Why views could not be rendered.
#[derive(Debug, thiserror::Error)]
pub enum RenderViewsError {
    /// The dataset.
    #[error("dataset {}: {source}", path.display())]
    Dataset {
        /// The dataset folder.
        path: PathBuf,
        /// What was wrong in it.
        source: Box<DatasetError>,
    },
    /// A dataset folder of neither known layout, or a split asked of a COLMAP scene.
    #[error("dataset {}: {message}", path.display())]
    Layout {
        /// The dataset folder.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A camera file that cannot be read, does not parse, or describes an invalid camera.
    #[error("camera {}: {source}", path.display())]
    Camera {
        /// The camera file.
        path: PathBuf,
        /// What is wrong: the file system's, the JSON reader's or the camera's error.
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// Two views whose pictures would have the same file name.
    #[error(
        "dataset {}: the views of {} and {} would both be written to {name}",
        data.display(), first.display(), second.display()
    )]
    DuplicateName {
        /// The dataset folder.
        data: PathBuf,
        /// The first view's picture.
        first: PathBuf,
        /// The second view's picture, of the same name.
        second: PathBuf,
        /// The render's file name they share.
        name: String,
    },
    /// The output folder could not be created.
    #[error("{}: {source}", path.display())]
    Io {
        /// The folder.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A picture could not be written.
    #[error("{0}")]
    Image(#[from] gs_core::GsError),
    /// The device failed.
    #[error("{0}")]
    Device(#[from] DeviceError),
}

/// A camera to render from, and the file name of its picture.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedCamera {
    /// The picture's file name (no folder), e.g. `r_0.png`.
    pub name: String,
    /// The camera.
    pub camera: Camera,
}

/// One camera as JSON, in OpenCV axes (x right, y down, z forward) with intrinsics in pixels:
///
/// ```json
/// {"width": 800, "height": 800, "fx": 1111.1, "fy": 1111.1, "cx": 400, "cy": 400,
///  "world_to_camera": [[1,0,0,0], [0,1,0,0], [0,0,1,4], [0,0,0,1]]}
/// ```
///
/// `world_to_camera` is a rigid 4x4 transform, row-major: an orthonormal rotation with
/// determinant 1 in the upper left, the translation in the last column, `[0, 0, 0, 1]` below.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CameraFile {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// World-to-camera transform, row-major.
    pub world_to_camera: [[f64; 4]; 4],
}

impl CameraFile {
    /// The camera this describes; an error when the transform is not rigid or the intrinsics
    /// are invalid.
    pub fn camera(&self) -> Result<Camera, Box<dyn std::error::Error + Send + Sync>> {
        let m = &self.world_to_camera;
        gs_core::camera::check_rigid(m)?;
        let r = [
            [m[0][0], m[0][1], m[0][2]],
            [m[1][0], m[1][1], m[1][2]],
            [m[2][0], m[2][1], m[2][2]],
        ];
        let t = [m[0][3], m[1][3], m[2][3]];
        Camera::new(
            r,
            t,
            [self.fx, self.fy, self.cx, self.cy],
            self.width,
            self.height,
        )
        .map_err(Into::into)
    }
}

/// The camera of the JSON file `path` (see [`CameraFile`]), its picture named
/// [`CAMERA_RENDER_PNG`].
pub fn camera_from_file(path: &Path) -> Result<NamedCamera, RenderViewsError> {
    let bad = |source: Box<dyn std::error::Error + Send + Sync>| RenderViewsError::Camera {
        path: path.to_path_buf(),
        source,
    };
    let text = std::fs::read_to_string(path).map_err(|e| bad(e.into()))?;
    let file: CameraFile = serde_json::from_str(&text).map_err(|e| bad(e.into()))?;
    Ok(NamedCamera {
        name: CAMERA_RENDER_PNG.into(),
        camera: file.camera().map_err(bad)?,
    })
}

/// The render's file name of each picture of `paths` (its stem with `.png`); an error names
/// the dataset `data` and both pictures when two share one.
pub(crate) fn render_names(
    data: &Path,
    paths: &[PathBuf],
) -> Result<Vec<String>, RenderViewsError> {
    let mut names = BTreeMap::new();
    paths
        .iter()
        .map(|path| {
            let stem = path.file_stem().unwrap_or_default().to_string_lossy();
            let name = format!("{stem}.png");
            if let Some(first) = names.insert(name.clone(), path.clone()) {
                return Err(RenderViewsError::DuplicateName {
                    data: data.to_path_buf(),
                    first,
                    second: path.clone(),
                    name,
                });
            }
            Ok(name)
        })
        .collect()
}

/// The cameras of the dataset in `data` (NeRF-synthetic when it has `transforms_*.json`, COLMAP
/// when it has `sparse/`), each named after its image with the extension `.png`. `split`
/// chooses the NeRF-synthetic transforms file (when `None`, the test split where the scene has
/// one, else train: `nerf_synthetic::default_render_split`); COLMAP scenes have no split
/// and refuse one.
pub fn dataset_cameras(
    data: &Path,
    split: Option<Split>,
    options: &LoadOptions,
) -> Result<Vec<NamedCamera>, RenderViewsError> {
    let wrap = |source| RenderViewsError::Dataset {
        path: data.to_path_buf(),
        source: Box::new(source),
    };
    let layout = |message: String| RenderViewsError::Layout {
        path: data.to_path_buf(),
        message,
    };
    // Nothing is decoded: the cameras come from the json or the sparse model (a picture's
    // header read only where its size is needed), and need not all have their pictures.
    let views = match Layout::detect(data) {
        Some(Layout::NerfSynthetic) => {
            let split = match split {
                Some(split) => split,
                None => nerf_synthetic::default_render_split(data).map_err(wrap)?,
            };
            nerf_synthetic::views(data, split, options).map_err(wrap)?
        }
        Some(Layout::Colmap) => {
            if split.is_some() {
                return Err(layout(
                    "a COLMAP scene has no splits: leave out --split to render every image".into(),
                ));
            }
            colmap::views(data, options).map_err(wrap)?
        }
        None => return Err(layout(Layout::LOOKED_FOR.into())),
    };
    let pictures: Vec<PathBuf> = views.iter().map(|v| v.picture.clone()).collect();
    let names = render_names(data, &pictures)?;
    Ok(views
        .into_iter()
        .zip(names)
        .map(|(view, name)| NamedCamera {
            name,
            camera: view.view.camera,
        })
        .collect())
}

/// Renders `gaussians` on `backend` from every camera over `background` into `out` (created
/// when absent), one PNG per camera named [`NamedCamera::name`]; returns the files in camera
/// order.
pub fn render_to_folder(
    gaussians: &GaussianSet,
    cameras: &[NamedCamera],
    background: [f32; 3],
    out: &Path,
    backend: &Backend,
) -> Result<Vec<PathBuf>, RenderViewsError> {
    let renderer = backend.renderer(gaussians)?;
    std::fs::create_dir_all(out).map_err(|source| RenderViewsError::Io {
        path: out.to_path_buf(),
        source,
    })?;
    cameras
        .iter()
        .map(|c| {
            let path = out.join(&c.name);
            renderer.render(&c.camera, background)?.save_png(&path)?;
            Ok(path)
        })
        .collect()
}
