//! The patch augmentation of the patch loss: random crop, random perspective warp, resize to
//! the CLIP input size, as the authors' `RandomCrop` + `RandomPerspective(fill=0, p=1,
//! distortion_scale=0.5)` + `Resize(224)` on a rendered image.

use candle_core::Tensor;
use rand::{Rng, SeedableRng};

use crate::cpu_elements::is_cpu_f32;
use crate::error::{Result, StyleLossError};
use crate::perspective::{
    gather_taps, image_corners, perspective_coefficients, Corners, SourceWindow, Taps,
};
use crate::resize::{Resize, ResizeKernel};
use crate::window_warp::{warp_windows, WindowWarp};

/// The random source of the patch augmentation: a seeded stream repeats a run exactly.
pub type StyleRng = rand_chacha::ChaCha8Rng;

/// A [`StyleRng`] seeded with `seed`.
pub fn style_rng(seed: u64) -> StyleRng {
    StyleRng::seed_from_u64(seed)
}

/// One patch: a crop of the image and the warp applied to it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PatchAugmentation {
    /// Row of the crop's top edge in the image.
    pub top: usize,
    /// Column of the crop's left edge in the image.
    pub left: usize,
    /// Where the crop's corners go (torchvision's `endpoints`, in crop pixels).
    pub corners: Corners,
}

/// Patch count, size and distortion of the patch loss.
#[derive(Clone, Debug, PartialEq)]
pub struct PatchSettings {
    /// Crop side in pixels (paper: 128). The image must be at least this large.
    pub patch_size: usize,
    /// Patches per step (paper: 64).
    pub num_patches: usize,
    /// torchvision's `distortion_scale` (0.5): each corner moves inward by an integer in
    /// `[0, distortion_scale * half_size]`.
    pub distortion_scale: f64,
}

impl Default for PatchSettings {
    fn default() -> Self {
        Self {
            patch_size: 128,
            num_patches: 64,
            distortion_scale: 0.5,
        }
    }
}

/// torchvision's `RandomPerspective.get_params(width, height, distortion_scale)` endpoints.
pub fn random_perspective_corners<R: Rng + ?Sized>(
    rng: &mut R,
    width: usize,
    height: usize,
    distortion_scale: f64,
) -> Corners {
    let (w, h) = (width as i64, height as i64);
    let dx = (distortion_scale * (w / 2) as f64) as i64;
    let dy = (distortion_scale * (h / 2) as f64) as i64;
    let near = |rng: &mut R, d: i64| rng.random_range(0..=d);
    let far = |rng: &mut R, size: i64, d: i64| rng.random_range(size - d - 1..size);
    let top_left = [near(rng, dx), near(rng, dy)];
    let top_right = [far(rng, w, dx), near(rng, dy)];
    let bottom_right = [far(rng, w, dx), far(rng, h, dy)];
    let bottom_left = [near(rng, dx), far(rng, h, dy)];
    [top_left, top_right, bottom_right, bottom_left]
}

impl PatchSettings {
    /// Draws `num_patches` independent crops and warps for an image of `height x width`.
    pub fn sample<R: Rng + ?Sized>(
        &self,
        rng: &mut R,
        height: usize,
        width: usize,
    ) -> Result<Vec<PatchAugmentation>> {
        if self.patch_size == 0 || height < self.patch_size || width < self.patch_size {
            return Err(StyleLossError::Input {
                name: "image".into(),
                reason: format!(
                    "{height}x{width} is smaller than the patch size {}",
                    self.patch_size
                ),
            });
        }
        Ok((0..self.num_patches)
            .map(|_| {
                let top = rng.random_range(0..=height - self.patch_size);
                let left = rng.random_range(0..=width - self.patch_size);
                let corners = random_perspective_corners(
                    rng,
                    self.patch_size,
                    self.patch_size,
                    self.distortion_scale,
                );
                PatchAugmentation { top, left, corners }
            })
            .collect())
    }
}

/// Crops, warps and resizes patches of `image` `[1, 3, h, w]`: `[n, 3, output, output]`,
/// differentiable in `image`. Warps are bilinear with fill 0; the resize is torchvision's
/// `Resize` (bilinear, antialias). Off the CPU (and under [`crate::GenericPath`]) the warp runs
/// as [`crate::window_warp`]: taps computed on the device, backward a gather.
pub fn warped_patches(
    image: &Tensor,
    patches: &[PatchAugmentation],
    patch_size: usize,
    output: usize,
) -> Result<Tensor> {
    let (batch, channels, height, width) = image.dims4()?;
    if batch != 1 {
        return Err(StyleLossError::Input {
            name: "image".into(),
            reason: format!("batch of {batch}, expected 1"),
        });
    }
    for (i, p) in patches.iter().enumerate() {
        if p.top + patch_size > height || p.left + patch_size > width {
            return Err(StyleLossError::Input {
                name: format!("patch {i}"),
                reason: format!(
                    "crop at ({}, {}) of size {patch_size} leaves the {height}x{width} image",
                    p.top, p.left
                ),
            });
        }
    }
    let start = image_corners(patch_size, patch_size);
    let coeffs = patches
        .iter()
        .map(|p| perspective_coefficients(&start, &p.corners))
        .collect::<Result<Vec<_>>>()?;
    let warped = if is_cpu_f32(image) {
        // On the CPU the taps are built here and the backward is a serial scatter-add.
        let mut taps = Taps::default();
        for (p, coeffs) in patches.iter().zip(&coeffs) {
            taps.push_perspective(
                coeffs,
                SourceWindow {
                    width: patch_size,
                    height: patch_size,
                    left: p.left,
                    top: p.top,
                    source_width: width,
                },
            );
        }
        let flat = image.reshape((channels, height * width))?;
        gather_taps(&flat, &taps)?
            .reshape((channels, patches.len(), patch_size, patch_size))?
            .transpose(0, 1)?
            .contiguous()?
    } else {
        let warps: Vec<WindowWarp> = patches
            .iter()
            .zip(coeffs)
            .map(|(p, coeffs)| WindowWarp {
                left: p.left,
                top: p.top,
                coeffs,
            })
            .collect();
        warp_windows(&image.squeeze(0)?, &warps, patch_size, patch_size)?
    };
    let resize = Resize::cached(
        ResizeKernel::BilinearAntialias,
        (patch_size, patch_size),
        (output, output),
        image.device(),
    )?;
    resize.apply(&warped)
}
