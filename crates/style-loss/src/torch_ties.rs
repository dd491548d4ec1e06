//! Ops on the image -> loss path whose gradient follows PyTorch's convention at ties and exact
//! zeros, where candle's own backward differs:
//!
//! - 2x2 max pooling gives a window's gradient to its first maximum in row-major order
//!   (PyTorch's `max_pool2d`); candle's `max` gives it to every element equal to the maximum.
//!   One CPU kernel serves channels-last tensors and, viewed as `[n c, h, w, 1]`, channels-first
//!   ones.
//! - `|x|` has gradient `sign(x)`, 0 at `x = 0` (PyTorch's `abs`); candle's gives 1.
//!
//! The ReLU after each VGG convolution (gradient 0 at 0, PyTorch's `threshold_backward`) is
//! fused into the convolution's backward in the `vgg` and `vgg_channels_last` modules.

use candle_core::{CpuStorage, CustomOp1, CustomOp2, Layout, Shape, Tensor};
use rayon::prelude::*;

use crate::cpu_elements::{elements, is_cpu_f32};
use crate::custom_grad::attach_input_gradient;

/// 2x2 max pool, stride 2, of `x` `[n, c, h, w]`, dropping a last odd row or column (PyTorch's
/// floor mode). As PyTorch's `max_pool2d`, a window holding a NaN gives NaN, and the gradient of
/// each window goes to its first maximum in row-major order (to its last NaN where it holds
/// one): on the cpu in one pass ([`route_to_first_maximum`]), on other devices with candle's
/// pooling and upsampling kernels (`route_with_tensor_ops`).
pub fn max_pool_2x2(x: &Tensor) -> candle_core::Result<Tensor> {
    let input = x.detach();
    let value = pooled_with_nans(&input)?;
    let pooled = value.clone();
    attach_input_gradient(&value, x, move |g| {
        if is_cpu_f32(&input) {
            route_to_first_maximum(&input, g)
        } else {
            route_with_tensor_ops(&input, &pooled, g)
        }
    })
}

/// `x` `[n, c, h, w]` cut to even sides `[n, c, 2 (h / 2), 2 (w / 2)]`.
fn even_sides(x: &Tensor) -> candle_core::Result<Tensor> {
    let (_, _, h, w) = x.dims4()?;
    x.narrow(2, 0, h / 2 * 2)?.narrow(3, 0, w / 2 * 2)
}

/// The 2x2 maxima of `x` `[n, c, h, w]`, NaN where a window holds a NaN (candle's pooling
/// skips NaNs on a GPU and keeps a leading one on the cpu; PyTorch's returns it).
fn pooled_with_nans(x: &Tensor) -> candle_core::Result<Tensor> {
    let x = even_sides(x)?;
    let maxima = x.max_pool2d(2)?;
    let holds_nan = x.ne(&x)?.max_pool2d(2)?;
    let nan = Tensor::full(f32::NAN, maxima.shape(), x.device())?.to_dtype(x.dtype())?;
    holds_nan.where_cond(&nan, &maxima)
}

/// [`route_to_first_maximum`] with candle's pooling, upsampling and elementwise kernels, on any
/// device, given `pooled`, the forward's [`pooled_with_nans`] of `x`. Each element of a window
/// gets a rank, the highest for the element PyTorch picks: among the elements equal to the
/// window's maximum, 4, 3, 2, 1 in row-major order; in a window holding a NaN, among its NaNs,
/// 1, 2, 3, 4. The window's gradient goes where the rank equals the window's largest rank.
fn route_with_tensor_ops(x: &Tensor, pooled: &Tensor, g: &Tensor) -> candle_core::Result<Tensor> {
    let (_, _, h, w) = x.dims4()?;
    let x = even_sides(x)?;
    let (n, c, h_even, w_even) = x.dims4()?;
    let spread = |t: &Tensor| t.upsample_nearest2d(h_even, w_even);
    // `mask` (1 where an element is a candidate) times each window's ranks, in row-major
    // window order: one broadcast product over the windows' view `[n, c, h / 2, 2, w / 2, 2]`.
    let ranked = |mask: &Tensor, ranks: [f32; 4]| {
        let ranks =
            Tensor::from_slice(&ranks, vec![1, 1, 1, 2, 1, 2], x.device())?.to_dtype(x.dtype())?;
        mask.to_dtype(x.dtype())?
            .reshape(vec![n, c, h_even / 2, 2, w_even / 2, 2])?
            .broadcast_mul(&ranks)?
            .reshape((n, c, h_even, w_even))
    };
    // Each window's value over its elements: NaN exactly where the window holds a NaN.
    let window_value = spread(pooled)?;
    let is_max = x.eq(&window_value)?;
    let is_nan = x.ne(&x)?;
    let window_nan = window_value.ne(&window_value)?;
    let rank = window_nan.where_cond(
        &ranked(&is_nan, [1.0, 2.0, 3.0, 4.0])?,
        &ranked(&is_max, [4.0, 3.0, 2.0, 1.0])?,
    )?;
    let taken = rank.eq(&spread(&rank.max_pool2d(2)?)?)?;
    let routed = taken.to_dtype(g.dtype())?.mul(&spread(&g.contiguous()?)?)?;
    routed
        .pad_with_zeros(2, 0, h - h_even)?
        .pad_with_zeros(3, 0, w - w_even)
}

