//! The f32 elements of candle CPU storage, as this crate's custom CPU kernels read them.

use std::cell::Cell;

use candle_core::{CpuStorage, DType, Layout, Tensor};

thread_local! {
    /// Whether this thread runs the generic composition on the CPU too ([`GenericPath`]).
    static GENERIC_PATH: Cell<bool> = const { Cell::new(false) };
}

/// Whether this thread holds a [`GenericPath`].
pub(crate) fn generic_path() -> bool {
    GENERIC_PATH.get()
}

/// Whether `x` can go to this crate's CPU kernels: f32 on the CPU, unless this thread holds a
/// [`GenericPath`].
pub(crate) fn is_cpu_f32(x: &Tensor) -> bool {
    !GENERIC_PATH.get() && x.device().is_cpu() && x.dtype() == DType::F32
}

/// While it lives, the thread that made it runs the composition of candle ops that a CUDA or
/// Metal device runs also on the CPU: every CPU fast path of this crate is off (the fused layer
/// norm, softmax and GELU kernels, the channels-last VGG convolutions, the max-pool routing
/// kernel, gemmkit's bf16 products: candle's own product widens bf16 to f32). Models built while it lives keep the generic layers. For tests (the generic path
/// proven on the CPU, `generic_path` tests) and for comparing a GPU run with the same
/// composition on the CPU.
#[derive(Debug)]
pub struct GenericPath {
    previous: bool,
}

impl GenericPath {
    /// Turns the CPU fast paths off on this thread until the returned value is dropped.
    pub fn on() -> Self {
        Self {
            previous: GENERIC_PATH.replace(true),
        }
    }
}

impl Drop for GenericPath {
    fn drop(&mut self) {
        GENERIC_PATH.set(self.previous);
    }
}

/// The elements of a contiguous f32 tensor, in order (bails on a strided layout or another
/// dtype).
pub(crate) fn elements<'a>(
    storage: &'a CpuStorage,
    layout: &Layout,
) -> candle_core::Result<&'a [f32]> {
    if !layout.is_contiguous() {
        candle_core::bail!("cpu kernel: strided input {layout:?}")
    }
    let start = layout.start_offset();
    Ok(&storage.as_slice::<f32>()?[start..start + layout.shape().elem_count()])
}

/// The elements of two contiguous f32 tensors of one shape (`op` names the kernel in the
/// error).
pub(crate) fn same_shape_elements<'a>(
    op: &str,
    (s1, l1): (&'a CpuStorage, &Layout),
    (s2, l2): (&'a CpuStorage, &Layout),
) -> candle_core::Result<(&'a [f32], &'a [f32])> {
    if l1.shape() != l2.shape() {
        candle_core::bail!("{op}: operands {l1:?} and {l2:?} differ in shape")
    }
    Ok((elements(s1, l1)?, elements(s2, l2)?))
}
