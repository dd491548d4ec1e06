//! The f32 elements of candle CPU storage, as this crate's custom CPU kernels read them.

use candle_core::{CpuStorage, DType, Layout, Tensor};

/// Whether `x` can go to this crate's CPU kernels: f32 on the CPU.
pub(crate) fn is_cpu_f32(x: &Tensor) -> bool {
    x.device().is_cpu() && x.dtype() == DType::F32
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
