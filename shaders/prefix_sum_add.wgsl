// Adds to every value of a block the prefix-summed total of the blocks before it, completing
// prefix_sum_blocks over more than one block.

//#import helpers.wgsl

@group(0) @binding(0) var<uniform> params: Pass;
@group(0) @binding(1) var<storage, read_write> data: array<u32>;
@group(0) @binding(2) var<storage, read> sums: array<u32>;

@compute @workgroup_size(256)
fn main(
    @builtin(workgroup_id) wid: vec3u,
    @builtin(num_workgroups) nwg: vec3u,
    @builtin(local_invocation_index) lid: u32,
) {
    let block = flat_workgroup(wid, nwg);
    if block >= params.blocks {
        return;
    }
    let base = block * BLOCK_ITEMS + 4u * lid;
    let add = sums[block];
    for (var j = 0u; j < 4u; j++) {
        if base + j < params.n {
            data[base + j] += add;
        }
    }
}
