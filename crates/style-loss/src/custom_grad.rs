//! Attach a hand-written input gradient to a value computed outside candle's autograd graph.
//!
//! candle's backward computes the gradient of every operand of an op, also of constant weights:
//! a `matmul` against a weight matrix costs a second matmul for the unused weight gradient, and a
//! `conv2d` costs a full correlation with an image-sized kernel for its unused kernel gradient.
//! Linear maps with constant operators (linear layers, convolutions, resizes) therefore compute
//! their value on a detached input and attach their input gradient with [`attach_input_gradient`].

use candle_core::backend::BackendStorage;
use candle_core::{CpuStorage, CudaStorage, CustomOp2, Layout, MetalStorage, Shape, Tensor};

/// The gradient map of a linear operator: upstream gradient of the output -> gradient of the
/// input.
type Backward = dyn Fn(&Tensor) -> candle_core::Result<Tensor> + Send + Sync;

/// `forward(value, input) = value`; `backward` sends `grad_fn(grad)` to `input`, nothing to
/// `value`.
struct InputGradient {
    grad_fn: Box<Backward>,
}

/// `value` must be dense and start at offset 0 in its storage: then its storage holds exactly
/// its elements in order and a clone of the storage is the value.
fn check_dense(layout: &Layout) -> candle_core::Result<()> {
    if layout.is_contiguous() && layout.start_offset() == 0 {
        Ok(())
    } else {
        candle_core::bail!("attach_input_gradient: value must be contiguous at offset 0")
    }
}

impl CustomOp2 for InputGradient {
    fn name(&self) -> &'static str {
        "attach-input-gradient"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        _: &CpuStorage,
        _: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        check_dense(l1)?;
        Ok((s1.try_clone(l1)?, l1.shape().clone()))
    }

    fn cuda_fwd(
        &self,
        s1: &CudaStorage,
        l1: &Layout,
        _: &CudaStorage,
        _: &Layout,
    ) -> candle_core::Result<(CudaStorage, Shape)> {
        check_dense(l1)?;
        Ok((s1.try_clone(l1)?, l1.shape().clone()))
    }

    fn metal_fwd(
        &self,
        s1: &MetalStorage,
        l1: &Layout,
        _: &MetalStorage,
        _: &Layout,
    ) -> candle_core::Result<(MetalStorage, Shape)> {
        check_dense(l1)?;
        Ok((s1.try_clone(l1)?, l1.shape().clone()))
    }

    fn bwd(
        &self,
        _value: &Tensor,
        _input: &Tensor,
        _res: &Tensor,
        grad_res: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>)> {
        Ok((None, Some((self.grad_fn)(grad_res)?)))
    }
}

/// Returns a tensor equal to `value` whose gradient flows to `input` as `grad_fn(upstream)`.
///
/// `value` must have been computed from `input.detach()` (so it carries no graph of its own);
/// `grad_fn` is the transposed Jacobian of that map at `input` (the adjoint of a linear map, or
/// a masked one for ReLU and max pooling) and must return a tensor of `input`'s shape. The value
/// is copied once (a fresh contiguous copy is made first if it is a view).
pub(crate) fn attach_input_gradient(
    value: &Tensor,
    input: &Tensor,
    grad_fn: impl Fn(&Tensor) -> candle_core::Result<Tensor> + Send + Sync + 'static,
) -> candle_core::Result<Tensor> {
    let value = if value.is_contiguous() && value.layout().start_offset() == 0 {
        value.detach()
    } else {
        value.detach().copy()?
    };
    value.apply_op2(
        input,
        InputGradient {
            grad_fn: Box::new(grad_fn),
        },
    )
}
