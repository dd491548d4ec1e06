//! Datasets of posed ground-truth images: NeRF-synthetic, D-NeRF, nerfstudio and instant-ngp
//! `transforms` files ([`nerf_synthetic`]) and COLMAP ([`colmap`]), loaded into gs-core views
//! and images with the options 3DGS users know; distorted cameras undistorted at load
//! ([`undistort`]); and INRIA's `cameras.json`, cameras without pictures ([`inria_cameras`]).

pub mod colmap;
mod images;
pub mod inria_cameras;
pub mod nerf_synthetic;
pub mod undistort;
mod view_picture;

use std::path::{Path, PathBuf};

use crate::model::View;
use crate::wide_pictures::shrunk_size;
use crate::{Camera, GsError, Image};
use serde::{Deserialize, Serialize};
use undistort::Undistorted;

pub use images::{BackgroundMask, ALPHA_BACKGROUND_BELOW};

/// The two dataset layouts a folder can have.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// `transforms_{train,test,val}.json` (NeRF-synthetic, D-NeRF) or one `transforms.json`
    /// (nerfstudio, instant-ngp), and their pictures.
    NerfSynthetic,
    /// A COLMAP sparse model in `sparse/` (or `dense/sparse/`) and pictures in `images/`.
    Colmap,
}

impl Layout {
    /// NeRF-synthetic when `data` holds any `transforms_*.json` of the three splits; else COLMAP
    /// when it holds `sparse/` or `dense/sparse/` (a COLMAP folder keeps its own cameras even
    /// beside a `transforms.json` that colmap2nerf or ns-process-data wrote from them, re-centred
    /// and re-scaled); else a `transforms.json` (nerfstudio, instant-ngp); else `None`.
    pub fn detect(data: &Path) -> Option<Self> {
        use nerf_synthetic::{Split, SINGLE_FILE};
        if [Split::Train, Split::Test, Split::Val]
            .iter()
            .any(|s| data.join(s.file_name()).is_file())
        {
            Some(Self::NerfSynthetic)
        } else if colmap::scene_folder(data).join("sparse").is_dir() {
            Some(Self::Colmap)
        } else if data.join(SINGLE_FILE).is_file() {
            Some(Self::NerfSynthetic)
        } else {
            None
        }
    }

    /// What [`Layout::detect`] looks for, for messages when it finds neither.
    pub const LOOKED_FOR: &'static str = "neither transforms_train.json or transforms.json \
        (NeRF-synthetic, D-NeRF, nerfstudio, instant-ngp) nor sparse/ or dense/sparse/ (COLMAP) \
        was found";
}

/// The colour that transparent pixels are composited over.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum Background {
    /// `(1, 1, 1)`, 3DGS's `--white_background`.
    White,
    /// `(0, 0, 0)`, 3DGS's default.
    #[default]
    Black,
    /// Any other colour, linear RGB in `[0, 1]` ([`Background::from_rgb`] gives white and black
    /// their own variants).
    Colour([f32; 3]),
}

impl Background {
    /// The background of colour `rgb` (linear RGB in `[0, 1]`): [`Background::White`] for
    /// `(1, 1, 1)`, [`Background::Black`] for `(0, 0, 0)`, else [`Background::Colour`].
    pub fn from_rgb(rgb: [f32; 3]) -> Self {
        if rgb == [1.0; 3] {
            Self::White
        } else if rgb == [0.0; 3] {
            Self::Black
        } else {
            Self::Colour(rgb)
        }
    }

    /// The colour, linear RGB in `[0, 1]`.
    pub fn rgb(self) -> [f32; 3] {
        match self {
            Self::White => [1.0; 3],
            Self::Black => [0.0; 3],
            Self::Colour(rgb) => rgb,
        }
    }
}

/// How a picture with transparency becomes the ground truth of its view.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GroundTruth {
    /// Composited over the background and cut to whole 8-bit levels ([`composite_8bit`](crate::levels::composite_8bit)):
    /// `readCamerasFromTransforms` of D-MiSo, VeGaS, MiraGe and of INRIA 3DGS before its
    /// August 2024 release. COLMAP pictures (8-bit RGB) are composited in `f32` where they have
    /// alpha.
    #[default]
    Composited,
    /// The picture's colour channels as stored, alpha ignored (it still gives the background
    /// mask): INRIA 3DGS at the commit CLIPGaussian's 3D code pins, whose `loadCam` re-opens the
    /// file and keeps its first three channels, so a transparent pixel is whatever colour the
    /// file stores there (black in the NeRF-synthetic scenes), whatever the background.
    FileColour,
}

