//! Ground-truth image files: decoding, alpha compositing, background masks, size checks and
//! resizing to a downscaled or shrunk camera (Pillow's bicubic resize of the 8-bit levels).

use std::path::Path;

use crate::levels::{as_unit_values, composited_levels, pil_levels};
use crate::pil_resize::{pil_bicubic_resize, pil_rgba_resize};
use crate::Image;
use image::imageops::FilterType;

use super::undistort::Undistortion;
use super::DatasetError;

/// A pixel is background when its alpha is below this value: 0.5/255, so an 8-bit alpha of 0
/// (and only that) marks background, as the pixels that equal the background colour exactly.
pub const ALPHA_BACKGROUND_BELOW: f32 = 0.5 / 255.0;

/// Background pixels of a ground-truth image: `data[y * width + x]` is 1 where the pixel is
/// background and 0 elsewhere (the layout and values of style-loss's background masks).
#[derive(Clone, Debug, PartialEq)]
pub struct BackgroundMask {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// 1 for background, 0 for foreground, `[H, W]`.
    pub data: Vec<f32>,
}

impl BackgroundMask {
    /// Number of background pixels.
    pub fn background_count(&self) -> usize {
        self.data.iter().filter(|&&v| v == 1.0).count()
    }
}

/// Width and height of an image file, read from its header only.
pub(crate) fn dimensions(path: &Path) -> Result<(u32, u32), DatasetError> {
    image::image_dimensions(path).map_err(|e| image_error(path, e))
}

fn image_error(path: &Path, e: image::ImageError) -> DatasetError {
    match e {
        image::ImageError::IoError(source) if source.kind() == std::io::ErrorKind::NotFound => {
            DatasetError::Missing {
                path: path.to_path_buf(),
                what: "an image of the dataset".into(),
            }
        }
        source => DatasetError::Image {
            path: path.to_path_buf(),
            source,
        },
    }
}

/// How alpha is composited over the background.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Composite {
    /// In `f32`, kept as it is (COLMAP pictures, 8-bit RGB already).
    Float,
    /// In `f64` and then cut to whole 8-bit levels, as INRIA 3DGS's and D-MiSo's
    /// `readCamerasFromTransforms` ([`crate::levels::composite_8bit`]).
    EightBit,
    /// Not at all: the colour channels as stored ([`super::GroundTruth::FileColour`]).
    Stored,
}

impl Composite {
    /// How `ground_truth` composites a picture of a NeRF-synthetic scene (`eight_bit`) or of a
    /// COLMAP one.
    pub(crate) fn of(ground_truth: super::GroundTruth, eight_bit: bool) -> Self {
        match (ground_truth, eight_bit) {
            (super::GroundTruth::FileColour, _) => Self::Stored,
            (super::GroundTruth::Composited, true) => Self::EightBit,
            (super::GroundTruth::Composited, false) => Self::Float,
        }
    }
}

