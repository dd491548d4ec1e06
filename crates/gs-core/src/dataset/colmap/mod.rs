//! COLMAP scenes: the sparse model in `sparse/0/` (`cameras`, `images`, `points3D`, each `.bin`
//! or `.txt`, binary preferred as 3DGS does) and the images in `images/`.
//!
//! Only undistorted cameras (PINHOLE, SIMPLE_PINHOLE) are accepted; any other model is an error
//! that says to run COLMAP's `image_undistorter` first.

mod binary;
mod text;

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use crate::model::View;
use crate::Camera;
use rayon::prelude::*;

use super::images::{self, Composite, ExpectedSize};
use super::{
    check_options, training_camera, Dataset, DatasetError, ImageCounter, LoadOptions, PointCloud,
};

/// COLMAP's camera models by id: name and number of parameters.
const CAMERA_MODELS: [(&str, usize); 12] = [
    ("SIMPLE_PINHOLE", 3),
    ("PINHOLE", 4),
    ("SIMPLE_RADIAL", 4),
    ("RADIAL", 5),
    ("OPENCV", 8),
    ("OPENCV_FISHEYE", 8),
    ("FULL_OPENCV", 12),
    ("FOV", 5),
    ("SIMPLE_RADIAL_FISHEYE", 4),
    ("RADIAL_FISHEYE", 5),
    ("THIN_PRISM_FISHEYE", 12),
    ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
];

/// Number of parameters of a camera model name, `None` for a name COLMAP does not define.
fn param_count(model: &str) -> Option<usize> {
    CAMERA_MODELS
        .iter()
        .find(|(name, _)| *name == model)
        .map(|&(_, n)| n)
}

/// A camera of `cameras.{bin,txt}`.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    /// Camera id.
    pub id: i64,
    /// Model name, e.g. `PINHOLE`.
    pub model: String,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Model parameters (PINHOLE: fx fy cx cy; SIMPLE_PINHOLE: f cx cy), pixels.
    pub params: Vec<f64>,
}

/// A registered image of `images.{bin,txt}`.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapImage {
    /// Image id.
    pub id: i64,
    /// World-to-camera rotation quaternion `(w, x, y, z)`.
    pub qvec: [f64; 4],
    /// World-to-camera translation.
    pub tvec: [f64; 3],
    /// Id of its camera.
    pub camera_id: i64,
    /// File name relative to the images folder.
    pub name: String,
}

/// A COLMAP sparse model.
#[derive(Clone, Debug, PartialEq)]
pub struct SparseModel {
    /// Cameras, in file order.
    pub cameras: Vec<ColmapCamera>,
    /// Registered images, in file order.
    pub images: Vec<ColmapImage>,
    /// The sparse points.
    pub points: PointCloud,
    /// The cameras file read (for messages).
    pub cameras_path: PathBuf,
}

/// `dir/<stem>.bin` if it exists, else `dir/<stem>.txt`, with whether it is binary.
fn model_file(dir: &Path, stem: &str) -> Result<(PathBuf, bool), DatasetError> {
    let bin = dir.join(format!("{stem}.bin"));
    let txt = dir.join(format!("{stem}.txt"));
    if bin.is_file() {
        Ok((bin, true))
    } else if txt.is_file() {
        Ok((txt, false))
    } else {
        Err(DatasetError::Missing {
            path: bin,
            what: format!("the COLMAP {stem} file (neither {stem}.bin nor {stem}.txt exists)"),
        })
    }
}

fn read_file(path: &Path) -> Result<Vec<u8>, DatasetError> {
    std::fs::read(path).map_err(|source| DatasetError::Io {
        path: path.to_path_buf(),
        source,
    })
}

fn read_text(path: &Path) -> Result<String, DatasetError> {
    String::from_utf8(read_file(path)?).map_err(|_| DatasetError::Format {
        path: path.to_path_buf(),
        message: "not UTF-8 text".into(),
    })
}

/// Reads the sparse model in `dir` (e.g. `scene/sparse/0`), each file binary or text.
pub fn read_sparse_model(dir: &Path) -> Result<SparseModel, DatasetError> {
    let (cameras_path, bin) = model_file(dir, "cameras")?;
    let cameras = if bin {
        binary::cameras(&cameras_path, &read_file(&cameras_path)?)?
    } else {
        text::cameras(&cameras_path, &read_text(&cameras_path)?)?
    };
    let (path, bin) = model_file(dir, "images")?;
    let images = if bin {
        binary::images(&path, &read_file(&path)?)?
    } else {
        text::images(&path, &read_text(&path)?)?
    };
    let (path, bin) = model_file(dir, "points3D")?;
    let points = if bin {
        binary::points(&path, &read_file(&path)?)?
    } else {
        text::points(&path, &read_text(&path)?)?
    };
    Ok(SparseModel {
        cameras,
        images,
        points,
        cameras_path,
    })
}

