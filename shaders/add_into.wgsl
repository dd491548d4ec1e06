// Twin of the cpu loop's gradient accumulation over a batch of views: adds `src` to `dst`, item by
// item (one parameter group's gradient of one view into the batch's sum).

//#import chunk.wgsl

@group(0) @binding(0) var<storage, read> src: array<f32>;
@group(0) @binding(1) var<storage, read_write> dst: array<f32>;

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
    dst[i] = dst[i] + src[i];
}
