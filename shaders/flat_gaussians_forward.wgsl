// Twin of base_mirage::flat::renderable for the log-scales: the flat axis at `lo` (ln 1e-8),
// the two in-plane log-scales clamped to [lo, hi] (ln 1e-8, ln 1). WGSL does not promise NaN
// semantics; no NaN reaches here in training (PLY input refuses them, gradients are checked).

struct Clamp {
    lo: f32,
    hi: f32,
    unused0: u32,
    unused1: u32,
}

//#import chunk.wgsl

@group(0) @binding(0) var<uniform> params: Clamp;
@group(0) @binding(1) var<storage, read> stored: array<f32>;
@group(0) @binding(2) var<storage, read_write> rendered: array<f32>;

fn clamp_log_scale(s: f32) -> f32 {
    if s < params.lo {
        return params.lo;
    }
    if s > params.hi {
        return params.hi;
    }
    return s;
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
    rendered[3u * i] = params.lo;
    rendered[3u * i + 1u] = clamp_log_scale(stored[3u * i + 1u]);
    rendered[3u * i + 2u] = clamp_log_scale(stored[3u * i + 2u]);
}
