// Twin of base_mirage::flat::add_scale_grads: the gradient of the stored log-scales is that of
// the rendered ones where the clamp to [lo, hi] passes it (bounds inclusive; never for NaN), and
// zero on the flat axis and where the clamp is active.

struct Clamp {
    lo: f32,
    hi: f32,
    unused0: u32,
    unused1: u32,
}

//#import chunk.wgsl

@group(0) @binding(0) var<uniform> params: Clamp;
@group(0) @binding(1) var<storage, read> stored: array<f32>;
@group(0) @binding(2) var<storage, read> rendered_grads: array<f32>;
@group(0) @binding(3) var<storage, read_write> grads: array<f32>;

fn passes_clamp(s: f32) -> bool {
    return s >= params.lo && s <= params.hi;
}

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
    grads[3u * i] = 0.0;
    for (var k = 1u; k < 3u; k++) {
        let j = 3u * i + k;
        grads[j] = select(0.0, rendered_grads[j], passes_clamp(stored[j]));
    }
}
