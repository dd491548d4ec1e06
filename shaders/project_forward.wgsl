// Twin of gs_core::raster::project::project: projects every Gaussian of the chunk to its
// splat, writes its depth as a sort key (culled Gaussians sort last with 0xffffffff) and the
// identity order (the Gaussian's index in the scene).

//#import helpers.wgsl
//#import sh.wgsl
//#import project.wgsl
//#import chunk.wgsl

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var<storage, read> means: array<f32>;
@group(0) @binding(2) var<storage, read> log_scales: array<f32>;
@group(0) @binding(3) var<storage, read> quats: array<f32>;
@group(0) @binding(4) var<storage, read> opacity_logits: array<f32>;
@group(0) @binding(5) var<storage, read> sh_dc: array<f32>;
@group(0) @binding(6) var<storage, read> sh_rest: array<f32>;
@group(0) @binding(7) var<storage, read_write> splats: array<Splat>;
@group(0) @binding(8) var<storage, read_write> depth_keys: array<u32>;
@group(0) @binding(9) var<storage, read_write> order: array<u32>;

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
    order[i] = chunk.first + i;
    let f = project_gaussian(i);
    if !f.valid {
        splats[i] = Splat(vec4f(0.0), vec4f(0.0), vec4f(0.0), vec4f(0.0));
        depth_keys[i] = 0xffffffffu;
        return;
    }
    splats[i] = Splat(
        vec4f(f.mean2d, f.extent),
        vec4f(f.conic, f.p_cam.z),
        vec4f(f.color, f.opacity),
        vec4f(f.sigma_cut, f.radius, 1.0, 0.0),
    );
    // Depths are positive: their bits sort as unsigned integers.
    depth_keys[i] = bitcast<u32>(f.p_cam.z);
}
