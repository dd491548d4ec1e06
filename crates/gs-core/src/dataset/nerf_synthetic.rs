//! `transforms` files: NeRF-synthetic (Blender) scenes' `transforms_{train,test,val}.json`, and
//! nerfstudio's and instant-ngp's single `transforms.json`.
//!
//! A file holds the camera (`camera_angle_x`, the horizontal field of view in radians, or pixel
//! intrinsics `fl_x, fl_y, cx, cy`, optionally `w, h` as integers or whole floats, each
//! overridable per frame) and frames of `file_path` (relative to the folder) and
//! `transform_matrix` (camera-to-world, OpenGL axes), in the file's own frame of reference:
//! instant-ngp's `aabb_scale`, `scale` and `offset` place the scene in instant-ngp's unit cube
//! and move no camera relative to the pictures, so they are read and left alone.
//!
//! Lens distortion (`k1, k2, k3, p1, p2`, or `k1..k4` with `camera_model: "OPENCV_FISHEYE"`)
//! is undone at load ([`undistort`](super::undistort)). A single `transforms.json` gives its
//! splits by nerfstudio's `train_filenames`, `val_filenames` and `test_filenames`; without
//! them every frame is a training frame and there is no test or val split.
//!
//! Pictures with alpha are composited over the chosen background and the result cut to whole
//! 8-bit levels, as D-MiSo and INRIA 3DGS before August 2024 read these scenes
//! ([`composite_8bit`](crate::levels::composite_8bit)), or the stored colours are kept
//! ([`GroundTruth`](super::GroundTruth)); alpha gives the background mask. With a downscale `f`,
//! pictures come from `images_<f>/` (same file names) when the folder exists, as nerfstudio reads
//! them.
//!
//! D-NeRF scenes are the same layout with a `time` in `[0, 1]` per frame ([`load_with_times`]).

use std::path::{Path, PathBuf};

use crate::camera::fov_to_focal;
use crate::Camera;
use serde::{Deserialize, Serialize};

use super::images::{self, Composite};
use super::undistort::LensDistortion;
use super::view_picture::{self, prescaled_folder, PictureFile, ViewSpec};
use super::{check_options, training_camera, Dataset, DatasetError, DatasetView, LoadOptions};

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
    /// The transforms file name of the split (NeRF-synthetic's).
    pub fn file_name(self) -> &'static str {
        match self {
            Self::Train => "transforms_train.json",
            Self::Test => "transforms_test.json",
            Self::Val => "transforms_val.json",
        }
    }

    /// nerfstudio's field listing the split's pictures in a single `transforms.json`.
    fn list_field(self) -> &'static str {
        match self {
            Self::Train => "train_filenames",
            Self::Test => "test_filenames",
            Self::Val => "val_filenames",
        }
    }
}

/// The one transforms file of nerfstudio and instant-ngp scenes, read where a split's own file
/// (`transforms_<split>.json`) is absent.
pub const SINGLE_FILE: &str = "transforms.json";

#[derive(Deserialize)]
struct Transforms {
    /// Horizontal field of view, radians (NeRF-synthetic); optional where `fl_x` is given.
    camera_angle_x: Option<f64>,
    /// The intrinsics of every frame, pixels (nerfstudio, instant-ngp); a frame may give its own.
    #[serde(flatten)]
    intrinsics: Intrinsics,
    /// nerfstudio's lens model: `OPENCV` (the default) or `OPENCV_FISHEYE`.
    camera_model: Option<String>,
    frames: Vec<Frame>,
    /// nerfstudio's split lists of `file_path`s.
    train_filenames: Option<Vec<String>>,
    val_filenames: Option<Vec<String>>,
    test_filenames: Option<Vec<String>>,
}

impl Transforms {
    /// The split list of `split`.
    fn split_list(&self, split: Split) -> Option<&Vec<String>> {
        match split {
            Split::Train => self.train_filenames.as_ref(),
            Split::Test => self.test_filenames.as_ref(),
            Split::Val => self.val_filenames.as_ref(),
        }
    }

