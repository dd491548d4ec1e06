// First half of gs_core::raster::bin::bin: the number of tiles of each splat, in depth order
// (`order` is the depth-sorted Gaussian indices), to be prefix-summed into list offsets.

//#import helpers.wgsl
//#import splat_parts.wgsl

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(5) var<storage, read> order: array<u32>;
@group(0) @binding(6) var<storage, read_write> counts: array<u32>;

@compute @workgroup_size(256)
fn main(
    @builtin(workgroup_id) wid: vec3u,
    @builtin(num_workgroups) nwg: vec3u,
    @builtin(local_invocation_index) lid: u32,
) {
    let r = flat_index(wid, nwg, lid, 256u);
    if r >= view.scene.x {
        return;
    }
    let s = load_splat(order[r]);
    var count = 0u;
    if s.cut_radius.z != 0.0 {
        let rect = tile_rect(s, view.size.zw);
        count = (rect.y - rect.x) * (rect.w - rect.z);
    }
    counts[r] = count;
}