/// Told of each picture a loader has decoded: `(decoded, total)` of the split or scene being
/// loaded (pictures load in parallel, so it may be called from several threads). What a run
/// shows as the loading's progress.
#[derive(Clone)]
pub struct ImageProgress(std::sync::Arc<dyn Fn(usize, usize) + Send + Sync>);

impl ImageProgress {
    /// The progress that calls `report(decoded, total)`.
    pub fn new(report: impl Fn(usize, usize) + Send + Sync + 'static) -> Self {
        Self(std::sync::Arc::new(report))
    }

    /// Tells that `done` of `total` pictures are decoded.
    pub fn report(&self, done: usize, total: usize) {
        (self.0)(done, total)
    }
}

impl std::fmt::Debug for ImageProgress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("ImageProgress")
    }
}

/// Counts the pictures of one loading of `total` and tells `progress` of each.
pub(crate) struct ImageCounter<'a> {
    progress: Option<&'a ImageProgress>,
    done: std::sync::atomic::AtomicUsize,
    total: usize,
}

impl<'a> ImageCounter<'a> {
    /// A count of `total` pictures for `options`'s progress.
    pub(crate) fn new(options: &'a LoadOptions, total: usize) -> Self {
        Self {
            progress: options.progress.as_ref(),
            done: std::sync::atomic::AtomicUsize::new(0),
            total,
        }
    }

    /// One more picture decoded.
    pub(crate) fn one_done(&self) {
        if let Some(progress) = self.progress {
            let done = self.done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
            progress.report(done, self.total);
        }
    }
}

/// How to load a dataset.
#[derive(Clone, Debug)]
pub struct LoadOptions {
    /// Background that alpha is composited over.
    pub background: Background,
    /// How pictures with alpha become the ground truth.
    pub ground_truth: GroundTruth,
    /// Resolution divisor, 3DGS's `-r`: 1 keeps the images as they are (but see `max_width`);
    /// `f > 1` divides the width and height by `f` (rounded as Python's `round`) and the
    /// intrinsics with them (see [`crate::Camera::downscaled`]). COLMAP scenes use
    /// `images_<f>/` when it exists. Resized pictures go through Pillow's bicubic resize.
    pub downscale: u32,
    /// With `downscale` 1, pictures wider than this many pixels are shrunk to it, the camera
    /// with them, as INRIA 3DGS's (and D-MiSo's) loader does at its default `-r -1`
    /// ([`crate::wide_pictures::shrunk_size`]; default 1600); 0 keeps every size (INRIA's `-r 1`).
    pub max_width: u32,
    /// Told of every picture decoded (none: nothing is told).
    pub progress: Option<ImageProgress>,
}

impl Default for LoadOptions {
    fn default() -> Self {
        Self {
            background: Background::Black,
            ground_truth: GroundTruth::Composited,
            downscale: 1,
            max_width: crate::wide_pictures::AUTHORS_MAX_WIDTH,
            progress: None,
        }
    }
}

/// The sparse points of a COLMAP reconstruction, the usual initial point cloud.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointCloud {
    /// World positions.
    pub positions: Vec<[f64; 3]>,
    /// 8-bit sRGB colours as COLMAP stores them.
    pub colors: Vec<[u8; 3]>,
}

/// A loaded dataset: one view, image, optional background mask and file per frame, in the
/// dataset's order (NeRF-synthetic: the json's frame order; COLMAP: sorted by image name, as
/// 3DGS does).
#[derive(Clone, Debug)]
pub struct Dataset {
    /// Cameras (time 0).
    pub views: Vec<View>,
    /// Ground-truth images, each the size of its camera, alpha composited over `background`.
    pub images: Vec<Image>,
    /// Background masks, present for images with an alpha channel.
    pub masks: Vec<Option<BackgroundMask>>,
    /// The image files.
    pub image_paths: Vec<PathBuf>,
    /// The background colour used.
    pub background: [f32; 3],
    /// Scene extent of these views, see [`scene_extent`].
    pub extent: f64,
    /// COLMAP sparse points; `None` for NeRF-synthetic.
    pub points: Option<PointCloud>,
    /// What undistorting each view's picture did (`None` for a pinhole camera's).
    pub undistorted: Vec<Option<Undistorted>>,
}

/// One view of a dataset and its picture file, read from the dataset's files without decoding
/// the picture: the view [`Dataset::views`] would hold at the same place.
#[derive(Clone, Debug, PartialEq)]
pub struct DatasetView {
    /// The camera (as trained: undistorted, downscaled) and time.
    pub view: View,
    /// The picture file.
    pub picture: PathBuf,
}