/// Loads `path`, checks that its size is `expected`, composites alpha over `background` as
/// `composite` says, and resizes to `target` when it is given and differs from the file's size:
/// 8-bit levels by Pillow's bicubic `Image.resize`, as INRIA 3DGS's `PILtoTorch` resizes
/// ([`Composite::Stored`]: the RGBA picture, premultiplied as Pillow resizes RGBA;
/// [`Composite::EightBit`]: the composited RGB picture, its alpha resized beside it for the
/// mask); [`Composite::Float`] values with a Catmull-Rom filter. With `undistortion` the
/// picture is first resampled to its pinhole camera; its values are then no longer 8-bit
/// levels, so it is composited in `f32` (unless [`Composite::Stored`]) and resized with the
/// Catmull-Rom filter. The mask is present when the file has alpha.
pub(crate) fn load(
    path: &Path,
    expected: (u32, u32),
    target: Option<(u32, u32)>,
    background: [f32; 3],
    composite: Composite,
    undistortion: Option<&Undistortion>,
) -> Result<(Image, Option<BackgroundMask>), DatasetError> {
    let decoded = crate::image::decode_picture(path).map_err(|e| match e {
        crate::image::PictureDecodeError::Image(e) => image_error(path, e),
        too_large => DatasetError::Format {
            path: path.to_path_buf(),
            message: too_large.to_string(),
        },
    })?;
    let found = (decoded.width(), decoded.height());
    if found != expected {
        return Err(DatasetError::ImageSize {
            path: path.to_path_buf(),
            expected,
            found,
            says: "its camera".into(),
        });
    }
    let has_alpha = decoded.color().has_alpha();
    let resampled = undistortion.map(|u| u.apply(&decoded.to_rgba32f()));
    let stored_size = resampled.as_ref().map_or(found, |r| r.dimensions());
    let resize_to = target.filter(|&t| t != stored_size);
    let in_float = |mut rgba: image::Rgba32FImage, composited: bool| {
        if composited {
            for p in rgba.pixels_mut() {
                let a = p[3];
                for c in 0..3 {
                    p[c] = p[c] * a + background[c] * (1.0 - a);
                }
            }
        }
        match resize_to {
            Some((w, h)) => image::imageops::resize(&rgba, w, h, FilterType::CatmullRom),
            None => rgba,
        }
    };
    let rgba = match (composite, resampled) {
        (composite, Some(resampled)) => in_float(resampled, composite != Composite::Stored),
        (Composite::Float, None) => in_float(decoded.to_rgba32f(), true),
        (Composite::EightBit, None) => {
            let levels = composited_levels(&decoded, background);
            as_unit_values(&match resize_to {
                Some(size) => pil_resize_planes(&levels, size),
                None => levels,
            })
        }
        (Composite::Stored, None) => {
            let levels = pil_levels(&decoded);
            as_unit_values(&match resize_to {
                Some(size) => pil_resize_rgba(&levels, size),
                None => levels,
            })
        }
    };
    let (width, height) = rgba.dimensions();
    let mut data = Vec::with_capacity(width as usize * height as usize * 3);
    for p in rgba.pixels() {
        data.extend((0..3).map(|c| p[c].clamp(0.0, 1.0)));
    }
    let mask = has_alpha.then(|| BackgroundMask {
        width,
        height,
        data: rgba
            .pixels()
            .map(|p| f32::from(u8::from(p[3] < ALPHA_BACKGROUND_BELOW)))
            .collect(),
    });
    Ok((
        Image {
            width,
            height,
            data,
        },
        mask,
    ))
}

/// `levels` resized to `(width, height)` as Pillow resizes an RGBA picture (premultiplied).
fn pil_resize_rgba(levels: &image::RgbaImage, (width, height): (u32, u32)) -> image::RgbaImage {
    let input = (levels.height() as usize, levels.width() as usize);
    let resized = pil_rgba_resize(levels.as_raw(), input, (height as usize, width as usize))
        .expect("a non-empty picture to a non-empty size");
    image::RgbaImage::from_raw(width, height, resized).expect("the resized size")
}

/// `levels` resized to `(width, height)` channel by channel, as Pillow resizes an RGB picture
/// (and an `L` one for the alpha).
fn pil_resize_planes(levels: &image::RgbaImage, (width, height): (u32, u32)) -> image::RgbaImage {
    let (w, h) = (levels.width() as usize, levels.height() as usize);
    let (ow, oh) = (width as usize, height as usize);
    let mut planes = vec![0u8; 4 * w * h];
    for (p, px) in levels.pixels().enumerate() {
        for c in 0..4 {
            planes[c * w * h + p] = px[c];
        }
    }
    let resized = pil_bicubic_resize(&planes, 4, (h, w), (oh, ow))
        .expect("a non-empty picture to a non-empty size");
    image::RgbaImage::from_fn(width, height, |x, y| {
        let p = y as usize * ow + x as usize;
        image::Rgba([0, 1, 2, 3].map(|c| resized[c * ow * oh + p]))
    })
}
