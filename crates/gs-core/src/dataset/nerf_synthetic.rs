//! NeRF-synthetic (Blender) scenes: `transforms_{train,test,val}.json` with `camera_angle_x`
//! (horizontal field of view, radians) and frames of `file_path` and `transform_matrix`
//! (camera-to-world, OpenGL axes). Images are RGBA PNGs; alpha is composited over the chosen
//! background and the result cut to whole 8-bit levels, as D-MiSo and INRIA 3DGS before August
//! 2024 read these scenes ([`composite_8bit`](super::composite_8bit)), or the stored colours are
//! kept ([`GroundTruth`](super::GroundTruth)); alpha gives the background mask.
//!
//! D-NeRF scenes are the same layout with a `time` in `[0, 1]` per frame ([`load_with_times`]).

use std::path::{Path, PathBuf};

use crate::camera::fov_to_focal;
use crate::model::View;
use crate::Camera;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::images::{self, Composite, ExpectedSize};
use super::{check_options, training_camera, Dataset, DatasetError, ImageCounter, LoadOptions};

/// Which transforms file to load.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Split {
    /// `transforms_train.json`.
    Train,
    /// `transforms_test.json`.
    Test,
    /// `transforms_val.json`.
    Val,
}

impl Split {
    /// The transforms file name.
    pub fn file_name(self) -> &'static str {
        match self {
            Self::Train => "transforms_train.json",
            Self::Test => "transforms_test.json",
            Self::Val => "transforms_val.json",
        }
    }
}

#[derive(Deserialize)]
struct Transforms {
    /// Horizontal field of view, radians (NeRF-synthetic); optional where `fl_x` is given.
    camera_angle_x: Option<f64>,
    /// Image width some exporters add; when present every image must have it. An integer, or
    /// a whole float as nerfstudio and instant-ngp write it (`1080.0`).
    #[serde(default, deserialize_with = "whole_pixels")]
    w: Option<u32>,
    /// Image height, as `w`.
    #[serde(default, deserialize_with = "whole_pixels")]
    h: Option<u32>,
    /// The intrinsics of every frame, pixels (nerfstudio, instant-ngp); a frame may give its own.
    #[serde(flatten)]
    intrinsics: Intrinsics,
    frames: Vec<Frame>,
}

/// Pixel intrinsics as nerfstudio and instant-ngp write them, each optional; and the lens
/// distortion they may record, which this reader does not undo (a distorted camera is refused).
#[derive(Clone, Copy, Default, Deserialize)]
struct Intrinsics {
    fl_x: Option<f64>,
    fl_y: Option<f64>,
    cx: Option<f64>,
    cy: Option<f64>,
    k1: Option<f64>,
    k2: Option<f64>,
    k3: Option<f64>,
    p1: Option<f64>,
    p2: Option<f64>,
}

impl Intrinsics {
    /// These, each field not given taken from `global`.
    fn over(self, global: Intrinsics) -> Intrinsics {
        Intrinsics {
            fl_x: self.fl_x.or(global.fl_x),
            fl_y: self.fl_y.or(global.fl_y),
            cx: self.cx.or(global.cx),
            cy: self.cy.or(global.cy),
            k1: self.k1.or(global.k1),
            k2: self.k2.or(global.k2),
            k3: self.k3.or(global.k3),
            p1: self.p1.or(global.p1),
            p2: self.p2.or(global.p2),
        }
    }

    /// `[fx, fy, cx, cy]` of a `width x height` picture: `fl_x` (`fl_y` defaults to it, the
    /// principal point to the centre), else the focal of `fov_x`; an error naming what is
    /// missing or why the camera is refused (lens distortion, which is not undone here).
    fn pixels(&self, fov_x: Option<f64>, width: u32, height: u32) -> Result<[f64; 4], String> {
        let distortion = [("k1", self.k1), ("k2", self.k2), ("k3", self.k3)]
            .into_iter()
            .chain([("p1", self.p1), ("p2", self.p2)])
            .find(|(_, v)| v.is_some_and(|v| v != 0.0));
        if let Some((name, Some(v))) = distortion {
            return Err(format!(
                "the camera has lens distortion ({name} = {v}), which this reader does not \
                 undo; undistort the pictures first (e.g. nerfstudio's ns-process-data or \
                 COLMAP's image_undistorter)"
            ));
        }
        let fx = match (self.fl_x, fov_x) {
            (Some(fx), _) => fx,
            (None, Some(fov)) if fov > 0.0 && fov < std::f64::consts::PI => {
                fov_to_focal(fov, width)
            }
            (None, Some(fov)) => {
                return Err(format!(
                    "camera_angle_x is {fov}; a field of view in radians in (0, pi) is expected"
                ))
            }
            (None, None) => {
                return Err("neither fl_x nor camera_angle_x gives the focal length".into())
            }
        };
        Ok([
            fx,
            self.fl_y.unwrap_or(fx),
            self.cx.unwrap_or(0.5 * f64::from(width)),
            self.cy.unwrap_or(0.5 * f64::from(height)),
        ])
    }
}

