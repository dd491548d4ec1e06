//! RGB images in memory: `f32` in `[0, 1]`, height x width x 3 (HWC), and PNG input/output.
//! Pixel values are the PNG's 8-bit values divided by 255, with no gamma conversion, as 3DGS
//! and CLIPGaussian read images.

use std::path::Path;

use crate::real::Real;
use crate::GsError;

/// An RGB image, `data[(y * width + x) * 3 + c]`.
#[derive(Clone, Debug, PartialEq)]
pub struct Image<T: Real = f32> {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Interleaved RGB values, `[H, W, 3]`.
    pub data: Vec<T>,
}

impl<T: Real> Image<T> {
    /// An image of one colour.
    pub fn filled(width: u32, height: u32, rgb: [T; 3]) -> Self {
        let n = width as usize * height as usize;
        let mut data = Vec::with_capacity(n * 3);
        for _ in 0..n {
            data.extend_from_slice(&rgb);
        }
        Self {
            width,
            height,
            data,
        }
    }

    /// Number of pixels.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// The RGB value at `(x, y)`.
    pub fn pixel(&self, x: u32, y: u32) -> [T; 3] {
        let i = (y as usize * self.width as usize + x as usize) * 3;
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }
}

impl Image<f32> {
    /// Reads a PNG or JPEG file; an alpha channel, if any, is composited over `background`.
    pub fn load(path: &Path, background: [f32; 3]) -> Result<Self, GsError> {
        let img = open_image(path)?;
        let rgba = img.to_rgba32f();
        let (width, height) = rgba.dimensions();
        let mut data = Vec::with_capacity(width as usize * height as usize * 3);
        for p in rgba.pixels() {
            let a = p[3];
            for c in 0..3 {
                data.push(p[c] * a + background[c] * (1.0 - a));
            }
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// Reads a PNG or JPEG file as the loaders of D-MiSo, VeGaS and MiraGe read pictures: alpha
    /// composited over `background` in `f64` and the result cut to whole 8-bit levels
    /// ([`crate::levels::composite_8bit`]), so the values are `level / 255`.
    pub fn load_8bit_composite(path: &Path, background: [f32; 3]) -> Result<Self, GsError> {
        let img = open_image(path)?;
        Ok(Self::rgb_of(&crate::levels::composited_8bit(
            &img, background,
        )))
    }

    /// Reads a PNG or JPEG file's stored colours, alpha ignored, as `level / 255` (PIL's
    /// levels; the authors' style images: `ToTensor()(image)[:3]`).
    pub fn load_stored_colours(path: &Path) -> Result<Self, GsError> {
        let img = open_image(path)?;
        Ok(Self::rgb_of(&crate::levels::stored_levels(&img)))
    }

    /// The RGB channels of `rgba`.
    fn rgb_of(rgba: &image::Rgba32FImage) -> Self {
        let (width, height) = rgba.dimensions();
        let data = rgba.pixels().flat_map(|p| [p[0], p[1], p[2]]).collect();
        Self {
            width,
            height,
            data,
        }
    }

    /// The image as 8-bit RGB, values clamped to `[0, 1]` and rounded.
    pub fn to_rgb8(&self) -> image::RgbImage {
        let bytes = self
            .data
            .iter()
            .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
            .collect();
        image::RgbImage::from_raw(self.width, self.height, bytes)
            .expect("data has width * height * 3 values")
    }

    /// Writes an 8-bit PNG. The file is written under a temporary name beside `path` and renamed,
    /// so a failure never leaves a partial file at `path`.
    pub fn save_png(&self, path: &Path) -> Result<(), GsError> {
        save_rgb8_png(&self.to_rgb8(), path)
    }

    /// Images placed left to right on one canvas (heights may differ; the rest is black).
    pub fn side_by_side(images: &[&Image]) -> Image {
        let width = images.iter().map(|i| i.width).sum();
        let height = images.iter().map(|i| i.height).max().unwrap_or(0);
        let mut out = Image::filled(width, height, [0.0; 3]);
        let mut x0 = 0usize;
        for img in images {
            for y in 0..img.height as usize {
                let src = &img.data[y * img.width as usize * 3..(y + 1) * img.width as usize * 3];
                let dst = (y * width as usize + x0) * 3;
                out.data[dst..dst + src.len()].copy_from_slice(src);
            }
            x0 += img.width as usize;
        }
        out
    }
}

/// Writes an 8-bit RGB PNG through a temporary file, an fsync and a rename
/// ([`crate::fs::write_atomic_with`]).
pub fn save_rgb8_png(img: &image::RgbImage, path: &Path) -> Result<(), GsError> {
    crate::fs::write_atomic_with(path, |w| {
        img.write_to(w, image::ImageFormat::Png)
            .map_err(std::io::Error::other)
    })
    .map_err(|e| GsError::Image {
        path: path.to_path_buf(),
        source: Box::new(e),
    })
}

/// The width and height of the picture at `path`, pixels, read from its header without
/// decoding it (so that a picture too large to decode can be refused first); the error names
/// the file.
pub fn picture_size(path: &Path) -> Result<(u32, u32), GsError> {
    image::image_dimensions(path).map_err(|e| GsError::Image {
        path: path.to_path_buf(),
        source: Box::new(e),
    })
}

/// Decodes the picture at `path`; the error names the file.
fn open_image(path: &Path) -> Result<image::DynamicImage, GsError> {
    decode_picture(path).map_err(|e| GsError::Image {
        path: path.to_path_buf(),
        source: Box::new(e),
    })
}

/// Pixels of the largest picture decoded (64 megapixels, e.g. 8192 x 8192): decoding and
/// converting to `f32` take up to 24 bytes a pixel, 1.6 GB.
pub const MAX_PICTURE_PIXELS: u64 = 1 << 26;

/// Why a picture could not be decoded.
#[derive(Debug, thiserror::Error)]
pub enum PictureDecodeError {
    /// The decoder's error.
    #[error("{0}")]
    Image(#[from] image::ImageError),
    /// A picture whose header claims more pixels than [`MAX_PICTURE_PIXELS`].
    #[error(
        "the picture is {width}x{height} ({} megapixels), which would take about {:.1} GB to \
         decode; pictures up to {} megapixels are read: downscale it first (for a dataset, a \
         downscaled folder such as images_4/ read with -r 4)",
        u64::from(*width) * u64::from(*height) / 1_000_000,
        24.0 * f64::from(*width) * f64::from(*height) / 1e9,
        MAX_PICTURE_PIXELS / 1_000_000
    )]
    TooLarge {
        /// Width its header gives, pixels.
        width: u32,
        /// Height its header gives, pixels.
        height: u32,
    },
    /// A picture whose header claims a side longer than [`crate::camera::MAX_SIDE`]: no
    /// camera can have it, and resizing it would cost in proportion to that side.
    #[error(
        "the picture is {width}x{height}; pictures up to {} pixels a side are read: crop or \
         downscale it first",
        crate::camera::MAX_SIDE
    )]
    TooLong {
        /// Width its header gives, pixels.
        width: u32,
        /// Height its header gives, pixels.
        height: u32,
    },
}

/// Decodes the picture at `path` after reading its size from its header: one of more than
/// [`MAX_PICTURE_PIXELS`], or with a side longer than [`crate::camera::MAX_SIDE`], is refused
/// before any of it is decoded (a few kilobytes of PNG can claim 23000 x 23000, or
/// 67108864 x 1), and the decoder may not allocate more than such a picture needs.
pub fn decode_picture(path: &Path) -> Result<image::DynamicImage, PictureDecodeError> {
    let open = || -> Result<image::ImageReader<_>, image::ImageError> {
        Ok(image::ImageReader::open(path)?.with_guessed_format()?)
    };
    let (width, height) = open()?.into_dimensions()?;
    if u64::from(width) * u64::from(height) > MAX_PICTURE_PIXELS {
        return Err(PictureDecodeError::TooLarge { width, height });
    }
    if width.max(height) > crate::camera::MAX_SIDE {
        return Err(PictureDecodeError::TooLong { width, height });
    }
    let mut reader = open()?;
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(8 * MAX_PICTURE_PIXELS + (1 << 20));
    reader.limits(limits);
    Ok(reader.decode()?)
}
