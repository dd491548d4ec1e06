// Second half of gs_core::raster::bin::bin: writes the (tile, Gaussian) pairs of every splat
// at its offset, in depth order; a stable sort by tile then gives each tile's list front to
// back.

//#import helpers.wgsl
//#import splat_parts.wgsl

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(5) var<storage, read> order: array<u32>;
@group(0) @binding(6) var<storage, read> offsets: array<u32>;
@group(0) @binding(7) var<storage, read_write> tile_keys: array<u32>;
@group(0) @binding(8) var<storage, read_write> tile_ids: array<u32>;

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
    let gid = order[r];
    let s = load_splat(gid);
    if s.cut_radius.z == 0.0 {
        return;
    }
    let rect = tile_rect(s, view.size.zw);
    var at = offsets[r];
    for (var ty = rect.z; ty < rect.w; ty++) {
        for (var tx = rect.x; tx < rect.y; tx++) {
            tile_keys[at] = ty * view.size.z + tx;
            tile_ids[at] = gid;
            at++;
        }
    }
}