/// One loaded frame: its view, ground-truth image, background mask, image file and what
/// undistorting it did.
pub(crate) struct LoadedFrame {
    pub view: View,
    pub image: Image,
    pub mask: Option<BackgroundMask>,
    pub path: PathBuf,
    pub undistorted: Option<Undistorted>,
}

impl Dataset {
    /// A dataset of `frames` in order, with the extent of their cameras.
    pub(crate) fn from_frames(
        frames: Vec<LoadedFrame>,
        background: [f32; 3],
        points: Option<PointCloud>,
    ) -> Self {
        let mut dataset = Dataset {
            views: Vec::with_capacity(frames.len()),
            images: Vec::with_capacity(frames.len()),
            masks: Vec::with_capacity(frames.len()),
            image_paths: Vec::with_capacity(frames.len()),
            background,
            extent: 0.0,
            points,
            undistorted: Vec::with_capacity(frames.len()),
        };
        for frame in frames {
            dataset.views.push(frame.view);
            dataset.images.push(frame.image);
            dataset.masks.push(frame.mask);
            dataset.image_paths.push(frame.path);
            dataset.undistorted.push(frame.undistorted);
        }
        dataset.extent = scene_extent(&dataset.views);
        dataset
    }

    /// Appends the frames of `other` (same background) after these; the extent becomes that of
    /// all the views.
    pub fn append(&mut self, other: Dataset) {
        self.views.extend(other.views);
        self.images.extend(other.images);
        self.masks.extend(other.masks);
        self.image_paths.extend(other.image_paths);
        self.undistorted.extend(other.undistorted);
        self.extent = scene_extent(&self.views);
    }

    /// The frames `held_out` says (one flag per view) split off, in order: `(kept, held)`, each
    /// with the extent of its own views and this dataset's background and points.
    ///
    /// # Panics
    /// If `held_out` does not have one flag per view.
    pub fn partition(self, held_out: &[bool]) -> (Dataset, Dataset) {
        assert_eq!(held_out.len(), self.views.len(), "one flag per view");
        let empty = || Dataset {
            views: Vec::new(),
            images: Vec::new(),
            masks: Vec::new(),
            image_paths: Vec::new(),
            background: self.background,
            extent: 0.0,
            points: self.points.clone(),
            undistorted: Vec::new(),
        };
        let (mut kept, mut held) = (empty(), empty());
        let frames = self
            .views
            .into_iter()
            .zip(self.images)
            .zip(self.masks)
            .zip(self.image_paths)
            .zip(self.undistorted);
        for (((((view, image), mask), path), undistorted), &out) in frames.zip(held_out) {
            let to = if out { &mut held } else { &mut kept };
            to.views.push(view);
            to.images.push(image);
            to.masks.push(mask);
            to.image_paths.push(path);
            to.undistorted.push(undistorted);
        }
        kept.extent = scene_extent(&kept.views);
        held.extent = scene_extent(&held.views);
        (kept, held)
    }

    /// One line a run shows per distinct undistortion of its pictures (camera model, stored
    /// size, crop, new intrinsics) with how many views it applies to; empty when no picture was
    /// undistorted.
    pub fn undistortion_summary(&self) -> Vec<String> {
        let mut lines: Vec<(String, usize)> = Vec::new();
        for line in self
            .undistorted
            .iter()
            .flatten()
            .map(Undistorted::to_string)
        {
            match lines.iter_mut().find(|(l, _)| *l == line) {
                Some((_, n)) => *n += 1,
                None => lines.push((line, 1)),
            }
        }
        lines
            .into_iter()
            .map(|(line, n)| format!("{n} view(s): {line}"))
            .collect()
    }
}

/// The scene extent as 3DGS computes it (`getNerfppNorm`'s radius): the largest distance of a
/// camera centre to the mean of the centres, times 1.1. World units; 0 for a single view and
/// for no view.
pub fn scene_extent(views: &[View]) -> f64 {
    if views.is_empty() {
        return 0.0;
    }
    let centres: Vec<[f64; 3]> = views.iter().map(|v| v.camera.centre()).collect();
    let mut mean = [0.0; 3];
    for c in &centres {
        for k in 0..3 {
            mean[k] += c[k] / centres.len() as f64;
        }
    }
    let max_distance = centres
        .iter()
        .map(|c| (0..3).map(|k| (c[k] - mean[k]).powi(2)).sum::<f64>().sqrt())
        .fold(0.0, f64::max);
    1.1 * max_distance
}

