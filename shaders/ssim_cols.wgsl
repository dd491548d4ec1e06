// Twin of the second (column) pass of gs_core::image_loss's `blur` over SSIM's five row-blurred
// moment planes, then of `ssim`'s per-pixel SSIM and its partials with respect to mu_x, the
// blurred x*x and the blurred x*y (scaled by 1 / values, the weight of the mean). One thread per
// value of the `[3][height][width]` planes.

//#import photometric.wgsl

@group(0) @binding(0) var<uniform> params: Photometric;
@group(0) @binding(1) var<storage, read> row_x: array<f32>;
@group(0) @binding(2) var<storage, read> row_y: array<f32>;
@group(0) @binding(3) var<storage, read> row_xx: array<f32>;
@group(0) @binding(4) var<storage, read> row_yy: array<f32>;
@group(0) @binding(5) var<storage, read> row_xy: array<f32>;
// Per value: SSIM, and its partials.
@group(0) @binding(6) var<storage, read_write> ssim_map: array<f32>;
@group(0) @binding(7) var<storage, read_write> d_mu: array<f32>;
@group(0) @binding(8) var<storage, read_write> d_xx: array<f32>;
@group(0) @binding(9) var<storage, read_write> d_xy: array<f32>;

@compute @workgroup_size(256)
fn main(
    @builtin(workgroup_id) wid: vec3u,
    @builtin(num_workgroups) nwg: vec3u,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = flat_index(wid, nwg, lid, 256u);
    let width = params.size.x;
    let height = params.size.y;
    if i >= params.size.w {
        return;
    }
    let at = plane_position(i, width, height);
    let plane = at.x * width * height;
    var mx = 0.0;
    var my = 0.0;
    var mxx = 0.0;
    var myy = 0.0;
    var mxy = 0.0;
    for (var t = 0; t < SSIM_TAPS; t++) {
        let row = i32(at.y) + t - SSIM_RADIUS;
        if row < 0 || row >= i32(height) {
            continue;
        }
        let q = plane + u32(row) * width + at.z;
        let w = tap(params.window, t);
        mx += w * row_x[q];
        my += w * row_y[q];
        mxx += w * row_xx[q];
        myy += w * row_yy[q];
        mxy += w * row_xy[q];
    }
    let inv_count = params.weights.y;
    let a1 = 2.0 * mx * my + SSIM_C1;
    let a2 = 2.0 * (mxy - mx * my) + SSIM_C2;
    let b1 = mx * mx + my * my + SSIM_C1;
    let b2 = (mxx - mx * mx) + (myy - my * my) + SSIM_C2;
    let den = b1 * b2;
    let s = a1 * a2 / den;
    ssim_map[i] = s;
    d_mu[i] = inv_count
        * ((2.0 * my * a2 - 2.0 * my * a1) / den - s * (2.0 * mx * b2 - 2.0 * mx * b1) / den);
    d_xx[i] = -inv_count * s / b2;
    d_xy[i] = inv_count * 2.0 * a1 / den;
}
