// Radix sort, pass step 1 of 3 (the GPU twin of the cpu backend's depth and tile sorts): the
// count of every 4-bit digit in each block of keys, stored digit-major (`counts[d * blocks +
// block]`) so that its prefix sum gives every (digit, block) its first output slot.

//#import helpers.wgsl

@group(0) @binding(0) var<uniform> params: Pass;
@group(0) @binding(1) var<storage, read> keys: array<u32>;
@group(0) @binding(2) var<storage, read_write> counts: array<u32>;

var<workgroup> histogram: array<atomic<u32>, 16>;

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
    if lid < 16u {
        atomicStore(&histogram[lid], 0u);
    }
    workgroupBarrier();
    let base = block * BLOCK_ITEMS + 4u * lid;
    for (var j = 0u; j < 4u; j++) {
        if base + j < params.n {
            atomicAdd(&histogram[(keys[base + j] >> params.shift) & 15u], 1u);
        }
    }
    workgroupBarrier();
    if lid < 16u {
        counts[lid * params.blocks + block] = atomicLoad(&histogram[lid]);
    }
}
