//! Differentiable image resizes that match PyTorch, as separable linear maps.
//!
//! A resize is `Y = R X C^T` per channel with constant matrices `R` (rows) and `C` (columns), so
//! its backward is `R^T G C`. The matrices hold PyTorch's interpolation weights, border clamping
//! included, so forward and backward equal `torch.nn.functional.interpolate`.

use candle_core::{Device, Tensor};

use gs_core::pil_resize::antialias_taps_of;

use crate::custom_grad::attach_input_gradient;
use crate::error::{Result, StyleLossError};
use crate::matmul::checked_matmul;

/// Keys' cubic convolution parameter used by PyTorch.
const CUBIC_A: f64 = -0.75;

/// The interpolation of a resize.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResizeKernel {
    /// `F.interpolate(mode="bicubic", align_corners=False)` without antialias: source index
    /// `(dst + 0.5) * in / out - 0.5`, taps clamped to the border.
    Bicubic,
    /// `F.interpolate(mode="bilinear", align_corners=False, antialias=True)`, which is what
    /// torchvision's `Resize` does to tensors; identical to plain bilinear when upsampling.
    BilinearAntialias,
}

fn cubic_near(x: f64) -> f64 {
    ((CUBIC_A + 2.0) * x - (CUBIC_A + 3.0)) * x * x + 1.0
}

fn cubic_far(x: f64) -> f64 {
    ((CUBIC_A * x - 5.0 * CUBIC_A) * x + 8.0 * CUBIC_A) * x - 4.0 * CUBIC_A
}

/// The triangle (bilinear) filter of PIL and of PyTorch's antialiased bilinear, support 1.
fn triangle_filter(x: f64) -> f64 {
    (1.0 - x.abs()).max(0.0)
}

/// The `[output, input]` interpolation matrix (row-major) of one axis.
pub fn resize_matrix(kernel: ResizeKernel, input: usize, output: usize) -> Vec<f32> {
    let mut m = vec![0f64; output * input];
    let scale = input as f64 / output as f64;
    for i in 0..output {
        let row = &mut m[i * input..(i + 1) * input];
        match kernel {
            ResizeKernel::Bicubic => {
                let real = scale * (i as f64 + 0.5) - 0.5;
                let floor = real.floor();
                let t = real - floor;
                let weights = [
                    cubic_far(t + 1.0),
                    cubic_near(t),
                    cubic_near(1.0 - t),
                    cubic_far(2.0 - t),
                ];
                for (k, w) in weights.iter().enumerate() {
                    let index = (floor as i64 - 1 + k as i64).clamp(0, input as i64 - 1);
                    row[index as usize] += w;
                }
            }
            ResizeKernel::BilinearAntialias => {
                let taps = antialias_taps_of(triangle_filter, 1.0, input, scale, i);
                row[taps.first..taps.first + taps.weights.len()].copy_from_slice(&taps.weights);
            }
        }
    }
    m.into_iter().map(|w| w as f32).collect()
}

/// `left^T x right` for `x` `[batch, h, w]`, `left` `[h, oh]`, `right` `[w, ow]`.
fn sandwich(x: &Tensor, left: &Tensor, right: &Tensor) -> candle_core::Result<Tensor> {
    let (batch, h, w) = x.dims3()?;
    let (oh, ow) = (left.dim(1)?, right.dim(1)?);
    let cols = checked_matmul(&x.contiguous()?.reshape((batch * h, w))?, right)?
        .reshape((batch, h, ow))?;
    let rows = cols
        .transpose(1, 2)?
        .contiguous()?
        .reshape((batch * ow, h))?;
    checked_matmul(&rows, left)?
        .reshape((batch, ow, oh))?
        .transpose(1, 2)?
        .contiguous()
}

/// A resize of fixed input and output sizes, with its matrices prepared on one device.
#[derive(Clone, Debug)]
pub struct Resize {
    /// `R^T` `[in_h, out_h]` and `C^T` `[in_w, out_w]`, for the forward pass.
    forward: (Tensor, Tensor),
    /// `R` `[out_h, in_h]` and `C` `[out_w, in_w]`, for the backward pass.
    backward: (Tensor, Tensor),
    input: (usize, usize),
    output: (usize, usize),
}

