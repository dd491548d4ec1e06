// Radix sort, pass step 3 of 3: moves every key and its value to its slot, stably. Each thread
// owns 4 consecutive items; per-digit counts of the threads before it (a workgroup prefix sum
// of 16 counts packed two to a u32) give each item its rank among the block's items of the same
// digit, and the prefix-summed `counts` the block's first slot for that digit.

//#import helpers.wgsl

@group(0) @binding(0) var<uniform> params: Pass;
@group(0) @binding(1) var<storage, read> keys: array<u32>;
@group(0) @binding(2) var<storage, read> values: array<u32>;
@group(0) @binding(3) var<storage, read> offsets: array<u32>;
@group(0) @binding(4) var<storage, read_write> keys_out: array<u32>;
@group(0) @binding(5) var<storage, read_write> values_out: array<u32>;

var<workgroup> packed: array<array<u32, 8>, 256>;

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
    var own: array<u32, 8>;
    for (var j = 0u; j < 4u; j++) {
        if base + j < params.n {
            let d = (keys[base + j] >> params.shift) & 15u;
            own[d / 2u] += 1u << (16u * (d % 2u));
        }
    }
    packed[lid] = own;
    workgroupBarrier();
    for (var off = 1u; off < 256u; off *= 2u) {
        var add: array<u32, 8>;
        if lid >= off {
            add = packed[lid - off];
        }
        workgroupBarrier();
        for (var w = 0u; w < 8u; w++) {
            packed[lid][w] += add[w];
        }
        workgroupBarrier();
    }
    var before: array<u32, 8>;
    for (var w = 0u; w < 8u; w++) {
        before[w] = packed[lid][w] - own[w];
    }
    for (var j = 0u; j < 4u; j++) {
        if base + j < params.n {
            let key = keys[base + j];
            let d = (key >> params.shift) & 15u;
            let field = 16u * (d % 2u);
            let rank = (before[d / 2u] >> field) & 0xffffu;
            before[d / 2u] += 1u << field;
            let slot = offsets[d * params.blocks + block] + rank;
            keys_out[slot] = key;
            values_out[slot] = values[base + j];
        }
    }
}