/// The gradient of a 2x2 max pool of `x` (`[n, c, h, w]`, f32 on the cpu) given `g`, the
/// gradient of its output (`[n, c, h / 2, w / 2]`): each window's value goes to the element
/// PyTorch's `max_pool2d` picks (its first maximum); the rest, and a dropped last odd row or
/// column, get 0.
pub fn route_to_first_maximum(x: &Tensor, g: &Tensor) -> candle_core::Result<Tensor> {
    let (n, c, h, w) = x.dims4()?;
    let (h2, w2) = (h / 2, w / 2);
    if g.dims() != [n, c, h2, w2] {
        candle_core::bail!(
            "max-pool backward: input {:?}, gradient {:?}",
            x.dims(),
            g.dims()
        )
    }
    // In memory, channels-first `[n, c, h, w]` is channels-last `[n c, h, w, 1]`.
    let x = x.contiguous()?.reshape((n * c, h, w, 1))?;
    let g = g.contiguous()?.reshape((n * c, h2, w2, 1))?;
    x.apply_op2_no_bwd(&g, &MaxPoolChannelsLast)?
        .reshape((n, c, h, w))
}

/// The element of `window` (indices into `x`, in row-major window order) that PyTorch's
/// `max_pool2d` picks: scanning from a maximum of `-inf`, an element is taken when it is greater
/// than the maximum so far or NaN (so the last NaN wins; an all `-inf` window gives its first).
fn first_maximum(x: &[f32], window: [usize; 4]) -> usize {
    let mut best = window[0];
    let mut max = f32::NEG_INFINITY;
    for k in window {
        if x[k] > max || x[k].is_nan() {
            max = x[k];
            best = k;
        }
    }
    best
}

/// 2x2 max pool, stride 2, of `x` `[n, h, w, c]`, dropping a last odd row or column (PyTorch's
/// floor mode). Each window's value and gradient are those of its first element that is
/// greater than all before it or NaN, in row-major order, as PyTorch's `max_pool2d`.
pub(crate) fn max_pool_2x2_channels_last(x: &Tensor) -> candle_core::Result<Tensor> {
    x.contiguous()?.apply_op1(MaxPoolChannelsLast)
}

/// The indices of the 2x2 window whose top-left element is at `top` (row length `row`,
/// `c` channels), in row-major order.
fn window(top: usize, row: usize, c: usize) -> [usize; 4] {
    [top, top + c, top + row, top + row + c]
}

/// The pool as a candle op: `apply_op1` pools (its backward routes the gradient),
/// `apply_op2(gradient)` routes the gradient of the pooled output back to the input's shape.
struct MaxPoolChannelsLast;

