// The twin of TileBins::offsets: each tile's range [start, end) in the tile-sorted pair list
// (`ranges` is cleared to empty ranges first).

//#import helpers.wgsl

@group(0) @binding(0) var<uniform> params: Pass;
@group(0) @binding(1) var<storage, read> tile_keys: array<u32>;
@group(0) @binding(2) var<storage, read_write> ranges: array<vec2u>;

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
    let t = tile_keys[i];
    if i == 0u || tile_keys[i - 1u] != t {
        ranges[t].x = i;
    }
    if i + 1u == params.n || tile_keys[i + 1u] != t {
        ranges[t].y = i + 1u;
    }
}
