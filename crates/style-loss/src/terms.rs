//! Each CLIPGaussian loss term alone, as a differentiable scalar of the rendered image, and
//! [`value_and_grad`] for one term's value and image gradient without a [`crate::StyleLoss`]
//! (no other model, weight or patch setting needed). [`crate::StyleLoss`] sums these.
//!
//! Images are `[1, 3, h, w]`, f32 in [0, 1].
//!
//! ```
//! use style_loss::candle_core::{Device, Tensor};
//! use style_loss::tensor_file::NamedTensors;
//! use style_loss::{terms, Vgg19Features, Vgg19Widths};
//!
//! // A tiny VGG-19 with random weights (real weights load with `Vgg19Features::load`).
//! let widths = Vgg19Widths([4, 8, 8, 8, 8]);
//! let vgg = Vgg19Features::from_tensors(&NamedTensors::random(&Device::Cpu), widths)?;
//! let gt = Tensor::full(0.5f32, (1, 3, 32, 48), &Device::Cpu)?;
//! let render = Tensor::rand(0f32, 1f32, (1, 3, 32, 48), &Device::Cpu)?;
//! let gt_features = vgg.forward(&gt)?.detach();
//! let (loss, grad) = terms::value_and_grad(&render, |x| terms::content(&vgg, x, &gt_features))?;
//! assert!(loss > 0.0);
//! assert_eq!(grad.dims(), render.dims());
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use candle_core::{DType, Tensor, Var};

use crate::clip::{clip_preprocess, ClipModel};
use crate::error::{Result, StyleLossError};
use crate::nn::l2_normalize;
use crate::patches::{warped_patches, PatchAugmentation};
use crate::style_direction::StyleDirection;
use crate::torch_ties;
use crate::vgg::{Vgg19Features, VggFeatures};

/// `L_d = 1 - cos(normalize(E(image) - E(gt)), s)`, with `gt_embedding` the normalized CLIP
/// embedding of the ground truth (`[1, dim]`).
pub fn directional(
    clip: &ClipModel,
    direction: &StyleDirection,
    image: &Tensor,
    gt_embedding: &Tensor,
) -> Result<Tensor> {
    let embedding = clip.encode_images(image)?;
    Ok(direction
        .directional_loss(&embedding, gt_embedding)?
        .mean_all()?)
}

/// `L_p`: the mean over `patches` (crops of `patch_size` pixels, perspective-warped, resized
/// to CLIP's input) of the directional loss of each patch against the full ground truth.
/// `patches` must not be empty (the patch loss would be the mean of nothing).
pub fn patch(
    clip: &ClipModel,
    direction: &StyleDirection,
    image: &Tensor,
    gt_embedding: &Tensor,
    patches: &[PatchAugmentation],
    patch_size: usize,
) -> Result<Tensor> {
    check_patches_given(patches)?;
    let crops = warped_patches(image, patches, patch_size, clip.image_size())?;
    let embeddings = clip.encode_images(&crops)?;
    Ok(direction
        .directional_loss(&embeddings, gt_embedding)?
        .mean_all()?)
}

/// Refuses an empty set of patches: the patch loss would be the mean of nothing, a NaN.
fn check_patches_given(patches: &[PatchAugmentation]) -> Result<()> {
    if patches.is_empty() {
        return Err(StyleLossError::Input {
            name: "patches".into(),
            reason: "the patch loss needs at least one patch, and none was given".into(),
        });
    }
    Ok(())
}

/// `(L_d, L_p)` from one pass of CLIP's vision tower over the whole image and its patches
/// together (a batch of `1 + patches.len()`), the values [`directional`] and [`patch`] give
/// apart: one image alone makes products of few rows, whose fixed costs a batch shares.
/// `patches` must not be empty (the patch loss would be the mean of nothing).
pub fn directional_and_patch(
    clip: &ClipModel,
    direction: &StyleDirection,
    image: &Tensor,
    gt_embedding: &Tensor,
    patches: &[PatchAugmentation],
    patch_size: usize,
) -> Result<(Tensor, Tensor)> {
    check_patches_given(patches)?;
    let size = clip.image_size();
    let whole = clip_preprocess(image, size)?;
    let crops = clip_preprocess(&warped_patches(image, patches, patch_size, size)?, size)?;
    let pixels = Tensor::cat(&[&whole, &crops], 0)?;
    let embeddings = l2_normalize(&clip.encode_pixels(&pixels)?)?;
    let losses = direction.directional_loss(&embeddings, gt_embedding)?;
    Ok((
        losses.narrow(0, 0, 1)?.mean_all()?,
        losses.narrow(0, 1, patches.len())?.mean_all()?,
    ))
}

/// `L_c = mean((F4 - F4_gt)^2) + mean((F5 - F5_gt)^2)` over VGG-19's conv4_2 and conv5_2
/// features.
pub fn content(vgg: &Vgg19Features, image: &Tensor, gt: &VggFeatures) -> Result<Tensor> {
    let f = vgg.forward(image)?;
    let mse = |a: &Tensor, b: &Tensor| (a - b)?.sqr()?.mean_all();
    Ok((mse(&f.relu4_2, &gt.relu4_2)? + mse(&f.relu5_2, &gt.relu5_2)?)?)
}

/// `L_b`: the mean over the `count` background pixels of `mask` (`[1, 1, h, w]`, 1 =
/// background) of the channel mean of `|image - gt|` (gradient 0 where they are equal, as
/// PyTorch's). `count` must be positive.
pub fn background(image: &Tensor, gt: &Tensor, mask: &Tensor, count: f64) -> Result<Tensor> {
    let per_pixel = torch_ties::abs(&(image - gt)?)?.mean_keepdim(1)?;
    Ok(((per_pixel * mask)?.sum_all()? / count)?)
}

/// The value of `term(image)` and its gradient with respect to `image` (zeros where the term
/// does not depend on it), in `image`'s shape.
pub fn value_and_grad(
    image: &Tensor,
    term: impl FnOnce(&Tensor) -> Result<Tensor>,
) -> Result<(f64, Tensor)> {
    let (value, grad) = value_tensor_and_grad(image, term)?;
    Ok((value.to_dtype(DType::F64)?.to_scalar::<f64>()?, grad))
}

/// [`value_and_grad`] with the value left on its device (detached), so that a caller can read
/// it with others in one transfer.
pub fn value_tensor_and_grad(
    image: &Tensor,
    term: impl FnOnce(&Tensor) -> Result<Tensor>,
) -> Result<(Tensor, Tensor)> {
    let var = Var::from_tensor(&image.detach())?;
    let value = term(var.as_tensor())?;
    let grads = value.backward()?;
    let grad = match grads.get(var.as_tensor()) {
        Some(g) => g.clone(),
        None => var.as_tensor().zeros_like()?,
    };
    Ok((value.detach(), grad))
}