/// A picture size written as an integer or as a whole float (`1080.0`).
fn whole_pixels<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Option<u32>, D::Error> {
    use serde::de::Error;
    match Option::<f64>::deserialize(d)? {
        None => Ok(None),
        Some(v) if v.fract() == 0.0 && v >= 1.0 && v <= f64::from(u32::MAX) => Ok(Some(v as u32)),
        Some(v) => Err(D::Error::custom(format!(
            "{v} is not a picture size (a whole number of pixels)"
        ))),
    }
}

#[derive(Deserialize)]
struct Frame {
    file_path: String,
    transform_matrix: [[f64; 4]; 4],
    /// D-NeRF's normalized time of the frame.
    time: Option<f64>,
    /// The frame's own intrinsics, over the file's.
    #[serde(flatten)]
    intrinsics: Intrinsics,
}

/// The image file of a frame: `file_path` relative to the scene folder, with ".png" appended
/// unless it already ends in .png, .jpg or .jpeg (INRIA appends ".png").
fn image_path(root: &Path, file_path: &str) -> PathBuf {
    let has_image_extension = Path::new(file_path)
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| ["png", "jpg", "jpeg"].contains(&e.to_ascii_lowercase().as_str()));
    if has_image_extension {
        root.join(file_path)
    } else {
        root.join(format!("{file_path}.png"))
    }
}

/// Which splits a run trains on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrainSplits {
    /// `transforms_train.json` and then, when the scene has it, `transforms_test.json`: INRIA
    /// 3DGS's and D-MiSo's loaders without `--eval`, which CLIPGaussian's commands never pass,
    /// so the test views train too and enter the scene extent.
    #[default]
    TrainAndTest,
    /// `transforms_train.json` only (the loaders with `--eval`): the test views stay unseen.
    Train,
}

/// The training views of the NeRF-synthetic scene in `root` as `splits` says, train first (as
/// INRIA's `train_cam_infos.extend(test_cam_infos)`), the extent that of all of them; each
/// split as [`load`] reads it.
pub fn load_training(
    root: &Path,
    splits: TrainSplits,
    options: &LoadOptions,
) -> Result<Dataset, DatasetError> {
    let mut dataset = load(root, Split::Train, options)?;
    if splits == TrainSplits::TrainAndTest && root.join(Split::Test.file_name()).is_file() {
        dataset.append(load(root, Split::Test, options)?);
    }
    Ok(dataset)
}

/// Loads one split of the NeRF-synthetic scene in `root`. Every image must have the size given by
/// the json's `w`/`h` when present, else the size of the first frame's image. Images load in
/// parallel. The extent is that of this split's cameras (3DGS uses the training split's).
/// Frame times, when present, are ignored: the views are at time 0.
pub fn load(root: &Path, split: Split, options: &LoadOptions) -> Result<Dataset, DatasetError> {
    load_split(root, split, options, false)
}

/// Loads one split of the D-NeRF scene in `root` as [`load`] does, each view at its frame's
/// `time`, which every frame must have, finite and in `[0, 1]` (D-MiSo would take a missing
/// time as 0; here it is an error naming the frame).
pub fn load_with_times(
    root: &Path,
    split: Split,
    options: &LoadOptions,
) -> Result<Dataset, DatasetError> {
    load_split(root, split, options, true)
}

