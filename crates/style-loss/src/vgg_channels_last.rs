//! VGG's convolution + ReLU on the CPU in channels-last layout (`[n, h, w, c]`), where a 3x3
//! convolution is three matrix products (the `conv3x3` module) instead of candle's im2col
//! convolution: a candle op with an input-only gradient that follows PyTorch's ReLU at exact
//! zeros (as the channels-first op in `vgg`). Its max pool is `torch_ties::max_pool_2x2_channels_last`.

use std::sync::{Arc, Mutex};

use candle_core::{CpuStorage, CustomOp1, CustomOp2, Layout, Shape, Tensor};

use crate::conv3x3::{conv3x3, Epilogue, ImageShape, PackedKernel};
use crate::conv3x3_bf16::{conv3x3_bf16, StackedKernel};
use crate::conv3x3_winograd::{conv3x3_winograd_bias_relu, WinogradKernel};
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
    /// f32 products of Winograd's F(2x2, 3x3) (`conv3x3_winograd`), with bias and ReLU.
    Winograd(Arc<WinogradKernel>),
}

impl Kernel {
    /// `packed`, kept in f32 or stacked in bf16.
    fn new(packed: PackedKernel, bf16: bool) -> Self {
        if bf16 {
            Self::Bf16(Arc::new(StackedKernel::new(&packed)))
        } else {
            Self::F32(Arc::new(packed))
        }
    }

    fn cin(&self) -> usize {
        match self {
            Self::F32(k) => k.cin(),
            Self::Bf16(k) => k.cin(),
            Self::Winograd(k) => k.cin(),
        }
    }

    fn cout(&self) -> usize {
        match self {
            Self::F32(k) => k.cout(),
            Self::Bf16(k) => k.cout(),
            Self::Winograd(k) => k.cout(),
        }
    }
}

/// A 3x3 convolution, padding 1, then ReLU, on channels-last f32 CPU tensors. Its forward
/// products are f32 (direct, or Winograd's with a bf16 backward); its backward products (the
/// adjoint on the gradient) f32 or bf16.
#[derive(Clone, Debug)]
pub(crate) struct ConvReluChannelsLast {
    kernel: Kernel,
    adjoint: Kernel,
    bias: Arc<Vec<f32>>,
}

impl ConvReluChannelsLast {
    /// From PyTorch weights `[cout, cin, 3, 3]` and bias `[cout]`; `bf16_backward` runs the
    /// backward products in bf16 and the forward by Winograd's F(2x2, 3x3) in f32 (2.25 times
    /// fewer multiply-adds, errors of the order of an f32 sum's, far under the bf16 backward's)
    /// rather than exactly.
    ///
    /// The forward stays f32 in either case: its outputs decide the ReLUs and the max pools,
    /// and outputs rounded to bf16 tie inside pooling windows, which routes the gradient to
    /// another pixel (17 % of the gradient of a small network, against 0.8 % for bf16 in the
    /// backward only).
    pub(crate) fn new(
        weight: &Tensor,
        bias: &Tensor,
        bf16_backward: bool,
    ) -> candle_core::Result<Self> {
        let (cout, cin, _, _) = weight.dims4()?;
        let w = weight.flatten_all()?.to_vec1::<f32>()?;
        let kernel = if bf16_backward {
            Kernel::Winograd(Arc::new(WinogradKernel::new(&w, cout, cin)))
        } else {
            Kernel::F32(Arc::new(PackedKernel::forward(&w, cout, cin)))
        };
        Ok(Self {
            kernel,
            adjoint: Kernel::new(PackedKernel::adjoint(&w, cout, cin), bf16_backward),
            bias: Arc::new(bias.flatten_all()?.to_vec1::<f32>()?),
        })
    }

    /// `relu(conv(x) + bias)` of `x` `[n, h, w, cin]`. The input gradient is the adjoint
    /// convolution of the upstream gradient where the output is not `<= 0` (PyTorch's ReLU:
    /// 0 at an exact 0). When a gradient is taken through `x` and the backward is f32, the sums
    /// are exact before their ReLU decides ([`Epilogue::ExactBiasRelu`]); else f32 (a bf16
    /// backward's error is larger than the decisions the exact sums change).
    pub(crate) fn forward(&self, x: &Tensor, scratch: &Scratch) -> candle_core::Result<Tensor> {
        x.contiguous()?.apply_op1(ConvOp {
            kernel: self.kernel.clone(),
            epilogue_bias: Some(self.bias.clone()),
            exact: x.track_op() && matches!(self.adjoint, Kernel::F32(_)),
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
    /// Whether the bias and ReLU follow exact sums ([`Epilogue::ExactBiasRelu`]; f32 products).
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
            Kernel::Winograd(kernel) => match (gate, bias) {
                (None, Some(bias)) => {
                    conv3x3_winograd_bias_relu(data, (images, h, w), kernel, bias)
                }
                _ => candle_core::bail!("conv3x3: the Winograd forward takes a bias and no gate"),
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
