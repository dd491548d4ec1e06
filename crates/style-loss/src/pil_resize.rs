//! Pillow's bicubic resize of 8-bit images, bit for bit (`gs_core::pil_resize`, where the
//! dataset loaders use it too), with this crate's error type.

use crate::error::{Result, StyleLossError};

/// Resizes planar 8-bit channels `[channels, h, w]` to `[channels, out_h, out_w]` exactly as
/// Pillow's `Image.resize((out_w, out_h), Image.BICUBIC)` resizes an 8-bit `L` or `RGB` image
/// (see [`gs_core::pil_resize::pil_bicubic_resize`]). Sizes are `(height, width)`.
pub fn pil_bicubic_resize(
    planes: &[u8],
    channels: usize,
    input: (usize, usize),
    output: (usize, usize),
) -> Result<Vec<u8>> {
    gs_core::pil_resize::pil_bicubic_resize(planes, channels, input, output).map_err(|e| {
        StyleLossError::Input {
            name: "planes".into(),
            reason: e.0,
        }
    })
}
