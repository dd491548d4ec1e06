//! Ground-truth image files: decoding, alpha compositing, background masks, size checks and
//! resizing to a downscaled camera.

use std::path::Path;

use crate::Image;
use image::imageops::FilterType;

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

/// What the file's size must be.
pub(crate) enum ExpectedSize {
    /// Exactly this size.
    Exact(u32, u32),
    /// Within one pixel of this size per axis (pre-downscaled folders: tools round differently).
    Near(u32, u32),
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
        e => DatasetError::Image {
            path: path.to_path_buf(),
            message: e.to_string(),
        },
    }
}

/// Loads `path`, checks its size against `expected`, composites alpha over `background`, and
/// resizes to `target` (bicubic, Catmull-Rom, as PIL's default resize that 3DGS uses) when it is
/// given and differs from the file's size. The mask is present when the file has alpha.
pub(crate) fn load(
    path: &Path,
    expected: ExpectedSize,
    target: Option<(u32, u32)>,
    background: [f32; 3],
) -> Result<(Image, Option<BackgroundMask>), DatasetError> {
    let decoded = image::open(path).map_err(|e| image_error(path, e))?;
    let found = (decoded.width(), decoded.height());
    let fits = match expected {
        ExpectedSize::Exact(w, h) => found == (w, h),
        ExpectedSize::Near(w, h) => found.0.abs_diff(w) <= 1 && found.1.abs_diff(h) <= 1,
    };
    if !fits {
        let (ExpectedSize::Exact(w, h) | ExpectedSize::Near(w, h)) = expected;
        return Err(DatasetError::ImageSize {
            path: path.to_path_buf(),
            expected: (w, h),
            found,
        });
    }
    let has_alpha = decoded.color().has_alpha();
    let mut rgba = decoded.to_rgba32f();
    for p in rgba.pixels_mut() {
        let a = p[3];
        for c in 0..3 {
            p[c] = p[c] * a + background[c] * (1.0 - a);
        }
    }
    if let Some((w, h)) = target.filter(|&t| t != found) {
        rgba = image::imageops::resize(&rgba, w, h, FilterType::CatmullRom);
    }
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
