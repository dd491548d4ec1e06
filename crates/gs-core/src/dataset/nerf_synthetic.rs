//! NeRF-synthetic (Blender) scenes: `transforms_{train,test,val}.json` with `camera_angle_x`
//! (horizontal field of view, radians) and frames of `file_path` and `transform_matrix`
//! (camera-to-world, OpenGL axes). Images are RGBA PNGs; alpha is composited over the chosen
//! background and the result cut to whole 8-bit levels, as D-MiSo and INRIA 3DGS before August
//! 2024 read these scenes ([`composite_8bit`](super::composite_8bit)), or the stored colours are
//! kept ([`GroundTruth`](super::GroundTruth)); alpha gives the background mask.
//!
//! D-NeRF scenes are the same layout with a `time` in `[0, 1]` per frame ([`load_with_times`]).

use std::path::{Path, PathBuf};

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
    camera_angle_x: f64,
    /// Image width some exporters add; when present every image must have it.
    w: Option<u32>,
    /// Image height some exporters add; when present every image must have it.
    h: Option<u32>,
    frames: Vec<Frame>,
}

#[derive(Deserialize)]
struct Frame {
    file_path: String,
    transform_matrix: [[f64; 4]; 4],
    /// D-NeRF's normalized time of the frame.
    time: Option<f64>,
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

/// The pixels of every view of `splits` of the scene in `root` as [`load`] would train them
/// with `options` (downscaled or shrunk), and the pixels of the largest picture as stored,
/// from the json files and at most one picture header a split, without decoding any picture:
/// what a run checks against its memory before loading.
pub fn training_pixels(
    root: &Path,
    splits: &[Split],
    options: &LoadOptions,
) -> Result<(Vec<u64>, u64), DatasetError> {
    let mut views = Vec::new();
    let mut largest = 0u64;
    for &split in splits {
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
        let trained = Camera::from_nerf(identity, transforms.camera_angle_x, w, h)
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
    if !(fov > 0.0 && fov < std::f64::consts::PI) {
        return Err(format_error(format!(
            "camera_angle_x is {fov}; a field of view in radians in (0, pi) is expected"
        )));
    }
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
    let background = options.background.rgb();
    let counter = ImageCounter::new(options, transforms.frames.len());
    let loaded: Vec<_> = transforms
        .frames
        .par_iter()
        .enumerate()
        .map(|(i, frame)| {
            let camera = Camera::from_nerf(frame.transform_matrix, fov, size.0, size.1)
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