impl CustomOp1 for MaxPoolChannelsLast {
    fn name(&self) -> &'static str {
        "max-pool-2x2-channels-last"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let (n, h, w, c) = l.shape().dims4()?;
        let x = elements(s, l)?;
        let (h2, w2) = (h / 2, w / 2);
        let mut out = vec![0f32; n * h2 * w2 * c];
        out.par_chunks_mut(w2 * c.max(1))
            .enumerate()
            .for_each(|(r, out_row)| {
                let (image, i) = (r / h2, r % h2);
                for j in 0..w2 {
                    for ch in 0..c {
                        let top = ((image * h + 2 * i) * w + 2 * j) * c + ch;
                        out_row[j * c + ch] = x[first_maximum(x, window(top, w * c, c))];
                    }
                }
            });
        Ok((CpuStorage::F32(out), Shape::from((n, h2, w2, c))))
    }

    fn bwd(
        &self,
        x: &Tensor,
        _pooled: &Tensor,
        grad: &Tensor,
    ) -> candle_core::Result<Option<Tensor>> {
        Ok(Some(x.apply_op2_no_bwd(
            &grad.contiguous()?,
            &MaxPoolChannelsLast,
        )?))
    }
}

impl CustomOp2 for MaxPoolChannelsLast {
    fn name(&self) -> &'static str {
        "max-pool-2x2-channels-last-backward"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let (n, h, w, c) = l1.shape().dims4()?;
        let (h2, w2) = (h / 2, w / 2);
        if l2.shape().dims() != [n, h2, w2, c] {
            candle_core::bail!("max-pool backward: input {l1:?}, gradient {l2:?}")
        }
        let x = elements(s1, l1)?;
        let g = elements(s2, l2)?;
        let mut out = vec![0f32; n * h * w * c];
        let image_len = (h * w * c).max(1);
        let pair_len = (2 * w * c).max(1);
        out.par_chunks_mut(image_len)
            .enumerate()
            .for_each(|(image, image_out)| {
                // Each task owns one window row (two input rows); an odd last row stays 0.
                image_out
                    .par_chunks_mut(pair_len)
                    .take(h2)
                    .enumerate()
                    .for_each(|(i, rows)| {
                        let base = (image * h + 2 * i) * w * c;
                        for j in 0..w2 {
                            for ch in 0..c {
                                let top = base + 2 * j * c + ch;
                                let best = first_maximum(x, window(top, w * c, c));
                                rows[best - base] = g[((image * h2 + i) * w2 + j) * c + ch];
                            }
                        }
                    });
            });
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

    /// `[2, 3, h, w]` values from {0, 1, 2}, so that most windows tie, with NaN, -inf and +inf
    /// mixed in when `special`.
    fn tied_values(h: usize, w: usize, special: bool) -> Tensor {
        let x: Vec<f32> = (0..2 * 3 * h * w)
            .map(|i| match ((i * 7 + i / 5) % 13, special) {
                (10, true) => f32::NAN,
                (11, true) => f32::NEG_INFINITY,
                (12, true) => f32::INFINITY,
                (k, _) => (k % 3) as f32,
            })
            .collect();
        Tensor::from_vec(x, (2, 3, h, w), &Device::Cpu).unwrap()
    }

    /// For `x` `[n, c, h, w]`, the element of each 2x2 window, in window order, that
    /// [`route_to_first_maximum`] gives the window's gradient to (checking that it gives it to
    /// exactly one).
    pub(super) fn routed_elements(x: &Tensor) -> Vec<f32> {
        let (n, c, h, w) = x.dims4().unwrap();
        let ones = Tensor::ones((n, c, h / 2, w / 2), x.dtype(), x.device()).unwrap();
        let routed = route_to_first_maximum(x, &ones).unwrap();
        let routed = routed.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let x = x.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let mut chosen = Vec::new();
        for plane in 0..n * c {
            for i in 0..h / 2 {
                for j in 0..w / 2 {
                    let top = plane * h * w + 2 * i * w + 2 * j;
                    let taken: Vec<usize> = [top, top + 1, top + w, top + w + 1]
                        .into_iter()
                        .filter(|&k| routed[k] == 1.0)
                        .collect();
                    assert_eq!(taken.len(), 1);
                    chosen.push(x[taken[0]]);
                }
            }
        }
        chosen
    }

    #[test]
    fn the_cpu_kernel_and_the_tensor_ops_route_alike() {
        for (h, w) in [(6, 8), (7, 5), (2, 3), (9, 9)] {
            for special in [false, true] {
                let x = tied_values(h, w, special);
                let g = Tensor::rand(-1f32, 1f32, (2, 3, h / 2, w / 2), &Device::Cpu).unwrap();
                let kernel = route_to_first_maximum(&x, &g).unwrap();
                let pooled = pooled_with_nans(&x).unwrap();
                let ops = route_with_tensor_ops(&x, &pooled, &g).unwrap();
                assert_eq!(
                    kernel.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
                    ops.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
                    "{h}x{w}, special values {special}"
                );
            }
        }
    }

