// Twin of the check of gs_core::train that every parameter gradient is finite: sets `flag` when
// any value of the chunk is NaN or infinite (by its bits, see `finite`).

//#import chunk.wgsl

@group(0) @binding(0) var<storage, read> values: array<f32>;
@group(0) @binding(1) var<storage, read_write> flag: array<atomic<u32>>;

@compute @workgroup_size(256)
fn main(
    @builtin(workgroup_id) wid: vec3u,
    @builtin(num_workgroups) nwg: vec3u,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = chunk_item(wid, nwg, lid);
    if i >= chunk.count {
        return;
    }
    if !finite(values[i]) {
        atomicStore(&flag[0], 1u);
    }
}
