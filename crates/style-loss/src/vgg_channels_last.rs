//! VGG's convolution + ReLU on the CPU in channels-last layout (`[n, h, w, c]`), where a 3x3
//! convolution is three matrix products (the `conv3x3` module) instead of candle's im2col
//! convolution: a candle op with an input-only gradient that follows PyTorch's ReLU at exact
//! zeros (as the channels-first op in `vgg`). Its max pool is `torch_ties::max_pool_2x2_channels_last`.

use std::sync::{Arc, Mutex, OnceLock};

use candle_core::{CpuStorage, CustomOp1, CustomOp2, Layout, Shape, Tensor};

use crate::conv3x3::{conv3x3, Epilogue, ImageShape, PackedKernel};
use crate::conv3x3_bf16::{conv3x3_bf16, StackedKernel};
use crate::conv3x3_winograd::{
    conv3x3_winograd, conv3x3_winograd_exact, ExactWinogradKernel, WinogradKernel, F4X4,
};
use crate::cpu_elements::{elements, same_shape_elements};

/// The padded-image buffer the convolutions of one network share (forward and backward run
/// one at a time; a clone of the network shares it).
pub(crate) type Scratch = Arc<Mutex<Vec<f32>>>;

/// A convolution's kernel in the format its products run in.
#[derive(Clone, Debug)]
enum Kernel {
    /// f32 products (`conv3x3`).
    F32(Arc<PackedKernel>),
    /// bf16 products (`conv3x3_bf16`).
    Bf16(Arc<StackedKernel>),
    /// f32 products of Winograd's F(2x2, 3x3) (`conv3x3_winograd`).
    Winograd(Arc<WinogradKernel>),
    /// f64 transforms and products of Winograd's F(4x4, 3x3), the bias added and the ReLU
    /// decided in f64, each output rounded once, those its error bound leaves open summed
    /// again directly (`conv3x3_winograd_exact`: the exact forward of a layer of
    /// [`KernelWidths::exact_winograd`] channels or more).
    ExactWinograd(Arc<ExactWinogradKernel<F4X4>>),
}

/// Which algorithm a layer's products take, by the layer's width (the fewer of its input and
/// output channels).
#[derive(Clone, Copy, Debug)]
pub(crate) struct KernelWidths {
    /// From this width on, a bf16 backward runs its products in bf16 (its forward then by
    /// Winograd's F(2x2, 3x3) in f32); below it such a layer's forward is the direct f32
    /// convolution and its backward as an f32 backward's.
    pub bf16_backward: usize,
    /// From this width on, a backward in f32 (an f32 one's, and a bf16 one's below
    /// `bf16_backward`) runs by Winograd's F(2x2, 3x3) in f32; below it, directly in f32.
    pub winograd_backward: usize,
    /// From this width on the exact forward (f64 sums, a gradient taken through an f32
    /// backward) runs by F(4x4, 3x3) in f64 (`conv3x3_winograd_exact`); narrower layers sum it
    /// directly in f64.
    pub exact_winograd: usize,
}

/// The widths measured on VGG-19 (docs/benchmarks.md): on layers narrower than 256 channels
/// the bf16 conversions cost more than they saved. F(2x2, 3x3) in f32 beat the direct
/// backward from 64 channels once a layer whose transformed kernel stays in cache ran its bands
/// in parallel (each convolution timed in the content term at 384x384 on a 2-core Zen 3,
/// medians: 384x384 64->64 from 127 to 81 ms, 192x192 128->128 from 100 to 70 ms). In f64,
/// F(4x4, 3x3) (2.25 multiply-adds per output and channel pair, against 4 for F(2x2, 3x3)
/// and 9 directly) with its bound checked beat
/// F(2x2, 3x3) and the direct sums on every layer but the first (3 input channels; timed
/// layer by layer at 384x384 and 800x800 on a 2-core Zen 3). Without the bound it moved the
/// content gradient by 1.8e-2 on `scripts/make_vgg_border_ties_fixture.py`'s cases from the
/// second layer: outputs a hair from 0 beside large ones, told apart by the rounding of their
/// tile's other inputs.
pub(crate) const MEASURED: KernelWidths = KernelWidths {
    bf16_backward: 256,
    winograd_backward: 64,
    exact_winograd: 64,
};

