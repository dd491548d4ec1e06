//! Exclusive prefix sums of `u32` arrays on the GPU, block by block with the block totals
//! summed recursively.

use super::buffers::{storage, uniform};
use super::device::{GpuContext, GpuError};
use super::shaders::KernelId;

/// Items one workgroup sums (`BLOCK_ITEMS` of shaders/helpers.wgsl).
pub(crate) const BLOCK_ITEMS: u32 = 1024;

/// The uniform of the prefix-sum and radix-sort kernels (`Pass` of shaders/helpers.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct PassUniform {
    /// Number of items.
    pub n: u32,
    /// Bit offset of the radix digit.
    pub shift: u32,
    /// Number of blocks of `BLOCK_ITEMS` items.
    pub blocks: u32,
    /// Padding.
    pub unused: u32,
}

impl PassUniform {
    pub(crate) fn new(n: u32, shift: u32) -> Self {
        Self {
            n,
            shift,
            blocks: n.div_ceil(BLOCK_ITEMS),
            unused: 0,
        }
    }
}

/// Records the exclusive prefix sum of the first `n` (> 0) values of `data`, in place, and
/// returns a buffer whose first value will be their total.
pub(crate) fn prefix_sum(
    ctx: &GpuContext,
    encoder: &mut wgpu::CommandEncoder,
    data: &wgpu::Buffer,
    n: u32,
) -> Result<wgpu::Buffer, GpuError> {
    let pass = PassUniform::new(n, 0);
    let sums = storage(ctx, "prefix-sum block totals", 4 * u64::from(pass.blocks))?;
    let params = uniform(ctx, &pass);
    ctx.dispatch(
        encoder,
        KernelId::PrefixSumBlocks,
        &[&params, data, &sums],
        pass.blocks,
    );
    if pass.blocks == 1 {
        return Ok(sums);
    }
    let total = prefix_sum(ctx, encoder, &sums, pass.blocks)?;
    ctx.dispatch(
        encoder,
        KernelId::PrefixSumAdd,
        &[&params, data, &sums],
        pass.blocks,
    );
    Ok(total)
}