/// The pixels of every view of the scene in `root` as [`load_training`] would train it with
/// `splits` and `options` (the train split, then the test split when `splits` takes it and
/// the scene has one; downscaled or shrunk), and the pixels of the largest picture as stored,
/// from the json files and at most one picture header a split, without decoding any picture:
/// what a run checks against its memory before loading.
pub fn training_pixels(
    root: &Path,
    splits: TrainSplits,
    options: &LoadOptions,
) -> Result<(Vec<u64>, u64), DatasetError> {
    let mut read = vec![Split::Train];
    if splits == TrainSplits::TrainAndTest && root.join(Split::Test.file_name()).is_file() {
        read.push(Split::Test);
    }
    let mut views = Vec::new();
    let mut largest = 0u64;
    for split in read {
        let (json_path, transforms) = read_transforms(root, split)?;
        let (w, h) = match (transforms.w, transforms.h, transforms.frames.first()) {
            (Some(w), Some(h), _) => (w, h),
            (_, _, Some(first)) => images::dimensions(&image_path(root, &first.file_path))?,
            (_, _, None) => continue,
        };
        let identity = [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ];
        // The trained size depends on the picture's size and the options only.
        let (fw, fh) = (f64::from(w), f64::from(h));
        let trained = Camera::from_nerf_intrinsics(identity, [fw, fw, fw / 2.0, fh / 2.0], w, h)
            .and_then(|c| training_camera(&c, options))
            .map_err(|source| DatasetError::Camera {
                context: json_path.display().to_string(),
                source,
            })?;
        let pixels = u64::from(trained.width) * u64::from(trained.height);
        views.extend(std::iter::repeat_n(pixels, transforms.frames.len()));
        largest = largest.max(u64::from(w) * u64::from(h));
    }
    Ok((views, largest))
}

/// The transforms file of `split` in `root`, parsed, and its path.
fn read_transforms(root: &Path, split: Split) -> Result<(PathBuf, Transforms), DatasetError> {
    let json_path = root.join(split.file_name());
    let text = std::fs::read_to_string(&json_path).map_err(|source| {
        if source.kind() == std::io::ErrorKind::NotFound {
            DatasetError::Missing {
                path: json_path.clone(),
                what: format!("the NeRF-synthetic {split:?} split"),
            }
        } else {
            DatasetError::Io {
                path: json_path.clone(),
                source,
            }
        }
    })?;
    let transforms: Transforms =
        serde_json::from_str(&text).map_err(|source| DatasetError::Json {
            path: json_path.clone(),
            source,
        })?;
    Ok((json_path, transforms))
}

fn load_split(
    root: &Path,
    split: Split,
    options: &LoadOptions,
    with_times: bool,
) -> Result<Dataset, DatasetError> {
    check_options(options)?;
    let (json_path, transforms) = read_transforms(root, split)?;
    let format_error = |message: String| DatasetError::Format {
        path: json_path.clone(),
        message,
    };
    let fov = transforms.camera_angle_x;
    let Some(first) = transforms.frames.first() else {
        return Err(format_error("no frames".into()));
    };
    let mut times = vec![0.0; transforms.frames.len()];
    if with_times {
        for (i, (frame, time)) in transforms.frames.iter().zip(&mut times).enumerate() {
            *time = match frame.time {
                None => {
                    return Err(format_error(format!(
                        "frame {i} ({}) has no \"time\"; a D-NeRF scene gives every frame a \
                         time in [0, 1]",
                        frame.file_path
                    )))
                }
                Some(t) if !(0.0..=1.0).contains(&t) => {
                    return Err(format_error(format!(
                        "frame {i} ({}) has time {t}; times must lie in [0, 1]",
                        frame.file_path
                    )))
                }
                Some(t) => t,
            };
        }
    }
    let size = match (transforms.w, transforms.h) {
        (Some(w), Some(h)) => (w, h),
        _ => images::dimensions(&image_path(root, &first.file_path))?,
    };
    let intrinsics = transforms
        .frames
        .iter()
        .enumerate()
        .map(|(i, frame)| {
            frame
                .intrinsics
                .over(transforms.intrinsics)
                .pixels(fov, size.0, size.1)
                .map_err(|why| format_error(format!("frame {i} ({}): {why}", frame.file_path)))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let background = options.background.rgb();
    let counter = ImageCounter::new(options, transforms.frames.len());
    let loaded: Vec<_> = transforms
        .frames
        .par_iter()
        .enumerate()
        .map(|(i, frame)| {
            let camera =
                Camera::from_nerf_intrinsics(frame.transform_matrix, intrinsics[i], size.0, size.1)
                    .and_then(|c| training_camera(&c, options))
                    .map_err(|source| DatasetError::Camera {
                        context: format!("{} frame {i}", json_path.display()),
                        source,
                    })?;
            let path = image_path(root, &frame.file_path);
            let (image, mask) = images::load(
                &path,
                ExpectedSize::Exact(size.0, size.1),
                Some((camera.width, camera.height)),
                background,
                Composite::of(options.ground_truth, true),
            )?;
            counter.one_done();
            Ok((
                View {
                    camera,
                    time: times[i],
                },
                image,
                mask,
                path,
            ))
        })
        // Gathered in order first, so the error reported is that of the first failing frame.
        .collect::<Vec<Result<_, DatasetError>>>()
        .into_iter()
        .collect::<Result<Vec<_>, _>>()?;
    Ok(Dataset::from_frames(loaded, background, None))
}
