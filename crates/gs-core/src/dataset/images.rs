//! Ground-truth image files: decoding, alpha compositing, background masks, size checks and
//! resizing to a downscaled or shrunk camera (Pillow's bicubic resize of the 8-bit levels).

use std::path::Path;

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
    /// `readCamerasFromTransforms` ([`composite_8bit`]).
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

/// One pixel of 8-bit levels (as PIL reads every file) composited as INRIA
/// 3DGS's `readCamerasFromTransforms` does it: `arr = (c / 255) (a / 255) + bg (1 - a / 255)` in
/// `f64`, then `np.array(arr * 255.0, dtype=np.byte)`, which truncates towards zero, so
/// `floor(arr * 255)`, a whole level in `0..=255`.
pub fn composite_8bit(rgb: [u8; 3], alpha: u8, background: [f32; 3]) -> [u8; 3] {
    let a = f64::from(alpha) / 255.0;
    // `arr` lies in [0, 1]; the cast saturates at the ends.
    let level = |c: usize| {
        let arr = (f64::from(rgb[c]) / 255.0) * a + f64::from(background[c]) * (1.0 - a);
        (arr * 255.0).floor() as u8
    };
    [level(0), level(1), level(2)]
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
        crate::image::PictureError::Image(e) => image_error(path, e),
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

/// 8-bit levels as values in `[0, 1]` (level / 255).
fn as_unit_values(levels: &image::RgbaImage) -> image::Rgba32FImage {
    image::Rgba32FImage::from_fn(levels.width(), levels.height(), |x, y| {
        image::Rgba(levels.get_pixel(x, y).0.map(|v| f32::from(v) / 255.0))
    })
}

/// The picture's 8-bit RGBA levels as PIL reads it: 8-bit files as they are; 16-bit RGB, RGBA
/// and grey-alpha files by the high byte of each value (PIL's `RGB;16B` unpacking); 16-bit grey
/// clipped to 255 (PIL's `I;16` converted to RGBA); other formats through the image crate.
pub(crate) fn pil_levels(decoded: &image::DynamicImage) -> image::RgbaImage {
    use image::DynamicImage as D;
    let high_byte = |v: u16| (v >> 8) as u8;
    match decoded {
        D::ImageRgb16(_) | D::ImageRgba16(_) | D::ImageLumaA16(_) => {
            let wide = decoded.to_rgba16();
            image::RgbaImage::from_fn(wide.width(), wide.height(), |x, y| {
                image::Rgba(wide.get_pixel(x, y).0.map(high_byte))
            })
        }
        D::ImageLuma16(grey) => image::RgbaImage::from_fn(grey.width(), grey.height(), |x, y| {
            let v = grey.get_pixel(x, y).0[0].min(255) as u8;
            image::Rgba([v, v, v, 255])
        }),
        _ => decoded.to_rgba8(),
    }
}

/// The stored colours and alpha of `decoded` as PIL's levels ([`pil_levels`]) / 255.
pub(crate) fn stored_levels(decoded: &image::DynamicImage) -> image::Rgba32FImage {
    as_unit_values(&pil_levels(decoded))
}

/// `decoded`'s levels as PIL reads them ([`pil_levels`]) composited over `background` by
/// [`composite_8bit`], the file's alpha kept for the mask.
fn composited_levels(decoded: &image::DynamicImage, background: [f32; 3]) -> image::RgbaImage {
    let mut levels = pil_levels(decoded);
    for p in levels.pixels_mut() {
        let [r, g, b, a] = p.0;
        let [r, g, b] = composite_8bit([r, g, b], a, background);
        *p = image::Rgba([r, g, b, a]);
    }
    levels
}

/// `decoded` composited over `background` by [`composite_8bit`] from its levels as PIL reads
/// them ([`pil_levels`]), as `f32` levels / 255 with the file's alpha kept for the mask.
pub(crate) fn composited_8bit(
    decoded: &image::DynamicImage,
    background: [f32; 3],
) -> image::Rgba32FImage {
    as_unit_values(&composited_levels(decoded, background))
}
