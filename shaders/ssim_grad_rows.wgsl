// Twin of the first (row) pass of gs_core::image_loss's `blur` over the three partial planes of
// SSIM (the window is symmetric: the blur is its own transpose, so this back-propagates the
// blur of the moments). One thread per value of the `[3][height][width]` planes.

//#import photometric.wgsl

@group(0) @binding(0) var<uniform> params: Photometric;
@group(0) @binding(1) var<storage, read> d_mu: array<f32>;
@group(0) @binding(2) var<storage, read> d_xx: array<f32>;
@group(0) @binding(3) var<storage, read> d_xy: array<f32>;
@group(0) @binding(4) var<storage, read_write> row_mu: array<f32>;
@group(0) @binding(5) var<storage, read_write> row_xx: array<f32>;
@group(0) @binding(6) var<storage, read_write> row_xy: array<f32>;

@compute @workgroup_size(256)
fn main(
    @builtin(workgroup_id) wid: vec3u,
    @builtin(num_workgroups) nwg: vec3u,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = flat_index(wid, nwg, lid, 256u);
    let width = params.size.x;
    if i >= params.size.w {
        return;
    }
    let at = plane_position(i, width, params.size.y);
    let start = i - at.z;
    var smu = 0.0;
    var sxx = 0.0;
    var sxy = 0.0;
    for (var t = 0; t < SSIM_TAPS; t++) {
        let col = i32(at.z) + t - SSIM_RADIUS;
        if col < 0 || col >= i32(width) {
            continue;
        }
        let q = start + u32(col);
        let w = tap(params.window, t);
        smu += w * d_mu[q];
        sxx += w * d_xx[q];
        sxy += w * d_xy[q];
    }
    row_mu[i] = smu;
    row_xx[i] = sxx;
    row_xy[i] = sxy;
}