/// Why a dataset could not be loaded. Each names the file and what in it was wrong.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// A file or folder the dataset needs is absent.
    #[error("{}: not found ({what})", path.display())]
    Missing {
        /// The path looked for.
        path: PathBuf,
        /// What it should hold.
        what: String,
    },
    /// A file that could not be read.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A json file that does not parse or lacks a field.
    #[error("{}: {source}", path.display())]
    Json {
        /// The file.
        path: PathBuf,
        /// The parser's error (names the field, line and column).
        source: serde_json::Error,
    },
    /// A value or record that is not what the format allows.
    #[error("{}: {message}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong and where (line, record, field, value).
        message: String,
    },
    /// A COLMAP camera of a model this reader cannot undistort.
    #[error(
        "{}: camera {camera_id} uses the {model} model, which this reader cannot undistort \
         (it reads SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV and \
         OPENCV_FISHEYE): undistort the images first (colmap image_undistorter)",
        path.display()
    )]
    UnsupportedCameraModel {
        /// The cameras file.
        path: PathBuf,
        /// The camera id.
        camera_id: i64,
        /// The COLMAP model name.
        model: String,
    },
    /// An image whose size is not the one its camera has.
    #[error(
        "{}: the image is {}x{} but {says} says {}x{}",
        path.display(), found.0, found.1, expected.0, expected.1
    )]
    ImageSize {
        /// The image file.
        path: PathBuf,
        /// Width and height the camera expects, pixels.
        expected: (u32, u32),
        /// Width and height of the file, pixels.
        found: (u32, u32),
        /// What gives the expected size: the view's frame or image and its file (`its camera`
        /// where no file is known).
        says: String,
    },
    /// An image file that could not be decoded.
    #[error("{}: {source}", path.display())]
    Image {
        /// The file.
        path: PathBuf,
        /// The decoder's error.
        source: image::ImageError,
    },
    /// A camera that gs-core refuses (impossible intrinsics or pose).
    #[error("{context}: {source}")]
    Camera {
        /// The file and frame or image it comes from.
        context: String,
        /// gs-core's error.
        source: GsError,
    },
    /// Options that cannot be used.
    #[error("invalid load options: {0}")]
    Options(String),
}

/// The camera the pictures of `full` are trained at: downscaled by `options.downscale`, or, at
/// downscale 1, shrunk to `options.max_width` when wider (INRIA 3DGS's `loadCam`).
pub(crate) fn training_camera(full: &Camera, options: &LoadOptions) -> Result<Camera, GsError> {
    match options.downscale {
        1 => {
            let (w, h) = shrunk_size(full.width, full.height, options.max_width);
            if (w, h) == (full.width, full.height) {
                Ok(full.clone())
            } else {
                full.resized(w, h)
            }
        }
        f => full.downscaled(f64::from(f)),
    }
}

fn check_options(options: &LoadOptions) -> Result<(), DatasetError> {
    if options.downscale == 0 {
        return Err(DatasetError::Options(
            "downscale must be at least 1 (1 keeps the resolution)".into(),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::Image;
    use crate::Camera;

    /// Four views along x, each marked by its picture's name and colour.
    fn four() -> Dataset {
        let views: Vec<View> = (0..4)
            .map(|i| {
                let eye = [i as f64, 0.0, -4.0];
                let camera = Camera::look_at(eye, [0.0; 3], [0.0, -1.0, 0.0], 0.9, 8, 6).unwrap();
                View::still(camera)
            })
            .collect();
        let extent = scene_extent(&views);
        Dataset {
            images: (0..4).map(|i| Image::filled(8, 6, [i as f32; 3])).collect(),
            masks: vec![None; 4],
            image_paths: (0..4).map(|i| PathBuf::from(format!("p{i}.png"))).collect(),
            background: [0.5; 3],
            extent,
            points: None,
            undistorted: vec![None; 4],
            views,
        }
    }

    #[test]
    fn a_partition_keeps_each_frame_whole_in_order_with_its_own_extent() {
        let all = four();
        let (kept, held) = all.clone().partition(&[true, false, false, true]);
        let names = |d: &Dataset| -> Vec<String> {
            d.image_paths
                .iter()
                .map(|p| p.display().to_string())
                .collect()
        };
        assert_eq!(names(&kept), ["p1.png", "p2.png"]);
        assert_eq!(names(&held), ["p0.png", "p3.png"]);
        assert_eq!(kept.views, [all.views[1].clone(), all.views[2].clone()]);
        assert_eq!(held.images[1].data[0], 3.0);
        assert_eq!((kept.masks.len(), held.undistorted.len()), (2, 2));
        assert_eq!(kept.extent, scene_extent(&kept.views));
        assert!(
            held.extent > kept.extent,
            "the held views stand further apart"
        );
        assert_eq!(held.background, [0.5; 3]);
        let (everything, none) = all.partition(&[false; 4]);
        assert_eq!((everything.views.len(), none.views.len()), (4, 0));
        assert_eq!(none.extent, 0.0);
    }
}