impl Kernel {
    fn cin(&self) -> usize {
        match self {
            Self::F32(k) => k.cin(),
            Self::Bf16(k) => k.cin(),
            Self::Winograd(k) => k.cin(),
            Self::ExactWinograd(k) => k.cin(),
        }
    }

    fn cout(&self) -> usize {
        match self {
            Self::F32(k) => k.cout(),
            Self::Bf16(k) => k.cout(),
            Self::Winograd(k) => k.cout(),
            Self::ExactWinograd(k) => k.cout(),
        }
    }
}

/// A 3x3 convolution, padding 1, then ReLU, on channels-last f32 CPU tensors. Its forward sums
/// are exact (f64, rounded once) with an f32 backward, f32 (direct, or Winograd's where its
/// backward is bf16) with a bf16 one; its backward products (the adjoint on the gradient) f32
/// (direct, or Winograd's from [`KernelWidths::winograd_backward`] channels) or, from
/// [`KernelWidths::bf16_backward`] channels with a bf16 backward, bf16.
#[derive(Clone, Debug)]
pub(crate) struct ConvReluChannelsLast {
    kernel: Kernel,
    adjoint: Kernel,
    bias: Arc<Vec<f32>>,
    /// Whether the backward was asked in bf16 (its forward then decides its ReLUs in f32).
    bf16_backward: bool,
    /// On a layer of [`KernelWidths::exact_winograd`] channels or more with an f32 backward, the
    /// kernel of the exact forward by Winograd's F(4x4, 3x3) in f64, built from `kernel` on the
    /// first forward (9 times the f32 weights' memory, and a copy of them: about 550 MB for
    /// VGG-19 to conv5_2, spent only by runs that take it).
    exact_forward: Option<Arc<OnceLock<Kernel>>>,
}

impl ConvReluChannelsLast {
    /// From PyTorch weights `[cout, cin, 3, 3]` and bias `[cout]`, the algorithms chosen by
    /// `widths` ([`MEASURED`] but in tests). From `widths.bf16_backward` channels,
    /// `bf16_backward` runs the backward products in bf16 and the forward by Winograd's
    /// F(2x2, 3x3) in f32 (2.25 times fewer multiply-adds, errors of the order of an f32 sum's,
    /// far under the bf16 backward's); narrower layers take the direct f32 forward and an f32
    /// backward. A backward in f32 runs by Winograd's F(2x2, 3x3) (it decides nothing, and an
    /// input whose window of gated gradient is all 0 gets exactly 0) from
    /// `widths.winograd_backward` channels, directly on narrower layers. With an f32
    /// backward, every forward gives the direct f64 sums rounded once: by
    /// Winograd's F(4x4, 3x3) in f64, its bound checked, from `widths.exact_winograd`
    /// channels, directly on narrower layers.
    ///
    /// The forward stays f32 in either case: its outputs decide the ReLUs and the max pools,
    /// and outputs rounded to bf16 tie inside pooling windows, which routes the gradient to
    /// another pixel (17 % of the gradient of a small network, against 0.8 % for bf16 in the
    /// backward only).
    pub(crate) fn new(
        weight: &Tensor,
        bias: &Tensor,
        bf16_backward: bool,
        widths: KernelWidths,
    ) -> candle_core::Result<Self> {
        let (cout, cin, _, _) = weight.dims4()?;
        let w = weight.flatten_all()?.to_vec1::<f32>()?;
        let width = cin.min(cout);
        let bf16_layer = bf16_backward && width >= widths.bf16_backward;
        let kernel = if bf16_layer {
            Kernel::Winograd(Arc::new(WinogradKernel::new(&w, cout, cin)))
        } else {
            Kernel::F32(Arc::new(PackedKernel::forward(&w, cout, cin)))
        };
        let adjoint = if bf16_layer {
            Kernel::Bf16(Arc::new(StackedKernel::new(&PackedKernel::adjoint(
                &w, cout, cin,
            ))))
        } else if width >= widths.winograd_backward {
            Kernel::Winograd(Arc::new(WinogradKernel::adjoint(&w, cout, cin)))
        } else {
            Kernel::F32(Arc::new(PackedKernel::adjoint(&w, cout, cin)))
        };
        Ok(Self {
            kernel,
            adjoint,
            bf16_backward,
            exact_forward: (!bf16_backward && cin.min(cout) >= widths.exact_winograd)
                .then(|| Arc::new(OnceLock::new())),
            bias: Arc::new(bias.flatten_all()?.to_vec1::<f32>()?),
        })
    }