/// Pinhole intrinsics `[fx, fy, cx, cy]` of an undistorted camera.
fn pinhole(camera: &ColmapCamera, path: &Path) -> Result<[f64; 4], DatasetError> {
    match (camera.model.as_str(), camera.params.as_slice()) {
        ("PINHOLE", &[fx, fy, cx, cy]) => Ok([fx, fy, cx, cy]),
        ("SIMPLE_PINHOLE", &[f, cx, cy]) => Ok([f, f, cx, cy]),
        _ => Err(DatasetError::UnsupportedCameraModel {
            path: path.to_path_buf(),
            camera_id: camera.id,
            model: camera.model.clone(),
        }),
    }
}

/// The image folder and whether it is pre-downscaled: `images_<f>/` when downscaling by `f` and
/// it exists, else `images/`.
fn image_folder(root: &Path, downscale: u32) -> Result<(PathBuf, bool), DatasetError> {
    let scaled = root.join(format!("images_{downscale}"));
    if downscale > 1 && scaled.is_dir() {
        return Ok((scaled, true));
    }
    let full = root.join("images");
    if full.is_dir() {
        Ok((full, false))
    } else {
        Err(DatasetError::Missing {
            path: full,
            what: "the folder of the COLMAP scene's images".into(),
        })
    }
}

/// The folder of the sparse model of the COLMAP scene in `root`: `sparse/0/` (COLMAP's
/// mapper), else `sparse/` itself when it holds the model (`image_undistorter`'s output).
fn sparse_model_dir(root: &Path) -> Result<PathBuf, DatasetError> {
    let sparse = root.join("sparse");
    let first = sparse.join("0");
    let holds_model = |dir: &Path| {
        ["cameras.bin", "cameras.txt"]
            .iter()
            .any(|name| dir.join(name).is_file())
    };
    if first.is_dir() {
        Ok(first)
    } else if holds_model(&sparse) {
        Ok(sparse)
    } else {
        Err(DatasetError::Missing {
            path: first,
            what: "the COLMAP sparse model folder (sparse/0/, or sparse/ holding cameras.bin \
                   or cameras.txt)"
                .into(),
        })
    }
}

/// Loads the COLMAP scene in `root`: views sorted by image name, images loaded in parallel,
/// the sparse points. With `downscale = f > 1`, images come from `images_<f>/` when it exists
/// (each within one pixel of the downscaled camera size, the intrinsics scaled to the file's
/// exact size), else from `images/` (exactly the camera size), resized.
pub fn load(root: &Path, options: &LoadOptions) -> Result<Dataset, DatasetError> {
    check_options(options)?;
    let sparse = sparse_model_dir(root)?;
    let model = read_sparse_model(&sparse)?;
    let cameras: HashMap<i64, &ColmapCamera> = model.cameras.iter().map(|c| (c.id, c)).collect();
    let (folder, prescaled) = image_folder(root, options.downscale)?;
    let mut order: Vec<&ColmapImage> = model.images.iter().collect();
    order.sort_by(|a, b| a.name.cmp(&b.name));
    let background = options.background.rgb();
    let counter = ImageCounter::new(options, order.len());
    let frames = order
        .par_iter()
        .map(|img| {
            let camera_error = |source| DatasetError::Camera {
                context: format!("image {:?} (id {})", img.name, img.id),
                source,
            };
            let colmap_camera =
                cameras
                    .get(&img.camera_id)
                    .ok_or_else(|| DatasetError::Format {
                        path: model.cameras_path.clone(),
                        message: format!(
                            "no camera {} for image {:?} (id {})",
                            img.camera_id, img.name, img.id
                        ),
                    })?;
            let intrinsics = pinhole(colmap_camera, &model.cameras_path)?;
            let (w, h) = (colmap_camera.width, colmap_camera.height);
            let full =
                Camera::from_colmap(img.qvec, img.tvec, intrinsics, w, h).map_err(camera_error)?;
            let scaled = training_camera(&full, options).map_err(camera_error)?;
            let path = folder.join(&img.name);
            let (camera, image, mask) = if prescaled {
                let (image, mask) = images::load(
                    &path,
                    ExpectedSize::Near(scaled.width, scaled.height),
                    None,
                    background,
                    Composite::of(options.ground_truth, false),
                )?;
                let (sx, sy) = (
                    image.width as f64 / w as f64,
                    image.height as f64 / h as f64,
                );
                let [fx, fy, cx, cy] = intrinsics;
                let camera = Camera::new(
                    full.rotation,
                    full.translation,
                    [fx * sx, fy * sy, cx * sx, cy * sy],
                    image.width,
                    image.height,
                )
                .map_err(camera_error)?;
                (camera, image, mask)
            } else {
                let (image, mask) = images::load(
                    &path,
                    ExpectedSize::Exact(w, h),
                    Some((scaled.width, scaled.height)),
                    background,
                    Composite::of(options.ground_truth, false),
                )?;
                (scaled, image, mask)
            };
            counter.one_done();
            Ok((View::still(camera), image, mask, path))
        })
        // Gathered in order first, so the error reported is that of the first failing frame.
        .collect::<Vec<Result<_, DatasetError>>>()
        .into_iter()
        .collect::<Result<Vec<_>, _>>()?;
    Ok(Dataset::from_frames(frames, background, Some(model.points)))
}