    #[test]
    fn pooled_values_are_the_routed_elements_nan_included() {
        for (h, w) in [(6, 8), (7, 5), (9, 9)] {
            let x = tied_values(h, w, true);
            let pooled = max_pool_2x2(&x).unwrap();
            let pooled = pooled.flatten_all().unwrap().to_vec1::<f32>().unwrap();
            let chosen = routed_elements(&x);
            assert_eq!(pooled.len(), chosen.len());
            let nans = pooled.iter().filter(|p| p.is_nan()).count();
            assert!(
                nans > 0 && nans < pooled.len(),
                "{h}x{w}: {nans} NaN windows"
            );
            for (p, e) in pooled.iter().zip(&chosen) {
                assert!(p == e || p.is_nan() && e.is_nan(), "{h}x{w}: {p} vs {e}");
            }
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

#[cfg(test)]
mod channels_last_tests {
    use candle_core::{Device, Tensor, Var};

    use super::*;

    /// `d sum(pool(x) * probe) / dx` and `pool(x)`, channels-last, for `x` `[n, h, w, c]`.
    fn pool_and_gradient(x: &Tensor, probe: &Tensor) -> (Tensor, Tensor) {
        let var = Var::from_tensor(x).unwrap();
        let y = max_pool_2x2_channels_last(var.as_tensor()).unwrap();
        let grads = (&y * probe).unwrap().sum_all().unwrap().backward().unwrap();
        (y, grads.get(var.as_tensor()).unwrap().clone())
    }

    #[test]
    fn pooling_matches_the_channels_first_pytorch_rule() {
        let device = Device::Cpu;
        for (n, h, w, c) in [(2, 6, 8, 3), (1, 7, 5, 4), (3, 2, 3, 1)] {
            // Values from {0, 1, 2} with NaNs and -inf mixed in: ties in most windows.
            let x: Vec<f32> = (0..n * h * w * c)
                .map(|i| match (i * 7 + i / 5) % 11 {
                    9 => f32::NAN,
                    10 => f32::NEG_INFINITY,
                    k => (k % 3) as f32,
                })
                .collect();
            let x = Tensor::from_vec(x, (n, h, w, c), &device).unwrap();
            let probe = Tensor::rand(-1f32, 1f32, (n, h / 2, w / 2, c), &device).unwrap();
            let (pooled, grad) = pool_and_gradient(&x, &probe);
            let first = |t: &Tensor| t.permute((0, 3, 1, 2)).unwrap().contiguous().unwrap();
            let expected_grad = route_to_first_maximum(&first(&x), &first(&probe)).unwrap();
            let grad = first(&grad)
                .flatten_all()
                .unwrap()
                .to_vec1::<f32>()
                .unwrap();
            assert_eq!(
                grad,
                expected_grad
                    .flatten_all()
                    .unwrap()
                    .to_vec1::<f32>()
                    .unwrap()
            );
            // Each value is the element its window's gradient went to (NaN where that is NaN).
            let chosen = super::tests::routed_elements(&first(&x));
            let pooled = first(&pooled)
                .flatten_all()
                .unwrap()
                .to_vec1::<f32>()
                .unwrap();
            assert_eq!(pooled.len(), chosen.len());
            for (p, e) in pooled.iter().zip(&chosen) {
                assert!(p == e || p.is_nan() && e.is_nan(), "{p} vs {e}");
            }
        }
    }

    #[test]
    fn an_all_negative_infinite_window_routes_to_its_first_element() {
        let x = Tensor::full(f32::NEG_INFINITY, (1, 2, 2, 1), &Device::Cpu).unwrap();
        let probe = Tensor::ones((1, 1, 1, 1), candle_core::DType::F32, &Device::Cpu).unwrap();
        let (pooled, grad) = pool_and_gradient(&x, &probe);
        assert_eq!(
            pooled.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
            [f32::NEG_INFINITY]
        );
        assert_eq!(
            grad.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
            [1.0, 0.0, 0.0, 0.0]
        );
    }
}