    /// `relu(conv(x) + bias)` of `x` `[n, h, w, cin]`. The input gradient is the adjoint
    /// convolution of the upstream gradient where the output is not `<= 0` (PyTorch's ReLU:
    /// 0 at an exact 0). With an f32 backward each output is the exact sum rounded once and its
    /// ReLU decides as the exact sum ([`Epilogue::ExactBiasRelu`], or the exact Winograd
    /// kernel), with or without a gradient through `x`: the ground truth's features are the
    /// same function as the render's, so equal pictures give equal features. With a bf16
    /// backward, as the f32 sum (its error is larger than the decisions the exact sums change).
    pub(crate) fn forward(&self, x: &Tensor, scratch: &Scratch) -> candle_core::Result<Tensor> {
        let exact = !self.bf16_backward;
        let kernel = match (&self.exact_forward, &self.kernel) {
            (Some(cell), Kernel::F32(packed)) => cell
                .get_or_init(|| {
                    let (cin, cout) = (packed.cin(), packed.cout());
                    let taps = packed.taps();
                    let tap = |o, i, dy, dx| taps[((dy * 3 + dx) * cin + i) * cout + o];
                    Kernel::ExactWinograd(Arc::new(ExactWinogradKernel::from_taps(cout, cin, tap)))
                })
                .clone(),
            _ => self.kernel.clone(),
        };
        x.contiguous()?.apply_op1(ConvOp {
            kernel,
            epilogue_bias: Some(self.bias.clone()),
            exact,
            adjoint: Some(self.adjoint.clone()),
            scratch: scratch.clone(),
        })
    }
}

/// The convolution as a candle op: `apply_op1` convolves (its backward is the `adjoint`
/// convolution of the gradient gated by the output), `apply_op2(gate)` convolves the input
/// gated by the second operand.
struct ConvOp {
    kernel: Kernel,
    epilogue_bias: Option<Arc<Vec<f32>>>,
    /// Whether the ReLUs decide as the exact sums ([`Epilogue::ExactBiasRelu`]; f32 products).
    exact: bool,
    adjoint: Option<Kernel>,
    scratch: Scratch,
}

