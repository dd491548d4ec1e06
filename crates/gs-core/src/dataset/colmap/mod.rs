//! COLMAP scenes: the sparse model in `sparse/0/` or `sparse/` (`cameras`, `images`, `points3D`,
//! each `.bin` or `.txt`, binary preferred as 3DGS does) and the images in `images/`; a folder
//! with neither `sparse/` but a `dense/` holding them (`image_undistorter`'s output) is read
//! from `dense/`.
//!
//! Pinhole cameras (PINHOLE, SIMPLE_PINHOLE) are used as they are. Distorted ones
//! (SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV, OPENCV_FISHEYE) have their pictures undistorted
//! once at load to a pinhole camera and cropped to the valid pixels
//! ([`undistort`](super::undistort)); COLMAP's other models are refused.

mod binary;
mod text;

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use crate::Camera;

use super::images::Composite;
use super::undistort::LensDistortion;
use super::view_picture::{self, prescaled_folder, PictureFile, ViewSpec};
use super::{check_options, Dataset, DatasetError, DatasetView, LoadOptions, PointCloud};

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

impl ColmapCamera {
    /// The intrinsics `[fx, fy, cx, cy]` (pixels) of this camera and its lens distortion
    /// (`None` for the pinhole models), by COLMAP's parameter order of each model; `None` for a
    /// model this reader cannot undistort or parameters of the wrong count.
    pub fn intrinsics(&self) -> Option<([f64; 4], Option<LensDistortion>)> {
        let perspective = |k: [f64; 6], p: [f64; 2]| Some(LensDistortion::Perspective { k, p });
        let zero = [0.0; 2];
        Some(match (self.model.as_str(), self.params.as_slice()) {
            ("PINHOLE", &[fx, fy, cx, cy]) => ([fx, fy, cx, cy], None),
            ("SIMPLE_PINHOLE", &[f, cx, cy]) => ([f, f, cx, cy], None),
            ("SIMPLE_RADIAL", &[f, cx, cy, k]) => (
                [f, f, cx, cy],
                perspective([k, 0.0, 0.0, 0.0, 0.0, 0.0], zero),
            ),
            ("RADIAL", &[f, cx, cy, k1, k2]) => (
                [f, f, cx, cy],
                perspective([k1, k2, 0.0, 0.0, 0.0, 0.0], zero),
            ),
            ("OPENCV", &[fx, fy, cx, cy, k1, k2, p1, p2]) => (
                [fx, fy, cx, cy],
                perspective([k1, k2, 0.0, 0.0, 0.0, 0.0], [p1, p2]),
            ),
            ("FULL_OPENCV", &[fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6]) => (
                [fx, fy, cx, cy],
                perspective([k1, k2, k3, k4, k5, k6], [p1, p2]),
            ),
            ("OPENCV_FISHEYE", &[fx, fy, cx, cy, k1, k2, k3, k4]) => (
                [fx, fy, cx, cy],
                Some(LensDistortion::Fisheye {
                    k: [k1, k2, k3, k4],
                }),
            ),
            _ => return None,
        })
    }
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
    /// The images file read (for messages).
    pub images_path: PathBuf,
}

/// Refuses images a picture cannot be read for, naming the image: an id given twice (two
/// poses for one image), a name that is empty, names a folder (`.`, ending in `/`), or leaves
/// the images folder (a `..` part, an absolute path).
fn check_images(images: &[ColmapImage]) -> Result<(), String> {
    use std::path::Component;
    let mut seen = std::collections::HashSet::with_capacity(images.len());
    for img in images {
        if !seen.insert(img.id) {
            return Err(format!("image {} appears twice", img.id));
        }
        let name = &img.name;
        let mut files = 0;
        for part in Path::new(name).components() {
            match part {
                Component::Normal(_) => files += 1,
                Component::CurDir => {}
                Component::ParentDir => {
                    return Err(format!(
                        "image {}: NAME {name:?} leaves the images folder (a `..` part)",
                        img.id
                    ))
                }
                Component::RootDir | Component::Prefix(_) => {
                    return Err(format!(
                        "image {}: NAME {name:?} is absolute; names are relative to the images \
                         folder",
                        img.id
                    ))
                }
            }
        }
        if files == 0 || name.ends_with(['/', '\\']) {
            return Err(format!(
                "image {}: NAME {name:?} names no picture file",
                img.id
            ));
        }
    }
    Ok(())
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
    let (images_path, bin) = model_file(dir, "images")?;
    let images = if bin {
        binary::images(&images_path, &read_file(&images_path)?)?
    } else {
        text::images(&images_path, &read_text(&images_path)?)?
    };
    check_images(&images).map_err(|message| DatasetError::Format {
        path: images_path.clone(),
        message,
    })?;
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
        images_path,
    })
}

