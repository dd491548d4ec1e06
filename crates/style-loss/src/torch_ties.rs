//! Ops on the image -> loss path whose gradient follows PyTorch's convention at ties and exact
//! zeros, where candle's own backward differs:
//!
//! - 2x2 max pooling gives a window's gradient to its first maximum in row-major order
//!   (PyTorch's `max_pool2d`); candle's `max` gives it to every element equal to the maximum.
//! - `|x|` has gradient `sign(x)`, 0 at `x = 0` (PyTorch's `abs`); candle's gives 1.
//!
//! The ReLU after each VGG convolution (gradient 0 at 0, PyTorch's `threshold_backward`) is
//! fused into the convolution's backward in the `vgg` module.

use candle_core::{CpuStorage, CustomOp2, DType, Layout, Shape, Tensor};

use crate::custom_grad::attach_input_gradient;

/// 2x2 max pool, stride 2, dropping a last odd row or column (PyTorch's floor mode). The
/// gradient of each window goes to its first maximum in row-major order, as in PyTorch: on the
/// cpu in one pass ([`route_to_first_maximum`], which also follows PyTorch at NaN), on other
/// devices with tensor ops, where a window whose maximum is NaN passes no gradient.
pub fn max_pool_2x2(x: &Tensor) -> candle_core::Result<Tensor> {
    let (n, c, h, w) = x.dims4()?;
    let value = windows(x)?
        .max_keepdim(5)?
        .max_keepdim(3)?
        .reshape((n, c, h / 2, w / 2))?;
    let input = x.detach();
    attach_input_gradient(&value, x, move |g| {
        if input.device().is_cpu() && input.dtype() == DType::F32 {
            route_to_first_maximum(&input, g)
        } else {
            route_with_tensor_ops(&input, g)
        }
    })
}

/// `x` (`[n, c, h, w]`, detached) as its 2x2 windows `[n, c, h / 2, 2, w / 2, 2]`, a last odd
/// row or column dropped.
fn windows(x: &Tensor) -> candle_core::Result<Tensor> {
    let (n, c, h, w) = x.dims4()?;
    let (h2, w2) = (h / 2, w / 2);
    x.detach()
        .narrow(2, 0, 2 * h2)?
        .narrow(3, 0, 2 * w2)?
        .reshape(vec![n, c, h2, 2, w2, 2])
}

/// [`route_to_first_maximum`] with tensor ops, on any device (a window whose maximum is NaN
/// passes nothing).
fn route_with_tensor_ops(x: &Tensor, g: &Tensor) -> candle_core::Result<Tensor> {
    let (n, c, h, w) = x.dims4()?;
    let (h2, w2) = (h / 2, w / 2);
    let windows = windows(x)?;
    let pooled = windows.max_keepdim(5)?.max_keepdim(3)?;
    let g = g.reshape(vec![n, c, h2, 1, w2, 1])?;
    let routed = first_maximum_mask(&windows, &pooled)?
        .broadcast_mul(&g)?
        .reshape((n, c, 2 * h2, 2 * w2))?;
    routed
        .pad_with_zeros(2, 0, h - 2 * h2)?
        .pad_with_zeros(3, 0, w - 2 * w2)
}

/// `[n, c, h2, 2, w2, 2]` with 1 at the first element of each window (row-major in the
/// window: (0,0), (0,1), (1,0), (1,1)) equal to the window's maximum `pooled`
/// (`[n, c, h2, 1, w2, 1]`), 0 elsewhere.
fn first_maximum_mask(windows: &Tensor, pooled: &Tensor) -> candle_core::Result<Tensor> {
    let mut taken: Option<Tensor> = None;
    let mut rows = Vec::with_capacity(2);
    for dy in 0..2 {
        let mut row = Vec::with_capacity(2);
        for dx in 0..2 {
            let is_max = windows
                .narrow(3, dy, 1)?
                .narrow(5, dx, 1)?
                .broadcast_eq(pooled)?
                .to_dtype(windows.dtype())?;
            let first = match &taken {
                Some(t) => (&is_max * t.affine(-1.0, 1.0)?)?,
                None => is_max.clone(),
            };
            taken = Some(match taken {
                Some(t) => t.maximum(&is_max)?,
                None => is_max,
            });
            row.push(first);
        }
        rows.push(Tensor::cat(&row, 5)?);
    }
    Tensor::cat(&rows, 3)
}

/// The gradient of a 2x2 max pool of `x` (`[n, c, h, w]`, f32 on the cpu) given `g`, the
/// gradient of its output (`[n, c, h / 2, w / 2]`): each window's value goes to the element
/// PyTorch's `max_pool2d` picks, the first one greater than all before it or NaN, in
/// row-major order; the rest, and a dropped last odd row or column, get 0.
pub fn route_to_first_maximum(x: &Tensor, g: &Tensor) -> candle_core::Result<Tensor> {
    x.contiguous()?
        .apply_op2_no_bwd(&g.contiguous()?, &FirstMaximumRoute)
}

/// See [`route_to_first_maximum`].
struct FirstMaximumRoute;