impl ConvOp {
    fn run(
        &self,
        input: (&CpuStorage, &Layout),
        gate: Option<(&CpuStorage, &Layout)>,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let (_, layout) = input;
        let (images, h, w, cin) = layout.shape().dims4()?;
        if cin != self.kernel.cin() {
            candle_core::bail!(
                "conv3x3: input {layout:?}, kernel from {} channels",
                self.kernel.cin()
            )
        }
        let (data, gate) = match gate {
            Some(gate) => {
                let (data, gate) = same_shape_elements("conv3x3 gate", input, gate)?;
                (data, Some(gate))
            }
            None => (elements(input.0, layout)?, None),
        };
        let shape = ImageShape { images, h, w };
        let bias = self.epilogue_bias.as_deref().map(Vec::as_slice);
        let out = match &self.kernel {
            Kernel::Bf16(kernel) => conv3x3_bf16(data, shape, kernel, gate, bias),
            Kernel::Winograd(kernel) => conv3x3_winograd(data, (images, h, w), kernel, gate, bias),
            Kernel::ExactWinograd(kernel) => match (bias, gate) {
                (Some(bias), None) => conv3x3_winograd_exact(data, (images, h, w), kernel, bias),
                _ => candle_core::bail!("conv3x3: the exact forward takes a bias and no gate"),
            },
            Kernel::F32(kernel) => {
                let epilogue = match (bias, self.exact) {
                    (Some(bias), true) => Epilogue::ExactBiasRelu(bias),
                    (Some(bias), false) => Epilogue::BiasRelu(bias),
                    (None, _) => Epilogue::Identity,
                };
                let mut scratch = self
                    .scratch
                    .lock()
                    .unwrap_or_else(|poisoned| poisoned.into_inner());
                conv3x3(data, shape, kernel, gate, epilogue, &mut scratch)
            }
        };
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
            exact: false,
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

#[cfg(test)]
mod tests {
    use candle_core::{Device, Tensor, Var};

    use super::*;

    /// Values in [-1, 1) from a small linear congruential generator.
    fn values(len: usize, seed: u64) -> Vec<f32> {
        let mut state = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        (0..len)
            .map(|_| {
                state = state
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1_442_695_040_888_963_407);
                ((state >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
            })
            .collect()
    }

    /// The layer and its input gradient for the upstream gradient `r`, in f64 from PyTorch
    /// weights: `relu(conv(x) + b)` and `adjoint(r where the output is > 0)`.
    fn reference(
        x: &[f32],
        (h, w, cin, cout): (usize, usize, usize, usize),
        weight: &[f32],
        bias: &[f32],
        r: &[f32],
    ) -> (Vec<f64>, Vec<f64>) {
        let at = |y: usize, x: usize, dy: usize, dx: usize| {
            let (sy, sx) = ((y + dy).wrapping_sub(1), (x + dx).wrapping_sub(1));
            (sy < h && sx < w).then_some((sy, sx))
        };
        let mut out = vec![0f64; h * w * cout];
        for y in 0..h {
            for xx in 0..w {
                for o in 0..cout {
                    let mut acc = f64::from(bias[o]);
                    for (dy, dx) in (0..3).flat_map(|dy| (0..3).map(move |dx| (dy, dx))) {
                        if let Some((sy, sx)) = at(y, xx, dy, dx) {
                            for i in 0..cin {
                                acc += f64::from(x[(sy * w + sx) * cin + i])
                                    * f64::from(weight[((o * cin + i) * 3 + dy) * 3 + dx]);
                            }
                        }
                    }
                    out[(y * w + xx) * cout + o] = acc.max(0.0);
                }
            }
        }
        let mut grad = vec![0f64; h * w * cin];
        for y in 0..h {
            for xx in 0..w {
                for o in 0..cout {
                    if out[(y * w + xx) * cout + o] <= 0.0 {
                        continue;
                    }
                    let g = f64::from(r[(y * w + xx) * cout + o]);
                    for (dy, dx) in (0..3).flat_map(|dy| (0..3).map(move |dx| (dy, dx))) {
                        if let Some((sy, sx)) = at(y, xx, dy, dx) {
                            for i in 0..cin {
                                grad[(sy * w + sx) * cin + i] +=
                                    g * f64::from(weight[((o * cin + i) * 3 + dy) * 3 + dx]);
                            }
                        }
                    }
                }
            }
        }
        (out, grad)
    }

    /// The exact forward of a 256-channel layer (f64 Winograd, a kernel large enough for its
    /// bands to run one after another) against the f64 direct convolution:
    /// biases that put one pre-activation per channel within an f32 rounding of 0 (both signs)
    /// decide as the exact sums, and each output is the f64 sum rounded once: to the ulp, or
    /// within 1e-13 (f64's error on the terms, of order 1) where the sum nearly cancels.
    #[test]
    fn the_exact_forward_of_a_256_channel_layer_rounds_the_exact_sums() {
        let (h, w, cin, cout) = (5, 7, 256, 256);
        let x = values(h * w * cin, 11);
        let weight: Vec<f32> = values(cout * cin * 9, 12)
            .iter()
            .map(|v| v / (3 * cin) as f32)
            .collect();
        let zeros = vec![0f32; cout];
        let r = vec![1f32; h * w * cout];
        // Sums without bias, relu'd: take them at a pixel where every channel's is positive or
        // use its negative (the ReLU is odd-symmetric in what it keeps).
        let (plain, _) = reference(&x, (h, w, cin, cout), &weight, &zeros, &r);
        let (negated, _) = reference(
            &x,
            (h, w, cin, cout),
            &weight.iter().map(|v| -v).collect::<Vec<_>>(),
            &zeros,
            &r,
        );
        let sum = |k: usize| plain[k] - negated[k];
        let bias: Vec<f32> = (0..cout)
            .map(|o| -(sum(((o * 5) % (h * w)) * cout + o) as f32))
            .collect();
        let (out, _) = reference(&x, (h, w, cin, cout), &weight, &bias, &r);
        let dev = Device::Cpu;
        let layer = ConvReluChannelsLast::new(
            &Tensor::from_vec(weight.clone(), (cout, cin, 3, 3), &dev).unwrap(),
            &Tensor::from_vec(bias.clone(), cout, &dev).unwrap(),
            false,
            MEASURED,
        )
        .unwrap();
        let input = Var::from_vec(x, (1, h, w, cin), &dev).unwrap();
        let y = layer
            .forward(input.as_tensor(), &Scratch::default())
            .unwrap();
        let got = y.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let (mut near_zero, mut rounded_apart) = (0, 0);
        for (k, (&g, &e)) in got.iter().zip(&out).enumerate() {
            let pre_activation = sum(k) + f64::from(bias[k % cout]);
            assert_eq!(
                g > 0.0,
                pre_activation > 0.0,
                "output {k}: {g} vs {pre_activation:e}"
            );
            if pre_activation.abs() < 1e-6 {
                near_zero += 1;
                assert!((f64::from(g) - e).abs() < 1e-13, "output {k}: {g} vs {e:e}");
                continue;
            }
            let rounded = e as f32;
            let ulps = (i64::from(g.to_bits() as i32) - i64::from(rounded.to_bits() as i32)).abs();
            assert!(ulps <= 1, "output {k}: {g} vs {rounded} ({ulps} ulp)");
            rounded_apart += usize::from(ulps > 0);
        }
        assert!(near_zero >= cout, "{near_zero} pre-activations near 0");
        assert!(
            rounded_apart * 1000 <= got.len(),
            "{rounded_apart} outputs off by an ulp"
        );
    }

    /// A forward without gradient gives the forward with a gradient's outputs bit for bit,
    /// before and after the exact kernel is built and through a clone of the layer (the ground
    /// truth's features and the render's share the kernel), on a layer of the exact Winograd
    /// forward and on a 3-channel one; the direct f32 sums (what it took before) differ.
    #[test]
    fn a_forward_without_gradient_is_the_forward_with_one() {
        let dev = Device::Cpu;
        let (h, w) = (6, 9);
        for (cin, cout) in [(MEASURED.exact_winograd, MEASURED.exact_winograd), (3, 16)] {
            let weight: Vec<f32> = values(cout * cin * 9, 31)
                .iter()
                .map(|v| v / (3 * cin) as f32)
                .collect();
            let weight = Tensor::from_vec(weight, (cout, cin, 3, 3), &dev).unwrap();
            let bias = Tensor::from_vec(values(cout, 32), cout, &dev).unwrap();
            let layer = ConvReluChannelsLast::new(&weight, &bias, false, MEASURED).unwrap();
            let clone = layer.clone();
            let scratch = Scratch::default();
            let x = Tensor::from_vec(values(h * w * cin, 33), (1, h, w, cin), &dev).unwrap();
            let outputs = |t: Tensor| t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
            let before = outputs(clone.forward(&x, &scratch).unwrap());
            let var = Var::from_tensor(&x).unwrap();
            let with_gradient = outputs(layer.forward(var.as_tensor(), &scratch).unwrap());
            let after = outputs(clone.forward(&x, &scratch).unwrap());
            let apart = |v: &[f32]| {
                v.iter()
                    .zip(&with_gradient)
                    .filter(|(a, e)| a.to_bits() != e.to_bits())
                    .count()
            };
            let what = format!("{cin}->{cout}, of {} outputs", with_gradient.len());
            assert_eq!(apart(&before), 0, "before: {what}");
            assert_eq!(apart(&after), 0, "after: {what}");
            let packed = PackedKernel::forward(
                &weight.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
                cout,
                cin,
            );
            let direct = conv3x3(
                &x.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
                ImageShape { images: 1, h, w },
                &packed,
                None,
                Epilogue::BiasRelu(&bias.to_vec1::<f32>().unwrap()),
                &mut Vec::new(),
            );
            assert!(
                apart(&direct) > 0,
                "{what}: the f32 sums round as the exact ones"
            );
        }
    }

    /// Layers wide enough for bf16 products with a bf16 backward, one whose exact forward and
    /// f32 backward take Winograd's (F(4x4, 3x3) in f64, F(2x2, 3x3) in f32) but whose bf16
    /// backward stays f32, and a narrow one, forward and input gradient against f64, with the
    /// f32 and the bf16 backward.
    #[test]
    fn wide_and_narrow_layers_match_f64_both_ways() {
        let (wide, exact) = (MEASURED.bf16_backward, MEASURED.exact_winograd);
        for (h, w, cin, cout) in [
            (5, 6, wide, wide),
            (4, 3, wide, 2 * wide),
            (7, 5, exact, exact),
            (5, 4, 8, 16),
        ] {
            let x = values(h * w * cin, 1);
            let weight: Vec<f32> = values(cout * cin * 9, 2)
                .iter()
                .map(|v| v / (3 * cin) as f32)
                .collect();
            let bias: Vec<f32> = values(cout, 3).iter().map(|v| 0.1 * v).collect();
            let r = values(h * w * cout, 4);
            let (out, grad) = reference(&x, (h, w, cin, cout), &weight, &bias, &r);
            let scale = |v: &[f64]| v.iter().fold(1e-6f64, |m, v| m.max(v.abs()));
            let (out_scale, grad_scale) = (scale(&out), scale(&grad));
            for (bf16_backward, grad_tolerance) in [(false, 1e-5), (true, 2e-2)] {
                let dev = Device::Cpu;
                let layer = ConvReluChannelsLast::new(
                    &Tensor::from_vec(weight.clone(), (cout, cin, 3, 3), &dev).unwrap(),
                    &Tensor::from_vec(bias.clone(), cout, &dev).unwrap(),
                    bf16_backward,
                    MEASURED,
                )
                .unwrap();
                let input = Var::from_vec(x.clone(), (1, h, w, cin), &dev).unwrap();
                let scratch = Scratch::default();
                let y = layer.forward(input.as_tensor(), &scratch).unwrap();
                let upstream = Tensor::from_vec(r.clone(), (1, h, w, cout), &dev).unwrap();
                let grads = (y.clone() * upstream)
                    .unwrap()
                    .sum_all()
                    .unwrap()
                    .backward()
                    .unwrap();
                let got_out = y.flatten_all().unwrap().to_vec1::<f32>().unwrap();
                let got_grad = grads
                    .get(input.as_tensor())
                    .unwrap()
                    .flatten_all()
                    .unwrap()
                    .to_vec1::<f32>()
                    .unwrap();
                let case = format!("{h}x{w} {cin}->{cout}, bf16 backward {bf16_backward}");
                for (g, e) in got_out.iter().zip(&out) {
                    assert!(
                        (f64::from(*g) - e).abs() <= 1e-6 * out_scale,
                        "{case}: {g} vs {e}"
                    );
                }
                for (g, e) in got_grad.iter().zip(&grad) {
                    assert!(
                        (f64::from(*g) - e).abs() <= grad_tolerance * grad_scale,
                        "{case}: gradient {g} vs {e}"
                    );
                }
            }
        }
    }
}
