//! The authors' `clip_normalize`: bicubic squash to the model's input size, then CLIP's
//! per-channel normalization.

use candle_core::Tensor;

use crate::error::Result;
use crate::resize::{resize, ResizeKernel};

/// CLIP's per-channel pixel mean (RGB, for values in [0, 1]).
pub const CLIP_MEAN: [f32; 3] = [0.481_454_66, 0.457_827_5, 0.408_210_73];
/// CLIP's per-channel pixel standard deviation (RGB, for values in [0, 1]).
pub const CLIP_STD: [f32; 3] = [0.268_629_54, 0.261_302_6, 0.275_777_1];

/// `(x - mean) / std` per channel of `[n, 3, h, w]`.
pub(crate) fn normalize_channels(
    images: &Tensor,
    mean: [f32; 3],
    std: [f32; 3],
) -> candle_core::Result<Tensor> {
    let device = images.device();
    let mean = Tensor::new(&mean, device)?.reshape((1, 3, 1, 1))?;
    let std = Tensor::new(&std, device)?.reshape((1, 3, 1, 1))?;
    images.broadcast_sub(&mean)?.broadcast_div(&std)
}

/// Images `[n, 3, h, w]` in [0, 1] -> CLIP input `[n, 3, size, size]`: bicubic resize (no
/// aspect preservation, no crop, no antialias, no clamp), then CLIP normalization.
pub fn clip_preprocess(images: &Tensor, size: usize) -> Result<Tensor> {
    let resized = resize(images, (size, size), ResizeKernel::Bicubic)?;
    Ok(normalize_channels(&resized, CLIP_MEAN, CLIP_STD)?)
}