    /// The lens of a frame's intrinsics under this file's `camera_model`; an error says why it
    /// cannot be undone.
    fn lens(&self, intrinsics: &Intrinsics) -> Result<Option<LensDistortion>, String> {
        let k =
            [intrinsics.k1, intrinsics.k2, intrinsics.k3, intrinsics.k4].map(|v| v.unwrap_or(0.0));
        let p = [intrinsics.p1, intrinsics.p2].map(|v| v.unwrap_or(0.0));
        match self.camera_model.as_deref() {
            None | Some("OPENCV") | Some("PINHOLE") | Some("SIMPLE_PINHOLE") => {
                if k[3] != 0.0 {
                    return Err(format!(
                        "k4 = {} with the {} model: nerfstudio's fourth radial term is not \
                         OpenCV's, and this reader undoes only k1, k2, k3, p1, p2 (or k1..k4 \
                         with camera_model OPENCV_FISHEYE)",
                        k[3],
                        self.camera_model.as_deref().unwrap_or("OPENCV")
                    ));
                }
                let lens = LensDistortion::Perspective {
                    k: [k[0], k[1], k[2], 0.0, 0.0, 0.0],
                    p,
                };
                Ok((!lens.is_none()).then_some(lens))
            }
            Some("OPENCV_FISHEYE") => {
                if p != [0.0; 2] {
                    return Err(format!(
                        "p1, p2 = {p:?} with the OPENCV_FISHEYE model, which has no \
                         tangential terms"
                    ));
                }
                Ok(Some(LensDistortion::Fisheye { k }))
            }
            Some(other) => Err(format!(
                "camera_model {other:?} is not one this reader undoes (OPENCV, \
                 OPENCV_FISHEYE, PINHOLE)"
            )),
        }
    }

    /// The model name reported for an undistorted frame.
    fn model_name(&self) -> &str {
        self.camera_model.as_deref().unwrap_or("OPENCV")
    }
}

