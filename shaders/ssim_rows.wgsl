// Twin of the first (row) pass of gs_core::image_loss's `blur` over SSIM's five moment planes of
// the seen render x and the target y: x, y, x*x, y*y and x*y, each blurred along its row. One
// thread per value of the `[3][height][width]` planes.

//#import photometric.wgsl

@group(0) @binding(0) var<uniform> params: Photometric;
// The render and the target, HWC.
@group(0) @binding(1) var<storage, read> render: array<f32>;
@group(0) @binding(2) var<storage, read> truth: array<f32>;
// The row-blurred planes of x, y, x*x, y*y, x*y.
@group(0) @binding(3) var<storage, read_write> row_x: array<f32>;
@group(0) @binding(4) var<storage, read_write> row_y: array<f32>;
@group(0) @binding(5) var<storage, read_write> row_xx: array<f32>;
@group(0) @binding(6) var<storage, read_write> row_yy: array<f32>;
@group(0) @binding(7) var<storage, read_write> row_xy: array<f32>;

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
    let clamped = params.size.z == 1u;
    var sx = 0.0;
    var sy = 0.0;
    var sxx = 0.0;
    var syy = 0.0;
    var sxy = 0.0;
    for (var t = 0; t < SSIM_TAPS; t++) {
        let col = i32(at.z) + t - SSIM_RADIUS;
        if col < 0 || col >= i32(width) {
            continue;
        }
        let q = 3u * (at.y * width + u32(col)) + at.x;
        let x = seen(render[q], clamped);
        let y = truth[q];
        let w = tap(params.window, t);
        sx += w * x;
        sy += w * y;
        sxx += w * (x * x);
        syy += w * (y * y);
        sxy += w * (x * y);
    }
    row_x[i] = sx;
    row_y[i] = sy;
    row_xx[i] = sxx;
    row_yy[i] = syy;
    row_xy[i] = sxy;
}
