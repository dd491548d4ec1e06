//! The picture a user gives (PNG or JPEG of any size, transparency composited over a chosen
//! background and cut to 8 bits, shrunk to 1600 pixels wide when wider unless asked otherwise,
//! as MiraGe reads pictures) and the embedded default picture.

use std::f32::consts::PI;
use std::path::Path;

use gs_core::wide_pictures::shrink_wide;
use gs_core::{GsError, Image};

/// The smallest side, in pixels, of a picture that can be fitted: one 16x16 rasterizer tile.
pub const MIN_SIDE: u32 = 16;

/// Side of the embedded default picture, pixels: big enough for the paper's 128-pixel
/// patches to be details, small enough for a CPU preview run.
pub const DEFAULT_SIDE: u32 = 384;

/// Why a picture cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum PictureError {
    /// The file could not be read or decoded.
    #[error("{0}")]
    Unreadable(#[from] GsError),
    /// The picture is too small to fit Gaussians to.
    #[error("picture {path}: {width}x{height} pixels is too small; both sides must be at least {MIN_SIDE}")]
    TooSmall {
        /// The file.
        path: String,
        /// Width, pixels.
        width: u32,
        /// Height, pixels.
        height: u32,
    },
}

/// Reads the picture at `path` as MiraGe reads pictures: transparent pixels composited over
/// `background` (linear RGB in `[0, 1]`) and the result cut to whole 8-bit levels, then shrunk
/// when wider than `max_width` (0: kept at its size; [`shrink_wide`]).
pub fn load_picture(
    path: &Path,
    background: [f32; 3],
    max_width: u32,
) -> Result<Image, PictureError> {
    let image = shrink_wide(Image::load_8bit_composite(path, background)?, max_width);
    if image.width < MIN_SIDE || image.height < MIN_SIDE {
        return Err(PictureError::TooSmall {
            path: path.display().to_string(),
            width: image.width,
            height: image.height,
        });
    }
    Ok(image)
}

/// The embedded default picture: [`landscape`] at [`DEFAULT_SIDE`] pixels.
pub fn default_picture() -> Image {
    landscape(DEFAULT_SIDE)
}

/// The default picture's drawing at `side x side` pixels: a landscape with an evening sky, a
/// sun, two mountain ridges, a lake that mirrors the sky and a red house with a dark roof. It
/// has smooth gradients, hard edges and small detail, so it shows both how well a fit holds a
/// picture and how a style changes it.
pub fn landscape(side: u32) -> Image {
    let mut data = Vec::with_capacity((side * side * 3) as usize);
    for y in 0..side {
        for x in 0..side {
            let u = (x as f32 + 0.5) / side as f32;
            let v = (y as f32 + 0.5) / side as f32;
            data.extend_from_slice(&landscape_colour(u, v));
        }
    }
    Image {
        width: side,
        height: side,
        data,
    }
}

fn mix(a: [f32; 3], b: [f32; 3], t: f32) -> [f32; 3] {
    let t = t.clamp(0.0, 1.0);
    [0, 1, 2].map(|c| a[c] + (b[c] - a[c]) * t)
}

/// The sky at height `v` (0 top): deep blue above, orange at the horizon, with the sun.
fn sky(u: f32, v: f32) -> [f32; 3] {
    let base = mix([0.12, 0.22, 0.55], [0.98, 0.62, 0.3], v / 0.62);
    let d = ((u - 0.7).powi(2) + (v - 0.42).powi(2)).sqrt();
    let glow = (-d * d / 0.01).exp() * 0.5;
    let lit = mix(base, [1.0, 0.9, 0.55], glow);
    if d < 0.06 {
        [1.0, 0.93, 0.6]
    } else {
        lit
    }
}

/// Colour at `(u, v)` in `[0, 1]^2`, `v` down.
fn landscape_colour(u: f32, v: f32) -> [f32; 3] {
    let horizon = 0.62;
    let far = 0.45 + 0.07 * (u * 2.0 * PI * 1.3).sin() + 0.03 * (u * 2.0 * PI * 4.1).sin();
    let near = 0.55 + 0.05 * (u * 2.0 * PI * 0.8 + 1.0).sin() + 0.015 * (u * 2.0 * PI * 9.0).sin();
    let house = (0.22..0.34).contains(&u) && (0.52..horizon).contains(&v);
    let roof = (v - (0.45 + (u - 0.28).abs())).abs() < 0.07 && v < 0.52 && (0.2..0.36).contains(&u);
    if roof && v > 0.45 + (u - 0.28).abs() {
        return [0.2, 0.12, 0.1];
    }
    if house {
        let window = (0.25..0.29).contains(&u) && (0.54..0.58).contains(&v);
        return if window {
            [0.95, 0.85, 0.4]
        } else {
            [0.72, 0.16, 0.12]
        };
    }
    if v >= horizon {
        let mirror = sky(u, 2.0 * horizon - v);
        let ripple = 0.04 * ((v - horizon) * 180.0 + (u * 25.0).sin()).sin();
        return mix([0.05, 0.18, 0.3], mirror, 0.7 + ripple);
    }
    if v > near {
        return mix([0.16, 0.36, 0.14], [0.08, 0.22, 0.08], (v - near) / 0.08);
    }
    if v > far {
        return mix([0.35, 0.32, 0.45], [0.22, 0.2, 0.32], (v - far) / 0.15);
    }
    sky(u, v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_picture_is_varied_and_in_range() {
        let img = default_picture();
        assert_eq!((img.width, img.height), (DEFAULT_SIDE, DEFAULT_SIDE));
        assert!(img.data.iter().all(|v| (0.0..=1.0).contains(v)));
        let mean: f32 = img.data.iter().sum::<f32>() / img.data.len() as f32;
        let var: f32 =
            img.data.iter().map(|v| (v - mean).powi(2)).sum::<f32>() / img.data.len() as f32;
        assert!(var > 0.02, "a picture, not a flat colour: variance {var}");
    }

    #[test]
    fn a_picture_wider_than_the_limit_is_shrunk_as_mirage_shrinks_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("wide.png");
        image::RgbImage::from_fn(1650, 20, |x, y| {
            image::Rgb([(x % 256) as u8, (y * 9) as u8, 40])
        })
        .save(&path)
        .unwrap();
        let full = load_picture(&path, [0.0; 3], 0).unwrap();
        assert_eq!((full.width, full.height), (1650, 20));
        let shrunk =
            load_picture(&path, [0.0; 3], gs_core::wide_pictures::AUTHORS_MAX_WIDTH).unwrap();
        // int(20 / (1650 / 1600)) = 19.
        assert_eq!((shrunk.width, shrunk.height), (1600, 19));
        assert_eq!(shrunk, shrink_wide(full, 1600));
    }

    #[test]
    fn a_transparent_picture_is_composited_and_cut_to_8_bits_as_mirage_reads_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("ramp.png");
        image::RgbaImage::from_fn(256, 32, |x, y| {
            image::Rgba([x as u8, 255 - x as u8, 7, (8 * y) as u8])
        })
        .save(&path)
        .unwrap();
        for background in [[0.0; 3], [1.0; 3]] {
            let picture = load_picture(&path, background, 0).unwrap();
            for (x, y) in [(0, 0), (255, 16), (130, 9), (3, 31), (200, 1)] {
                let rgb = [x as u8, 255 - x as u8, 7];
                let want = gs_core::levels::composite_8bit(rgb, (8 * y) as u8, background)
                    .map(|v| f32::from(v) / 255.0);
                assert_eq!(picture.pixel(x, y), want, "({x}, {y}) over {background:?}");
            }
        }
    }
}
