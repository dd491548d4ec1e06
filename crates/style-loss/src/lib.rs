//! CLIPGaussian's style losses in candle: CLIP (vision and text towers), its tokenizer and
//! prompt templates, VGG-19 features, differentiable resize / crop / perspective warp, and the
//! four losses (directional, patch, content, background) with their gradient with respect to
//! the rendered image.
//!
//! [`StyleObjective`] plugs the losses into gs-core's training loop.
//!
//! Conventions: images are f32, linear, in [0, 1], channels first (`[3, h, w]` or
//! `[1, 3, h, w]`); gradients come back in the shape the image came in. Every operation that
//! lies between the image and a loss has a backward pass that is tested against PyTorch.
//!
//! - [`clip`], [`tokenizer`], [`templates`], [`style_direction`]: CLIP, its tokenizer, the
//!   prompt templates, and the style direction in CLIP space.
//! - [`vgg`]: VGG-19 features of the content loss.
//! - [`losses`] and [`terms`]: the four losses of a view with their gradient, and each term
//!   alone as a differentiable scalar.
//! - [`objective`]: the losses as gs-core's training objective ([`StyleObjective`]).
//! - [`patches`], [`perspective`], [`window_warp`], [`resize`], [`pil_resize`]: the patch
//!   augmentation (crop, perspective warp, resize), on the host and in the form a GPU runs it.
//! - [`nn`], [`matmul`], [`torch_ties`]: differentiable building blocks, products in the
//!   layouts candle's CUDA backend accepts, PyTorch's gradient at ties and exact zeros.
//! - [`precision`], [`auto_precision`]: the formats CLIP and VGG run in, and how `auto` times
//!   f32 against bf16 products to choose.
//! - [`metrics`]: the paper's CLIP evaluation metrics.
//! - [`compute_device`], [`memory`], [`transfers`]: the loss's device, the allocator setting,
//!   the host-device traffic counts.
//! - [`image_layout`], [`tensor_file`], [`weight_resolution`], [`error`]: image layouts,
//!   checkpoints, where model files come from, the error type.
//! - `test_models` (feature `test-models`): random-weight models for tests and benchmarks.

pub mod auto_precision;
mod bf16_product;
pub mod clip;
pub mod compute_device;
mod conv3x3;
mod conv3x3_bf16;
mod conv3x3_winograd;
mod cpu_elements;
pub mod cpu_threads;
mod custom_grad;
pub mod error;
mod fused_cpu;
pub mod image_layout;
pub mod losses;
pub mod matmul;
pub mod memory;
pub mod metrics;
pub mod nn;
pub mod objective;
pub mod patches;
pub mod perspective;
pub mod pil_resize;
pub mod precision;
pub mod resize;
mod seeded;
pub mod style_direction;
pub mod templates;
pub mod tensor_file;
pub mod terms;
#[cfg(test)]
mod test_grad;
#[cfg(feature = "test-models")]
pub mod test_models;
pub mod tokenizer;
pub mod torch_ties;
pub mod transfers;
pub mod vgg;
mod vgg_channels_last;
pub mod weight_resolution;
pub mod window_warp;

/// The candle this crate is built on: images and gradients cross as its tensors, so callers
/// use this one rather than pinning their own.
pub use candle_core;
pub use clip::{ClipConfig, ClipModel};
pub use cpu_elements::GenericPath;
pub use error::{Result, StyleLossError};
pub use losses::{
    background_mask_from_color, LossTerms, LossWeights, StyleLoss, StyleLossOutput, ViewCache,
};
pub use objective::{CacheBudget, StyleObjective};
pub use patches::{style_rng, PatchAugmentation, PatchSettings, StyleRng};
pub use precision::{ClipPrecision, VggPrecision};
pub use style_direction::{StyleDirection, DEFAULT_SOURCE_PROMPT};
pub use tensor_file::NamedTensors;
pub use tokenizer::ClipTokenizer;
pub use vgg::{Vgg19Features, Vgg19Widths};
