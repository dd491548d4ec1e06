//! The loss curve as a picture: the total loss against the step, a polyline inside two axes,
//! drawn with the `image` crate alone.

use std::path::Path;

use image::{Rgb, RgbImage};

use crate::StylizeError;

/// Width of the plot, pixels.
pub const PLOT_WIDTH: u32 = 640;
/// Height of the plot, pixels.
pub const PLOT_HEIGHT: u32 = 360;
const MARGIN: u32 = 30;
const AXIS: Rgb<u8> = Rgb([0, 0, 0]);
const CURVE: Rgb<u8> = Rgb([200, 40, 40]);

/// Plots `values` (one per step, in order) on a linear scale from their minimum (bottom) to
/// their maximum (top); non-finite values are skipped.
pub fn plot(values: &[f32]) -> RgbImage {
    let mut img = RgbImage::from_pixel(PLOT_WIDTH, PLOT_HEIGHT, Rgb([255, 255, 255]));
    let (left, right) = (MARGIN, PLOT_WIDTH - MARGIN);
    let (top, bottom) = (MARGIN, PLOT_HEIGHT - MARGIN);
    line(&mut img, (left, bottom), (right, bottom), AXIS);
    line(&mut img, (left, top), (left, bottom), AXIS);
    let finite: Vec<(usize, f32)> = values
        .iter()
        .copied()
        .enumerate()
        .filter(|(_, v)| v.is_finite())
        .collect();
    let lo = finite.iter().map(|p| p.1).fold(f32::INFINITY, f32::min);
    let hi = finite.iter().map(|p| p.1).fold(f32::NEG_INFINITY, f32::max);
    let span = if hi > lo { hi - lo } else { 1.0 };
    let last = values.len().saturating_sub(1).max(1) as f32;
    let to_pixel = |(i, v): (usize, f32)| {
        let x = left as f32 + (right - left) as f32 * i as f32 / last;
        let y = bottom as f32 - (bottom - top) as f32 * (v - lo) / span;
        (x.round() as u32, y.round() as u32)
    };
    let points: Vec<(u32, u32)> = finite.into_iter().map(to_pixel).collect();
    for pair in points.windows(2) {
        line(&mut img, pair[0], pair[1], CURVE);
    }
    if let [only] = points.as_slice() {
        img.put_pixel(only.0, only.1, CURVE);
    }
    img
}

/// Writes the plot of `values` to `path` (PNG, through [`gs_core::fs`]).
pub fn write_plot(path: &Path, values: &[f32]) -> Result<(), StylizeError> {
    Ok(gs_core::image::save_rgb8_png(&plot(values), path)?)
}

/// A straight line between two pixels (both inside the image), one pixel per step of its
/// longer axis.
fn line(img: &mut RgbImage, a: (u32, u32), b: (u32, u32), color: Rgb<u8>) {
    let (dx, dy) = (b.0 as f32 - a.0 as f32, b.1 as f32 - a.1 as f32);
    let n = dx.abs().max(dy.abs()).max(1.0) as u32;
    for k in 0..=n {
        let t = k as f32 / n as f32;
        let x = (a.0 as f32 + t * dx).round() as u32;
        let y = (a.1 as f32 + t * dy).round() as u32;
        img.put_pixel(x, y, color);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_falling_curve_starts_high_on_the_left_and_ends_low_on_the_right() {
        let img = plot(&[3.0, 2.0, f32::NAN, 1.0]);
        assert_eq!(img.dimensions(), (PLOT_WIDTH, PLOT_HEIGHT));
        assert_eq!(*img.get_pixel(MARGIN, MARGIN), CURVE);
        assert_eq!(
            *img.get_pixel(PLOT_WIDTH - MARGIN, PLOT_HEIGHT - MARGIN),
            CURVE
        );
        assert_eq!(
            *img.get_pixel(PLOT_WIDTH - MARGIN, MARGIN),
            Rgb([255, 255, 255])
        );
        let single = plot(&[2.0]);
        assert_eq!(*single.get_pixel(MARGIN, PLOT_HEIGHT - MARGIN), CURVE);
    }
}
