//! VGG's layers on the CPU in channels-last layout (`[n, h, w, c]`), where a 3x3 convolution is
//! three matrix products (the `conv3x3` module) instead of candle's im2col convolution: the
//! convolution + ReLU and the 2x2 max pool, as candle ops with input-only gradients that follow
//! PyTorch at ties and exact zeros (as the channels-first ops in `vgg` and `torch_ties`).

use std::sync::{Arc, Mutex};

use candle_core::{CpuStorage, CustomOp1, CustomOp2, Layout, Shape, Tensor};
use rayon::prelude::*;

use crate::conv3x3::{conv3x3, Epilogue, ImageShape, PackedKernel};

/// The padded-image buffer the convolutions of one network share (forward and backward run
/// one at a time; a clone of the network shares it).
pub(crate) type Scratch = Arc<Mutex<Vec<f32>>>;

/// A 3x3 convolution, padding 1, then ReLU, on channels-last f32 CPU tensors.
#[derive(Clone, Debug)]
pub(crate) struct ConvReluChannelsLast {
    kernel: Arc<PackedKernel>,
    adjoint: Arc<PackedKernel>,
    bias: Arc<Vec<f32>>,
}

impl ConvReluChannelsLast {
    /// From PyTorch weights `[cout, cin, 3, 3]` and bias `[cout]`.
    pub(crate) fn new(weight: &Tensor, bias: &Tensor) -> candle_core::Result<Self> {
        let (cout, cin, _, _) = weight.dims4()?;
        let w = weight.flatten_all()?.to_vec1::<f32>()?;
        Ok(Self {
            kernel: Arc::new(PackedKernel::forward(&w, cout, cin)),
            adjoint: Arc::new(PackedKernel::adjoint(&w, cout, cin)),
            bias: Arc::new(bias.flatten_all()?.to_vec1::<f32>()?),
        })
    }

    /// `relu(conv(x) + bias)` of `x` `[n, h, w, cin]`. The input gradient is the adjoint
    /// convolution of the upstream gradient where the output is not `<= 0` (PyTorch's ReLU:
    /// 0 at an exact 0).
    pub(crate) fn forward(&self, x: &Tensor, scratch: &Scratch) -> candle_core::Result<Tensor> {
        x.contiguous()?.apply_op1(ConvOp {
            kernel: self.kernel.clone(),
            epilogue_bias: Some(self.bias.clone()),
            adjoint: Some(self.adjoint.clone()),
            scratch: scratch.clone(),
        })
    }
}

/// The convolution as a candle op: `apply_op1` convolves (its backward is the `adjoint`
/// convolution of the gradient gated by the output), `apply_op2(gate)` convolves the input
/// gated by the second operand.
struct ConvOp {
    kernel: Arc<PackedKernel>,
    epilogue_bias: Option<Arc<Vec<f32>>>,
    adjoint: Option<Arc<PackedKernel>>,
    scratch: Scratch,
}

impl ConvOp {
    fn run(
        &self,
        input: (&CpuStorage, &Layout),
        gate: Option<(&CpuStorage, &Layout)>,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let (storage, layout) = input;
        let (images, h, w, cin) = layout.shape().dims4()?;
        if cin != self.kernel.cin() || !layout.is_contiguous() {
            candle_core::bail!(
                "conv3x3: input {layout:?}, kernel from {} channels",
                self.kernel.cin()
            )
        }
        let data = contiguous_slice(storage, layout)?;
        let gate = match gate {
            Some((s, l)) if l.shape() == layout.shape() && l.is_contiguous() => {
                Some(contiguous_slice(s, l)?)
            }
            Some((_, l)) => candle_core::bail!("conv3x3: gate {l:?} for input {layout:?}"),
            None => None,
        };
        let epilogue = match &self.epilogue_bias {
            Some(bias) => Epilogue::BiasRelu(bias),
            None => Epilogue::Identity,
        };
        let mut scratch = self
            .scratch
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        let out = conv3x3(
            data,
            ImageShape { images, h, w },
            &self.kernel,
            gate,
            epilogue,
            &mut scratch,
        );
        Ok((
            CpuStorage::F32(out),
            Shape::from((images, h, w, self.kernel.cout())),
        ))
    }
}

impl CustomOp1 for ConvOp {
    fn name(&self) -> &'static str {
        "conv3x3-channels-last"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        self.run((s, l), None)
    }

    fn bwd(
        &self,
        _x: &Tensor,
        output: &Tensor,
        grad: &Tensor,
    ) -> candle_core::Result<Option<Tensor>> {
        let Some(adjoint) = &self.adjoint else {
            candle_core::bail!("conv3x3: this convolution has no adjoint")
        };
        let adjoint = ConvOp {
            kernel: adjoint.clone(),
            epilogue_bias: None,
            adjoint: None,
            scratch: self.scratch.clone(),
        };
        Ok(Some(grad.contiguous()?.apply_op2_no_bwd(output, &adjoint)?))
    }
}

