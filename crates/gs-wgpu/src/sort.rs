//! A stable least-significant-digit radix sort of `u32` keys with `u32` values on the GPU,
//! 4 bits a pass: per-block digit counts, their prefix sum, a stable scatter.

use super::buffers::{storage, uniform};
use super::device::{GpuContext, GpuError};
use super::scan::{prefix_sum, PassUniform};
use super::shaders::KernelId;

/// Bits sorted per pass.
const DIGIT_BITS: u32 = 4;

/// Records a stable sort of the first `n` keys of `keys` by their low `bits` bits (higher bits
/// must be zero or are ignored), moving `values` along. Returns the buffers that will hold
/// the sorted keys and values (the inputs or scratch buffers, depending on the pass count).
pub(crate) fn radix_sort(
    ctx: &GpuContext,
    encoder: &mut wgpu::CommandEncoder,
    keys: wgpu::Buffer,
    values: wgpu::Buffer,
    n: u32,
    bits: u32,
) -> Result<(wgpu::Buffer, wgpu::Buffer), GpuError> {
    if n <= 1 || bits == 0 {
        return Ok((keys, values));
    }
    let bytes = 4 * u64::from(n);
    let mut src = (keys, values);
    let mut dst = (
        storage(ctx, "radix sort keys", bytes)?,
        storage(ctx, "radix sort values", bytes)?,
    );
    for shift in (0..bits).step_by(DIGIT_BITS as usize) {
        let pass = PassUniform::new(n, shift);
        let params = uniform(ctx, &pass);
        let counts = storage(ctx, "radix sort counts", 64 * u64::from(pass.blocks))?;
        ctx.dispatch(
            encoder,
            KernelId::RadixSortCount,
            &[&params, &src.0, &counts],
            pass.blocks,
        );
        prefix_sum(ctx, encoder, &counts, 16 * pass.blocks)?;
        ctx.dispatch(
            encoder,
            KernelId::RadixSortScatter,
            &[&params, &src.0, &src.1, &counts, &dst.0, &dst.1],
            pass.blocks,
        );
        std::mem::swap(&mut src, &mut dst);
    }
    Ok(src)
}