/// Pixel intrinsics as nerfstudio and instant-ngp write them, each optional, with the picture
/// size and the lens distortion they may record.
#[derive(Clone, Copy, Default, Deserialize)]
struct Intrinsics {
    fl_x: Option<f64>,
    fl_y: Option<f64>,
    cx: Option<f64>,
    cy: Option<f64>,
    /// Picture width, an integer or a whole float as nerfstudio and instant-ngp write it.
    #[serde(default, deserialize_with = "whole_pixels")]
    w: Option<u32>,
    /// Picture height, as `w`.
    #[serde(default, deserialize_with = "whole_pixels")]
    h: Option<u32>,
    k1: Option<f64>,
    k2: Option<f64>,
    k3: Option<f64>,
    k4: Option<f64>,
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
            w: self.w.or(global.w),
            h: self.h.or(global.h),
            k1: self.k1.or(global.k1),
            k2: self.k2.or(global.k2),
            k3: self.k3.or(global.k3),
            k4: self.k4.or(global.k4),
            p1: self.p1.or(global.p1),
            p2: self.p2.or(global.p2),
        }
    }

    /// `[fx, fy, cx, cy]` of a `width x height` picture: `fl_x` (`fl_y` defaults to it, the
    /// principal point to the centre), else the focal of `fov_x`; an error naming what is
    /// missing.
    fn pixels(&self, fov_x: Option<f64>, width: u32, height: u32) -> Result<[f64; 4], String> {
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

/// The training views of the scene in `root` as `splits` says, train first (as INRIA's
/// `train_cam_infos.extend(test_cam_infos)`), the extent that of all of them; each split as
/// [`load`] reads it.
pub fn load_training(
    root: &Path,
    splits: TrainSplits,
    options: &LoadOptions,
) -> Result<Dataset, DatasetError> {
    let mut loaded = training_splits(root, splits)?
        .into_iter()
        .map(|split| load(root, split, options));
    let mut dataset = loaded.next().expect("at least one split")?;
    for more in loaded {
        dataset.append(more?);
    }
    Ok(dataset)
}

/// The splits [`load_training`] reads as `splits` says: the train split, then the test split
/// when `splits` takes it and it has frames; an empty train split is no views when the test
/// split trains too and has some (as INRIA's loader takes it). Never empty: with no frames to
/// train on, the train split, whose reading says why.
fn training_splits(root: &Path, splits: TrainSplits) -> Result<Vec<Split>, DatasetError> {
    let test = splits == TrainSplits::TrainAndTest && has_split(root, Split::Test)?;
    Ok(match (has_split(root, Split::Train)?, test) {
        (true, true) => vec![Split::Train, Split::Test],
        (false, true) => vec![Split::Test],
        (_, false) => vec![Split::Train],
    })
}

/// The views [`load_training`] would train on, as [`views`] reads them (no picture decoded):
/// the train split's, then the test split's when `splits` takes it and the scene has one.
pub fn training_views(
    root: &Path,
    splits: TrainSplits,
    options: &LoadOptions,
) -> Result<Vec<DatasetView>, DatasetError> {
    let mut found = Vec::new();
    for split in training_splits(root, splits)? {
        found.extend(views(root, split, options)?);
    }
    Ok(found)
}

/// Whether the scene in `root` has frames of `split`: its `transforms_<split>.json`, or a
/// `transforms.json` whose frames make the split (see the module's documentation), with at
/// least one frame (`"frames": []` is no views of the split, as INRIA's loader reads it).
pub fn has_split(root: &Path, split: Split) -> Result<bool, DatasetError> {
    let own = root.join(split.file_name());
    if own.is_file() {
        return Ok(!parse_file(&own)?.1.frames.is_empty());
    }
    if !root.join(SINGLE_FILE).is_file() {
        return Ok(false);
    }
    let (path, transforms) = parse_file(&root.join(SINGLE_FILE))?;
    Ok(split_frames(&path, transforms, split)?.is_some_and(|t| !t.frames.is_empty()))
}

/// The split a render of the scene in `root` takes when none is asked for: the test split
/// where the scene has one (the views `eval` scores), else the training split.
pub fn default_render_split(root: &Path) -> Result<Split, DatasetError> {
    Ok(if has_split(root, Split::Test)? {
        Split::Test
    } else {
        Split::Train
    })
}

/// Loads one split of the scene in `root`. Every picture must have the size its frame gives
/// (`w`/`h` of the frame or of the file), else the size of the first frame's picture. Pictures
/// load in parallel. The extent is that of this split's cameras (3DGS uses the training
/// split's). Frame times, when present, are ignored: the views are at time 0.
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
/// what a run checks against its memory before loading. Undistortion, which only crops, is
/// not counted.
pub fn training_pixels(
    root: &Path,
    splits: TrainSplits,
    options: &LoadOptions,
) -> Result<(Vec<u64>, u64), DatasetError> {
    let read = training_splits(root, splits)?;
    let mut views = Vec::new();
    let mut largest = 0u64;
    for split in read {
        let (json_path, transforms) = read_transforms(root, split)?;
        let identity = [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ];
        for (w, h) in frame_sizes(root, &transforms)? {
            // The trained size depends on the picture's size and the options only.
            let (fw, fh) = (f64::from(w), f64::from(h));
            let trained =
                Camera::from_nerf_intrinsics(identity, [fw, fw, fw / 2.0, fh / 2.0], w, h)
                    .and_then(|c| training_camera(&c, options))
                    .map_err(|source| DatasetError::Camera {
                        context: json_path.display().to_string(),
                        source,
                    })?;
            views.push(u64::from(trained.width) * u64::from(trained.height));
            largest = largest.max(u64::from(w) * u64::from(h));
        }
    }
    Ok((views, largest))
}

/// The stored size of each frame's picture: the frame's `w`/`h`, else the file's, else the
/// size of the first frame's picture (read from its header only when needed).
fn frame_sizes(root: &Path, transforms: &Transforms) -> Result<Vec<(u32, u32)>, DatasetError> {
    let mut first = None;
    transforms
        .frames
        .iter()
        .map(|frame| {
            let given = frame.intrinsics.over(transforms.intrinsics);
            match (given.w, given.h) {
                (Some(w), Some(h)) => Ok((w, h)),
                _ => match first {
                    Some(size) => Ok(size),
                    None => {
                        let frame = &transforms.frames[0];
                        let size = images::dimensions(&image_path(root, &frame.file_path))?;
                        first = Some(size);
                        Ok(size)
                    }
                },
            }
        })
        .collect()
}

/// `path` parsed as a transforms file.
fn parse_file(path: &Path) -> Result<(PathBuf, Transforms), DatasetError> {
    let text = std::fs::read_to_string(path).map_err(|source| DatasetError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let transforms: Transforms =
        serde_json::from_str(&text).map_err(|source| DatasetError::Json {
            path: path.to_path_buf(),
            source,
        })?;
    for (i, frame) in transforms.frames.iter().enumerate() {
        check_inside(&frame.file_path).map_err(|why| DatasetError::Format {
            path: path.to_path_buf(),
            message: format!("frame {i}: file_path {:?} {why}", frame.file_path),
        })?;
    }
    Ok((path.to_path_buf(), transforms))
}

/// Refuses a `file_path` that would not name a file inside the scene folder: empty, absolute,
/// or with a `..` part.
fn check_inside(file_path: &str) -> Result<(), &'static str> {
    use std::path::Component;
    let mut files = 0;
    for part in Path::new(file_path).components() {
        match part {
            Component::Normal(_) => files += 1,
            Component::CurDir => {}
            Component::ParentDir => return Err("leaves the scene folder (a `..` part)"),
            Component::RootDir | Component::Prefix(_) => {
                return Err("is absolute; frames are named relative to the scene folder")
            }
        }
    }
    if files == 0 {
        return Err("names no file");
    }
    Ok(())
}

/// The frames of `split` in the single file `transforms`: those its split list names (each
/// name must be a frame's), every frame for the train split of a file without lists, and
/// `None` where the file has no such split.
fn split_frames(
    path: &Path,
    mut transforms: Transforms,
    split: Split,
) -> Result<Option<Transforms>, DatasetError> {
    let has_lists = [Split::Train, Split::Test, Split::Val]
        .iter()
        .any(|&s| transforms.split_list(s).is_some());
    let Some(names) = transforms.split_list(split) else {
        return Ok((split == Split::Train && !has_lists).then_some(transforms));
    };
    let key = |name: &str| -> PathBuf {
        Path::new(name)
            .components()
            .filter(|c| *c != std::path::Component::CurDir)
            .collect()
    };
    let wanted: std::collections::HashSet<PathBuf> = names.iter().map(|n| key(n)).collect();
    let present: std::collections::HashSet<PathBuf> = transforms
        .frames
        .iter()
        .map(|f| key(&f.file_path))
        .collect();
    if let Some(missing) = names.iter().find(|n| !present.contains(&key(n))) {
        return Err(DatasetError::Format {
            path: path.to_path_buf(),
            message: format!(
                "{} names {missing:?}, which no frame's file_path is",
                split.list_field()
            ),
        });
    }
    transforms
        .frames
        .retain(|frame| wanted.contains(&key(&frame.file_path)));
    Ok(Some(transforms))
}

/// The transforms of `split` in `root`, parsed, and the path of their file: the split's own
/// file, else the split's frames of [`SINGLE_FILE`].
fn read_transforms(root: &Path, split: Split) -> Result<(PathBuf, Transforms), DatasetError> {
    let split_path = root.join(split.file_name());
    let single_path = root.join(SINGLE_FILE);
    if split_path.is_file() || !single_path.is_file() {
        return parse_file(&split_path).map_err(|e| match e {
            DatasetError::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound => {
                DatasetError::Missing {
                    path: split_path.clone(),
                    what: format!("the {split:?} split (nor is there a {SINGLE_FILE})"),
                }
            }
            e => e,
        });
    }
    let (path, transforms) = parse_file(&single_path)?;
    match split_frames(&path, transforms, split)? {
        Some(frames) => Ok((path, frames)),
        None => Err(DatasetError::Missing {
            path: split_path,
            what: format!(
                "the {split:?} split; {SINGLE_FILE} has no {}",
                split.list_field()
            ),
        }),
    }
}

fn load_split(
    root: &Path,
    split: Split,
    options: &LoadOptions,
    with_times: bool,
) -> Result<Dataset, DatasetError> {
    let specs = view_specs(root, split, options, with_times)?;
    let loaded =
        view_picture::load_all(&specs, options, Composite::of(options.ground_truth, true))?;
    Ok(Dataset::from_frames(loaded, options.background.rgb(), None))
}

/// The views of one split of the scene in `root` as [`load`] gives them (at time 0), without
/// decoding any picture: the cameras from the json, a picture's header read only where its
/// size is needed (a json without `w`/`h`, a pre-downscaled or distorted picture). What a
/// render from a dataset's cameras needs; the pictures need not all be there.
pub fn views(
    root: &Path,
    split: Split,
    options: &LoadOptions,
) -> Result<Vec<DatasetView>, DatasetError> {
    view_picture::views(&view_specs(root, split, options, false)?, options)
}

/// Every frame of one split of the scene in `root`, checked, before its picture is read: the
/// picture file, the camera of the stored picture, its lens and its time (0 unless
/// `with_times`, when every frame must have one in `[0, 1]`).
fn view_specs(
    root: &Path,
    split: Split,
    options: &LoadOptions,
    with_times: bool,
) -> Result<Vec<ViewSpec>, DatasetError> {
    check_options(options)?;
    let (json_path, transforms) = read_transforms(root, split)?;
    let format_error = |message: String| DatasetError::Format {
        path: json_path.clone(),
        message,
    };
    if transforms.frames.is_empty() {
        return Err(format_error("no frames".into()));
    }
    let sizes = frame_sizes(root, &transforms)?;
    let prescaled = prescaled_folder(root, options.downscale);
    transforms
        .frames
        .iter()
        .zip(&sizes)
        .enumerate()
        .map(|(i, (frame, &(w, h)))| {
            let frame_error =
                |why: String| format_error(format!("frame {i} ({}){why}", frame.file_path));
            let time = match frame.time {
                _ if !with_times => 0.0,
                None => {
                    return Err(frame_error(
                        " has no \"time\"; a D-NeRF scene gives every frame a time in [0, 1]"
                            .into(),
                    ))
                }
                Some(t) if !(0.0..=1.0).contains(&t) => {
                    return Err(frame_error(format!(
                        " has time {t}; times must lie in [0, 1]"
                    )))
                }
                Some(t) => t,
            };
            let given = frame.intrinsics.over(transforms.intrinsics);
            let intrinsics = given
                .pixels(transforms.camera_angle_x, w, h)
                .map_err(|why| frame_error(format!(": {why}")))?;
            let lens = transforms
                .lens(&given)
                .map_err(|why| frame_error(format!(": {why}")))?;
            let context = format!("{} frame {i}", json_path.display());
            let full = Camera::from_nerf_intrinsics(frame.transform_matrix, intrinsics, w, h)
                .map_err(|source| DatasetError::Camera {
                    context: context.clone(),
                    source,
                })?;
            let full_size = image_path(root, &frame.file_path);
            let picture = match &prescaled {
                Some(folder) => PictureFile {
                    path: folder.join(full_size.file_name().unwrap_or_default()),
                    prescaled: true,
                },
                None => PictureFile {
                    path: full_size,
                    prescaled: false,
                },
            };
            Ok(ViewSpec {
                picture,
                full,
                lens,
                model: transforms.model_name().to_string(),
                time,
                context,
            })
        })
        .collect()
}
