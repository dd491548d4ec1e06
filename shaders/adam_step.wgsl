// Twin of gs_core::adam::Adam::step for one parameter group: PyTorch's Adam update with bias
// correction, the step size and the inverse root of the second bias correction given.

struct AdamStep {
    step_size: f32,
    inv_bc2_sqrt: f32,
    beta1: f32,
    beta2: f32,
    eps: f32,
    unused0: u32,
    unused1: u32,
    unused2: u32,
}

//#import chunk.wgsl

@group(0) @binding(0) var<uniform> params: AdamStep;
@group(0) @binding(1) var<storage, read_write> values: array<f32>;
@group(0) @binding(2) var<storage, read> grads: array<f32>;
@group(0) @binding(3) var<storage, read_write> m: array<f32>;
@group(0) @binding(4) var<storage, read_write> v: array<f32>;

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
    let g = grads[i];
    let mi = params.beta1 * m[i] + (1.0 - params.beta1) * g;
    let vi = params.beta2 * v[i] + (1.0 - params.beta2) * g * g;
    m[i] = mi;
    v[i] = vi;
    values[i] -= params.step_size * mi / (sqrt(vi) * params.inv_bc2_sqrt + params.eps);
}