impl CustomOp2 for FirstMaximumRoute {
    fn name(&self) -> &'static str {
        "max-pool-2x2-backward"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let (n, c, h, w) = l1.shape().dims4()?;
        let (h2, w2) = (h / 2, w / 2);
        if l2.shape().dims() != [n, c, h2, w2] || !l1.is_contiguous() || !l2.is_contiguous() {
            candle_core::bail!("max-pool backward: input {l1:?}, gradient {l2:?}")
        }
        let x = &s1.as_slice::<f32>()?[l1.start_offset()..];
        let g = &s2.as_slice::<f32>()?[l2.start_offset()..];
        let mut out = vec![0f32; n * c * h * w];
        for plane in 0..n * c {
            let (xp, op) = (plane * h * w, plane * h * w);
            for i in 0..h2 {
                for j in 0..w2 {
                    let top = xp + 2 * i * w + 2 * j;
                    let mut best = top;
                    let mut max = f32::NEG_INFINITY;
                    for k in [top, top + 1, top + w, top + w + 1] {
                        if x[k] > max || x[k].is_nan() {
                            max = x[k];
                            best = k;
                        }
                    }
                    out[op + (best - xp)] = g[plane * h2 * w2 + i * w2 + j];
                }
            }
        }
        Ok((CpuStorage::F32(out), l1.shape().clone()))
    }
}

/// `|x|` with gradient `sign(x)` (0 at 0), as PyTorch's `abs`.
pub fn abs(x: &Tensor) -> candle_core::Result<Tensor> {
    x.mul(&x.sign()?.detach())
}

#[cfg(test)]
mod tests {
    use candle_core::{Device, Tensor, Var};

    use super::*;

    fn grad_of(
        x: &[f32],
        dims: (usize, usize, usize, usize),
        f: impl Fn(&Tensor) -> Tensor,
    ) -> Vec<f32> {
        let var = Var::from_tensor(&Tensor::from_slice(x, dims, &Device::Cpu).unwrap()).unwrap();
        let y = f(var.as_tensor());
        let grads = y.sum_all().unwrap().backward().unwrap();
        grads
            .get(var.as_tensor())
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1()
            .unwrap()
    }

    #[test]
    fn pooling_routes_each_window_to_its_first_maximum() {
        // 3x5: windows [[1,1],[1,1]] (all tied), [[0,2],[2,-1]] (tie at (0,1) and (1,0));
        // the last row and column are dropped (floor mode) and get no gradient.
        #[rustfmt::skip]
        let x = [
            1.0, 1.0, 0.0, 2.0, 9.0,
            1.0, 1.0, 2.0, -1.0, 9.0,
            9.0, 9.0, 9.0, 9.0, 9.0,
        ];
        let pooled =
            max_pool_2x2(&Tensor::from_slice(&x, (1, 1, 3, 5), &Device::Cpu).unwrap()).unwrap();
        assert_eq!(
            pooled.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
            [1.0, 2.0]
        );
        let g = grad_of(&x, (1, 1, 3, 5), |t| max_pool_2x2(t).unwrap());
        #[rustfmt::skip]
        let expected = [
            1.0, 0.0, 0.0, 1.0, 0.0,
            0.0, 0.0, 0.0, 0.0, 0.0,
            0.0, 0.0, 0.0, 0.0, 0.0,
        ];
        assert_eq!(g, expected);
    }

    #[test]
    fn a_negative_infinite_window_still_routes_to_its_first_element() {
        let x = [f32::NEG_INFINITY; 4];
        let g = grad_of(&x, (1, 1, 2, 2), |t| max_pool_2x2(t).unwrap());
        assert_eq!(g, [1.0, 0.0, 0.0, 0.0]);
    }

    #[test]
    fn the_cpu_kernel_and_the_tensor_ops_route_alike() {
        let device = Device::Cpu;
        for (h, w) in [(6, 8), (7, 5)] {
            // Values from {0, 1, 2}: most windows tie somewhere.
            let x: Vec<f32> = (0..2 * 3 * h * w)
                .map(|i| ((i * 7 + i / 5) % 3) as f32)
                .collect();
            let x = Tensor::from_vec(x, (2, 3, h, w), &device).unwrap();
            let g = Tensor::rand(-1f32, 1f32, (2, 3, h / 2, w / 2), &device).unwrap();
            let kernel = route_to_first_maximum(&x, &g).unwrap();
            let ops = route_with_tensor_ops(&x, &g).unwrap();
            let diff = (kernel - ops).unwrap().abs().unwrap().max_all().unwrap();
            assert_eq!(diff.to_scalar::<f32>().unwrap(), 0.0, "{h}x{w}");
        }
    }

    #[test]
    fn the_cpu_kernel_routes_a_nan_window_to_its_nan_as_pytorch() {
        let x = [1.0, f32::NAN, 3.0, 2.0];
        let g = grad_of(&x, (1, 1, 2, 2), |t| max_pool_2x2(t).unwrap());
        assert_eq!(g, [0.0, 1.0, 0.0, 0.0]);
    }

    #[test]
    fn abs_has_zero_gradient_at_zero() {
        let x = [-2.0, 0.0, 3.0, -0.0];
        let g = grad_of(&x, (1, 1, 1, 4), |t| abs(t).unwrap());
        assert_eq!(g, [-1.0, 0.0, 1.0, 0.0]);
        let v = abs(&Tensor::from_slice(&x, 4, &Device::Cpu).unwrap()).unwrap();
        assert_eq!(v.to_vec1::<f32>().unwrap(), [2.0, 0.0, 3.0, 0.0]);
    }
}
