// Twin of the check of gs_core::train that every parameter gradient is finite: sets `flag` when
// any of the first `n` values is NaN or infinite (by its bits, see `finite`).

//#import helpers.wgsl

@group(0) @binding(0) var<uniform> params: Pass;
@group(0) @binding(1) var<storage, read> values: array<f32>;
@group(0) @binding(2) var<storage, read_write> flag: array<atomic<u32>>;

@compute @workgroup_size(256)
fn main(
    @builtin(workgroup_id) wid: vec3u,
    @builtin(num_workgroups) nwg: vec3u,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = flat_index(wid, nwg, lid, 256u);
    if i >= params.n {
        return;
    }
    if !finite(values[i]) {
        atomicStore(&flag[0], 1u);
    }
}
