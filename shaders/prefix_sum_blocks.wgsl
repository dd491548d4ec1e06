// The exclusive prefix sum of every block of BLOCK_ITEMS values, in place, and each block's
// total in `sums` (prefix-summed in turn, then added back by prefix_sum_add). Twin of the
// offsets loop of gs_core::raster::bin::bin.

//#import helpers.wgsl

@group(0) @binding(0) var<uniform> params: Pass;
@group(0) @binding(1) var<storage, read_write> data: array<u32>;
@group(0) @binding(2) var<storage, read_write> sums: array<u32>;

var<workgroup> partial: array<u32, 256>;

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
    var values: array<u32, 4>;
    var total = 0u;
    for (var j = 0u; j < 4u; j++) {
        if base + j < params.n {
            values[j] = data[base + j];
        }
        total += values[j];
    }
    partial[lid] = total;
    workgroupBarrier();
    for (var off = 1u; off < 256u; off *= 2u) {
        var add = 0u;
        if lid >= off {
            add = partial[lid - off];
        }
        workgroupBarrier();
        partial[lid] += add;
        workgroupBarrier();
    }
    var running = partial[lid] - total;
    for (var j = 0u; j < 4u; j++) {
        if base + j < params.n {
            data[base + j] = running;
        }
        running += values[j];
    }
    if lid == 255u {
        sums[block] = partial[255];
    }
}