/// The image folder and whether it is pre-downscaled: `images_<f>/` when downscaling by `f` and
/// it exists, else `images/`.
fn image_folder(root: &Path, downscale: u32) -> Result<(PathBuf, bool), DatasetError> {
    if let Some(scaled) = prescaled_folder(root, downscale) {
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

/// The folder a COLMAP scene's `sparse/` and `images/` are in: `root`, or `root/dense/` when
/// `root` has no `sparse/` and `dense/` has (`image_undistorter --output_path dense`).
pub fn scene_folder(root: &Path) -> PathBuf {
    let dense = root.join("dense");
    if !root.join("sparse").is_dir() && dense.join("sparse").is_dir() {
        dense
    } else {
        root.to_path_buf()
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

/// Loads the COLMAP scene in `root` (or in `root/dense/`, see [`scene_folder`]): views sorted
/// by image name, images loaded in parallel, the sparse points. With `downscale = f > 1`,
/// images come from `images_<f>/` when it exists (each within one pixel of the downscaled
/// camera size, the intrinsics scaled to the file's exact size), else from `images/` (exactly
/// the camera size), resized. Distorted cameras' pictures are undistorted first.
pub fn load(root: &Path, options: &LoadOptions) -> Result<Dataset, DatasetError> {
    let (specs, points) = view_specs(root, options)?;
    let frames =
        view_picture::load_all(&specs, options, Composite::of(options.ground_truth, false))?;
    Ok(Dataset::from_frames(
        frames,
        options.background.rgb(),
        Some(points),
    ))
}

/// The views of the COLMAP scene in `root` as [`load`] gives them, without decoding any
/// picture: the cameras from the sparse model, a picture's header read only where its size is
/// needed (a pre-downscaled or distorted picture). What a render from a scene's cameras
/// needs; the pictures need not all be there.
pub fn views(root: &Path, options: &LoadOptions) -> Result<Vec<DatasetView>, DatasetError> {
    view_picture::views(&view_specs(root, options)?.0, options)
}

/// Every registered image of the scene in `root`, sorted by name and checked, before its
/// picture is read; and the sparse points.
fn view_specs(
    root: &Path,
    options: &LoadOptions,
) -> Result<(Vec<ViewSpec>, PointCloud), DatasetError> {
    check_options(options)?;
    let root = &scene_folder(root);
    let sparse = sparse_model_dir(root)?;
    let model = read_sparse_model(&sparse)?;
    let cameras: HashMap<i64, &ColmapCamera> = model.cameras.iter().map(|c| (c.id, c)).collect();
    let (folder, prescaled) = image_folder(root, options.downscale)?;
    let mut order: Vec<&ColmapImage> = model.images.iter().collect();
    order.sort_by(|a, b| a.name.cmp(&b.name));
    let specs =
        order
            .iter()
            .map(|img| {
                let context = format!(
                    "{}: image {:?} (id {}) with camera {} of {}",
                    model.images_path.display(),
                    img.name,
                    img.id,
                    img.camera_id,
                    model.cameras_path.display()
                );
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
                let (intrinsics, lens) = colmap_camera.intrinsics().ok_or_else(|| {
                    DatasetError::UnsupportedCameraModel {
                        path: model.cameras_path.clone(),
                        camera_id: colmap_camera.id,
                        model: colmap_camera.model.clone(),
                    }
                })?;
                let (w, h) = (colmap_camera.width, colmap_camera.height);
                let full = Camera::from_colmap(img.qvec, img.tvec, intrinsics, w, h).map_err(
                    |source| DatasetError::Camera {
                        context: context.clone(),
                        source,
                    },
                )?;
                Ok(ViewSpec {
                    picture: PictureFile {
                        path: folder.join(&img.name),
                        prescaled,
                    },
                    full,
                    lens,
                    model: colmap_camera.model.clone(),
                    time: 0.0,
                    context,
                })
            })
            .collect::<Result<Vec<_>, DatasetError>>()?;
    Ok((specs, model.points))
}