impl CustomOp2 for ConvOp {
    fn name(&self) -> &'static str {
        "conv3x3-channels-last-gated"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        self.run((s1, l1), Some((s2, l2)))
    }
}

/// The elements of a contiguous f32 tensor.
fn contiguous_slice<'a>(
    storage: &'a CpuStorage,
    layout: &Layout,
) -> candle_core::Result<&'a [f32]> {
    let start = layout.start_offset();
    Ok(&storage.as_slice::<f32>()?[start..start + layout.shape().elem_count()])
}

/// 2x2 max pool, stride 2, of `x` `[n, h, w, c]`, dropping a last odd row or column (PyTorch's
/// floor mode). Each window's value and gradient are those of its first element that is
/// greater than all before it or NaN, in row-major order, as PyTorch's `max_pool2d`.
pub(crate) fn max_pool_2x2(x: &Tensor) -> candle_core::Result<Tensor> {
    x.contiguous()?.apply_op1(MaxPool)
}

/// The pool as a candle op: `apply_op1` pools (its backward routes the gradient),
/// `apply_op2(gradient)` routes the gradient of the pooled output back to the input's shape.
struct MaxPool;

/// Offset of the chosen element of the window whose top-left element is at `top` (row length
/// `row`, `c` channels), by PyTorch's rule: scanning in row-major order from a maximum of
/// `-inf`, an element is taken when it is greater than the maximum so far or NaN.
fn first_maximum(x: &[f32], top: usize, row: usize, c: usize) -> usize {
    let mut best = top;
    let mut max = f32::NEG_INFINITY;
    for k in [top, top + c, top + row, top + row + c] {
        if x[k] > max || x[k].is_nan() {
            max = x[k];
            best = k;
        }
    }
    best
}

impl CustomOp1 for MaxPool {
    fn name(&self) -> &'static str {
        "max-pool-2x2-channels-last"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let (n, h, w, c) = l.shape().dims4()?;
        let x = contiguous_slice(s, l)?;
        let (h2, w2) = (h / 2, w / 2);
        let mut out = vec![0f32; n * h2 * w2 * c];
        out.par_chunks_mut(w2 * c.max(1))
            .enumerate()
            .for_each(|(r, out_row)| {
                let (image, i) = (r / h2, r % h2);
                for j in 0..w2 {
                    for ch in 0..c {
                        let top = ((image * h + 2 * i) * w + 2 * j) * c + ch;
                        out_row[j * c + ch] = x[first_maximum(x, top, w * c, c)];
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
        Ok(Some(x.apply_op2_no_bwd(&grad.contiguous()?, &MaxPool)?))
    }
}

impl CustomOp2 for MaxPool {
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
        let x = contiguous_slice(s1, l1)?;
        let g = contiguous_slice(s2, l2)?;
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
                                let best = first_maximum(x, top, w * c, c);
                                rows[best - base] = g[((image * h2 + i) * w2 + j) * c + ch];
                            }
                        }
                    });
            });
        Ok((CpuStorage::F32(out), l1.shape().clone()))
    }
}

#[cfg(test)]
mod tests {
    use candle_core::{Device, Tensor, Var};

    use super::*;
    use crate::torch_ties;

    /// `d sum(pool(x) * probe) / dx` and `pool(x)`, channels-last, for `x` `[n, h, w, c]`.
    fn pool_and_gradient(x: &Tensor, probe: &Tensor) -> (Tensor, Tensor) {
        let var = Var::from_tensor(x).unwrap();
        let y = max_pool_2x2(var.as_tensor()).unwrap();
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
            let expected_grad =
                torch_ties::route_to_first_maximum(&first(&x), &first(&probe)).unwrap();
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
            let ones =
                Tensor::ones((n, c, h / 2, w / 2), candle_core::DType::F32, &device).unwrap();
            let routed = torch_ties::route_to_first_maximum(&first(&x), &ones).unwrap();
            let routed = routed.flatten_all().unwrap().to_vec1::<f32>().unwrap();
            let x_first = first(&x).flatten_all().unwrap().to_vec1::<f32>().unwrap();
            let (h2, w2) = (h / 2, w / 2);
            let mut chosen = Vec::new();
            for plane in 0..n * c {
                for i in 0..h2 {
                    for j in 0..w2 {
                        let top = plane * h * w + 2 * i * w + 2 * j;
                        let taken: Vec<usize> = [top, top + 1, top + w, top + w + 1]
                            .into_iter()
                            .filter(|&k| routed[k] == 1.0)
                            .collect();
                        assert_eq!(taken.len(), 1);
                        chosen.push(x_first[taken[0]]);
                    }
                }
            }
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
