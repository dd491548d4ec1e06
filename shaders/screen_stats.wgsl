// Twin of gs_core::densify::ScreenStats::add_view: adds one view's densification statistics of
// every Gaussian of the chunk that the view shows (its splat visible: INRIA's `radii > 0`): the
// norm of its projected centre's gradient in normalized device coordinates (the pixel gradient,
// the first two of its SPLAT_GRADS slots in `accum`, times width / 2 and height / 2) to
// `grad_sum`, and 1 to `count`. One thread a Gaussian: no atomics.

//#import helpers.wgsl
//#import chunk.wgsl

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var<storage, read> splats: array<Splat>;
@group(0) @binding(2) var<storage, read> accum: array<f32>;
@group(0) @binding(3) var<storage, read_write> grad_sum: array<f32>;
@group(0) @binding(4) var<storage, read_write> count: array<u32>;

@compute @workgroup_size(256)
fn main(
    @builtin(workgroup_id) wid: vec3u,
    @builtin(num_workgroups) nwg: vec3u,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = chunk_item(wid, nwg, lid);
    if i >= chunk.count || splats[i].cut_radius.z != 1.0 {
        return;
    }
    let half = vec2f(f32(view.size.x), f32(view.size.y)) * 0.5;
    let base = SPLAT_GRADS * i;
    let g = vec2f(accum[base], accum[base + 1u]) * half;
    grad_sum[i] += length(g);
    count[i] += 1u;
}