impl Resize {
    /// A resize from `input` (height, width) to `output` (height, width).
    pub fn new(
        kernel: ResizeKernel,
        input: (usize, usize),
        output: (usize, usize),
        device: &Device,
    ) -> Result<Self> {
        if input.0 == 0 || input.1 == 0 || output.0 == 0 || output.1 == 0 {
            return Err(StyleLossError::Input {
                name: "resize sizes".into(),
                reason: format!("input {input:?} and output {output:?} must be non-empty"),
            });
        }
        let rows = Tensor::from_vec(
            resize_matrix(kernel, input.0, output.0),
            (output.0, input.0),
            device,
        )?;
        let cols = Tensor::from_vec(
            resize_matrix(kernel, input.1, output.1),
            (output.1, input.1),
            device,
        )?;
        crate::transfers::record_upload(4 * output.0 * input.0);
        crate::transfers::record_upload(4 * output.1 * input.1);
        Ok(Self {
            forward: (rows.t()?.contiguous()?, cols.t()?.contiguous()?),
            backward: (rows, cols),
            input,
            output,
        })
    }

    /// Resizes `[n, c, in_h, in_w]` to `[n, c, out_h, out_w]`, differentiably.
    pub fn apply(&self, images: &Tensor) -> Result<Tensor> {
        let (n, c, h, w) = images.dims4()?;
        if (h, w) != self.input {
            return Err(StyleLossError::Input {
                name: "images".into(),
                reason: format!("size {h}x{w}, this resize takes {:?}", self.input),
            });
        }
        if self.input == self.output {
            // Both kernels interpolate at the pixel centres themselves: the identity.
            return Ok(images.clone());
        }
        let flat = images.reshape((n * c, h, w))?;
        let value = sandwich(&flat.detach(), &self.forward.0, &self.forward.1)?;
        let (rows, cols) = self.backward.clone();
        let out = attach_input_gradient(&value, &flat, move |g| sandwich(g, &rows, &cols))?;
        Ok(out.reshape((n, c, self.output.0, self.output.1))?)
    }
}

/// Resizes `[n, c, h, w]` to `[n, c, out_h, out_w]` with `kernel` ([`Resize::cached`]).
pub fn resize(images: &Tensor, output: (usize, usize), kernel: ResizeKernel) -> Result<Tensor> {
    let (_, _, h, w) = images.dims4()?;
    Resize::cached(kernel, (h, w), output, images.device())?.apply(images)
}

/// The resizes a process made, with the device their matrices are on: a step makes the same
/// few (the patches' and CLIP's input), so their matrices are built and uploaded once, not every
/// step. Bounded: the oldest goes when it holds [`CACHED_RESIZES`].
type ResizeCache = Vec<(ResizeKernel, Device, Resize)>;

/// How many resizes [`Resize::cached`] keeps.
const CACHED_RESIZES: usize = 16;

static RESIZES: std::sync::Mutex<ResizeCache> = std::sync::Mutex::new(Vec::new());

impl Resize {
    /// [`Resize::new`], the matrices built and uploaded once per kernel, sizes and device in a
    /// process (later calls clone the cached tensors, which share their storage).
    pub fn cached(
        kernel: ResizeKernel,
        input: (usize, usize),
        output: (usize, usize),
        device: &Device,
    ) -> Result<Self> {
        let mut cache = RESIZES
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        let hit = cache.iter().find(|(k, d, r)| {
            *k == kernel && r.input == input && r.output == output && d.same_device(device)
        });
        if let Some((_, _, resize)) = hit {
            return Ok(resize.clone());
        }
        let resize = Self::new(kernel, input, output, device)?;
        if cache.len() >= CACHED_RESIZES {
            cache.remove(0);
        }
        cache.push((kernel, device.clone(), resize.clone()));
        Ok(resize)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cached_resizes_share_their_matrices_and_resize_alike() {
        let device = Device::Cpu;
        let kernel = ResizeKernel::Bicubic;
        let a = Resize::cached(kernel, (13, 17), (7, 9), &device).unwrap();
        let b = Resize::cached(kernel, (13, 17), (7, 9), &device).unwrap();
        // The same tensors (no second build or upload), for the forward and the backward.
        assert_eq!(a.forward.0.id(), b.forward.0.id());
        assert_eq!(a.backward.1.id(), b.backward.1.id());
        let other = Resize::cached(kernel, (13, 17), (7, 10), &device).unwrap();
        assert_ne!(other.forward.1.id(), a.forward.1.id());
        let bilinear =
            Resize::cached(ResizeKernel::BilinearAntialias, (13, 17), (7, 9), &device).unwrap();
        assert_ne!(bilinear.forward.0.id(), a.forward.0.id());
        let image = Tensor::rand(0f32, 1f32, (1, 3, 13, 17), &device).unwrap();
        let fresh = Resize::new(kernel, (13, 17), (7, 9), &device).unwrap();
        let (x, y) = (
            a.apply(&image)
                .unwrap()
                .flatten_all()
                .unwrap()
                .to_vec1::<f32>()
                .unwrap(),
            fresh
                .apply(&image)
                .unwrap()
                .flatten_all()
                .unwrap()
                .to_vec1::<f32>()
                .unwrap(),
        );
        assert_eq!(x, y);
    }
}
