//! torchvision's perspective warp (`transforms.functional.perspective` on tensors, bilinear,
//! fill 0) as a differentiable gather from the image.
//!
//! Each output pixel is a weighted sum of four input pixels, so the warp is `gather` plus a
//! weighted sum and its backward is a scatter-add: gradients reach the image. The weights follow
//! torchvision exactly: coefficients solved in f64 and rounded to f32, sampling at pixel centres
//! with `grid_sample(align_corners=False, padding_mode="zeros")`, and torchvision's fill
//! handling, which multiplies the sample by the warped all-ones mask.

use crate::error::{Result, StyleLossError};

/// Corner points `(x, y)` in pixels, in torchvision's order: top-left, top-right,
/// bottom-right, bottom-left.
pub type Corners = [[i64; 2]; 4];

/// The corners of an unwarped `width x height` image: torchvision's `startpoints`.
pub fn image_corners(width: usize, height: usize) -> Corners {
    let (w, h) = (width as i64 - 1, height as i64 - 1);
    [[0, 0], [w, 0], [w, h], [0, h]]
}

/// torchvision's `_get_perspective_coeffs(startpoints, endpoints)`: `(a, b, c, d, e, f, g, h)`
/// mapping an output point `(x, y)` to the input point
/// `((a x + b y + c) / (g x + h y + 1), (d x + e y + f) / (g x + h y + 1))`.
pub fn perspective_coefficients(start: &Corners, end: &Corners) -> Result<[f32; 8]> {
    let mut a = [[0f64; 9]; 8];
    for (i, (p, q)) in end.iter().zip(start).enumerate() {
        let (x, y) = (p[0] as f64, p[1] as f64);
        let (u, v) = (q[0] as f64, q[1] as f64);
        a[2 * i] = [x, y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y, u];
        a[2 * i + 1] = [0.0, 0.0, 0.0, x, y, 1.0, -v * x, -v * y, v];
    }
    // Gaussian elimination with partial pivoting on the augmented 8x9 system.
    for col in 0..8 {
        let pivot = (col..8)
            .max_by(|&r, &s| a[r][col].abs().total_cmp(&a[s][col].abs()))
            .unwrap_or(col);
        if a[pivot][col].abs() < 1e-12 {
            return Err(StyleLossError::Input {
                name: "perspective corners".into(),
                reason: format!("degenerate quadrilateral {end:?}"),
            });
        }
        a.swap(col, pivot);
        for row in 0..8 {
            if row != col {
                let factor = a[row][col] / a[col][col];
                for k in col..9 {
                    a[row][k] -= factor * a[col][k];
                }
            }
        }
    }
    let mut coeffs = [0f32; 8];
    for (i, c) in coeffs.iter_mut().enumerate() {
        *c = (a[i][8] / a[i][i]) as f32;
    }
    Ok(coeffs)
}

/// Bilinear taps of a warp: for each output pixel four `(source index, weight)` pairs.
/// Taps outside the source get index 0 and weight 0.
#[derive(Clone, Debug, Default)]
pub struct Taps {
    /// Flat source indices, four per output pixel.
    pub index: Vec<u32>,
    /// Weights, four per output pixel.
    pub weight: Vec<f32>,
}

/// Where a warp reads from: a `width x height` window at `(left, top)` of a source image
/// `source_width` pixels wide (the window is the crop that is being warped).
#[derive(Clone, Copy, Debug)]
pub struct SourceWindow {
    /// Window width in pixels.
    pub width: usize,
    /// Window height in pixels.
    pub height: usize,
    /// Column of the window's left edge in the source.
    pub left: usize,
    /// Row of the window's top edge in the source.
    pub top: usize,
    /// Width of the whole source image (row stride of flat indices).
    pub source_width: usize,
}

impl Taps {
    /// Appends the taps of warping `window` (output of the window's size) with `coeffs`.
    pub fn push_perspective(&mut self, coeffs: &[f32; 8], window: SourceWindow) {
        let c: Vec<f64> = coeffs.iter().map(|&v| v as f64).collect();
        let (w, h) = (window.width as f64, window.height as f64);
        for oy in 0..window.height {
            for ox in 0..window.width {
                let (x, y) = (ox as f64 + 0.5, oy as f64 + 0.5);
                let den = c[6] * x + c[7] * y + 1.0;
                // torchvision's normalized grid, then grid_sample's unnormalization.
                let gx = (c[0] * x + c[1] * y + c[2]) / (0.5 * w) / den - 1.0;
                let gy = (c[3] * x + c[4] * y + c[5]) / (0.5 * h) / den - 1.0;
                let ix = ((gx + 1.0) * w - 1.0) / 2.0;
                let iy = ((gy + 1.0) * h - 1.0) / 2.0;
                let (x0, y0) = (ix.floor(), iy.floor());
                let (fx, fy) = (ix - x0, iy - y0);
                let corners = [
                    (x0, y0, (1.0 - fx) * (1.0 - fy)),
                    (x0 + 1.0, y0, fx * (1.0 - fy)),
                    (x0, y0 + 1.0, (1.0 - fx) * fy),
                    (x0 + 1.0, y0 + 1.0, fx * fy),
                ];
                let inside = |px: f64, py: f64| px >= 0.0 && py >= 0.0 && px < w && py < h;
                // torchvision samples an all-ones mask with the same grid and multiplies.
                let mask: f64 = corners
                    .iter()
                    .filter(|(px, py, _)| inside(*px, *py))
                    .map(|(_, _, wt)| wt)
                    .sum();
                for &(px, py, wt) in &corners {
                    if inside(px, py) && wt != 0.0 {
                        let sx = window.left + px as usize;
                        let sy = window.top + py as usize;
                        self.index.push((sy * window.source_width + sx) as u32);
                        self.weight.push((wt * mask) as f32);
                    } else {
                        self.index.push(0);
                        self.weight.push(0.0);
                    }
                }
            }
        }
    }
}

/// Samples `source` `[channels, pixels]` (flattened rows) at `taps`: `[channels, outputs]`,
/// differentiable in `source` (gather forward, scatter-add backward).
pub fn gather_taps(source: &candle_core::Tensor, taps: &Taps) -> Result<candle_core::Tensor> {
    let (channels, _) = source.dims2()?;
    let count = taps.index.len();
    if !count.is_multiple_of(4) || taps.weight.len() != count {
        return Err(StyleLossError::Input {
            name: "taps".into(),
            reason: format!(
                "{count} indices and {} weights, expected 4 per output",
                taps.weight.len()
            ),
        });
    }
    let device = source.device();
    let index = candle_core::Tensor::from_slice(&taps.index, count, device)?;
    let weight = candle_core::Tensor::from_slice(&taps.weight, (1, count), device)?;
    crate::transfers::record_upload(std::mem::size_of_val(taps.index.as_slice()));
    crate::transfers::record_upload(std::mem::size_of_val(taps.weight.as_slice()));
    let sampled = source.index_select(&index, 1)?.broadcast_mul(&weight)?;
    Ok(sampled.reshape((channels, count / 4, 4))?.sum(2)?)
}
