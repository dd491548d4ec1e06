// Twin of the end of gs_core::image_loss's `ssim` and of `PhotometricObjective::evaluate` as
// `ClampedObjective` and the training step's `checked_value` hand it on: the column pass of the
// blur of SSIM's partials, dL/dimage `(1 - lambda) dL1 - lambda dSSIM` (L1's `sign(x - y) / values`,
// 0 at a tie), zero where a clamped render lies outside [0, 1] or is NaN, times the batch's
// factor; and per workgroup the sums of |x - y|, of SSIM and of the squared difference of the
// render and the target clamped to [0, 1] (PSNR's), which the host adds in f64, and the count of
// non-finite values of dL/dimage (the training step's check). One thread per value of the
// `[3][height][width]` planes.

//#import photometric.wgsl

@group(0) @binding(0) var<uniform> params: Photometric;
@group(0) @binding(1) var<storage, read> render: array<f32>;
@group(0) @binding(2) var<storage, read> truth: array<f32>;
@group(0) @binding(3) var<storage, read> ssim_map: array<f32>;
@group(0) @binding(4) var<storage, read> row_mu: array<f32>;
@group(0) @binding(5) var<storage, read> row_xx: array<f32>;
@group(0) @binding(6) var<storage, read> row_xy: array<f32>;
// dL/dimage, HWC.
@group(0) @binding(7) var<storage, read_write> grad: array<f32>;
// Per workgroup: the sums of |x - y|, SSIM and the clamped squared difference, and the count of
// non-finite gradient values.
@group(0) @binding(8) var<storage, read_write> partials: array<f32>;

var<workgroup> sums: array<vec4f, 256>;

@compute @workgroup_size(256)
fn main(
    @builtin(workgroup_id) wid: vec3u,
    @builtin(num_workgroups) nwg: vec3u,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = flat_index(wid, nwg, lid, 256u);
    let width = params.size.x;
    let height = params.size.y;
    var mine = vec4f(0.0);
    if i < params.size.w {
        let at = plane_position(i, width, height);
        let plane = at.x * width * height;
        var g_mu = 0.0;
        var g_xx = 0.0;
        var g_xy = 0.0;
        for (var t = 0; t < SSIM_TAPS; t++) {
            let row = i32(at.y) + t - SSIM_RADIUS;
            if row < 0 || row >= i32(height) {
                continue;
            }
            let q = plane + u32(row) * width + at.z;
            let w = tap(params.window, t);
            g_mu += w * row_mu[q];
            g_xx += w * row_xx[q];
            g_xy += w * row_xy[q];
        }
        let q = 3u * (at.y * width + at.z) + at.x;
        let clamped = params.size.z == 1u;
        let raw = render[q];
        let x = seen(raw, clamped);
        let y = truth[q];
        let inv_count = params.weights.y;
        var g1 = 0.0;
        if x > y {
            g1 = inv_count;
        } else if x < y {
            g1 = -inv_count;
        }
        let g_ssim = g_mu + 2.0 * x * g_xx + y * g_xy;
        let lambda = params.weights.x;
        var g = (1.0 - lambda) * g1 - lambda * g_ssim;
        if clamped && (is_nan(raw) || raw < 0.0 || raw > 1.0) {
            g = 0.0;
        }
        g = g * params.weights.z;
        grad[q] = g;
        let d = seen(raw, true) - clamp(y, 0.0, 1.0);
        mine = vec4f(abs(x - y), ssim_map[i], d * d, select(1.0, 0.0, finite(g)));
    }
    sums[lid] = mine;
    for (var stride = 128u; stride > 0u; stride = stride / 2u) {
        workgroupBarrier();
        if lid < stride {
            sums[lid] = sums[lid] + sums[lid + stride];
        }
    }
    if lid == 0u {
        let k = 4u * flat_workgroup(wid, nwg);
        partials[k] = sums[0].x;
        partials[k + 1u] = sums[0].y;
        partials[k + 2u] = sums[0].z;
        partials[k + 3u] = sums[0].w;
    }
}
