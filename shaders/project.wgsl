// Projection of one Gaussian (EWA, gsplat conventions) with the intermediate values its
// backward needs, shared by project_forward and project_backward. The importing kernel declares
// `view` and the parameter arrays `means`, `log_scales`, `quats`, `opacity_logits`, `sh_dc` and
// `sh_rest` (the layouts of gs_core::GaussianSet).

struct Projection {
    valid: bool,
    p_cam: vec3f,
    qn: vec4f,
    q_norm: f32,
    rot: mat3x3f,
    scale: vec3f,
    // rot * diag(scale).
    m: mat3x3f,
    cov_cam: mat3x3f,
    jac0: vec3f,
    jac1: vec3f,
    clamped: vec2<bool>,
    u: vec2f,
    conic: vec3f,
    mean2d: vec2f,
    radius: f32,
    opacity: f32,
    sigma_cut: f32,
    extent: vec2f,
    dir: vec3f,
    dir_norm: f32,
    color: vec3f,
    color_active: vec3<bool>,
}

fn camera_rotation() -> mat3x3f {
    return transpose(mat3x3f(view.rot0.xyz, view.rot1.xyz, view.rot2.xyz));
}

// The rotation matrix of the unit quaternion (w, x, y, z).
fn quat_to_rotation(q: vec4f) -> mat3x3f {
    let w = q.x;
    let x = q.y;
    let y = q.z;
    let z = q.w;
    let r0 = vec3f(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y));
    let r1 = vec3f(2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x));
    let r2 = vec3f(2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y));
    return transpose(mat3x3f(r0, r1, r2));
}

// True when every parameter of Gaussian i is finite and its quaternion is not zero.
fn gaussian_valid(i: u32) -> bool {
    var ok = true;
    for (var k = 0u; k < 3u; k++) {
        ok = ok && finite(means[3u * i + k]) && finite(log_scales[3u * i + k]);
        ok = ok && finite(sh_dc[3u * i + k]);
    }
    var nonzero = false;
    for (var k = 0u; k < 4u; k++) {
        let q = quats[4u * i + k];
        ok = ok && finite(q);
        nonzero = nonzero || q != 0.0;
    }
    ok = ok && nonzero && finite(opacity_logits[i]);
    let rest = 3u * view.scene.z;
    for (var k = 0u; k < rest; k++) {
        ok = ok && finite(sh_rest[rest * i + k]);
    }
    return ok;
}

fn load_mean(i: u32) -> vec3f {
    return vec3f(means[3u * i], means[3u * i + 1u], means[3u * i + 2u]);
}

// Projects Gaussian i; `valid` is false when it is culled.
fn project_gaussian(i: u32) -> Projection {
    var f: Projection;
    f.valid = false;
    if !gaussian_valid(i) {
        return f;
    }
    let mean = load_mean(i);
    let w = camera_rotation();
    let p_cam = vec3f(
        view.rot0.x * mean.x + view.rot0.y * mean.y + view.rot0.z * mean.z + view.rot0.w,
        view.rot1.x * mean.x + view.rot1.y * mean.y + view.rot1.z * mean.z + view.rot1.w,
        view.rot2.x * mean.x + view.rot2.y * mean.y + view.rot2.z * mean.z + view.rot2.w,
    );
    let z = p_cam.z;
    if !(z > NEAR_PLANE) || !(z < FAR_PLANE) || !finite3(p_cam) {
        return f;
    }
    f.p_cam = p_cam;
    let q = vec4f(quats[4u * i], quats[4u * i + 1u], quats[4u * i + 2u], quats[4u * i + 3u]);
    let q_norm = sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w);
    if !(q_norm > 0.0) || !finite(q_norm) {
        return f;
    }
    f.q_norm = q_norm;
    f.qn = q / q_norm;
    f.rot = quat_to_rotation(f.qn);
    f.scale = exp(vec3f(log_scales[3u * i], log_scales[3u * i + 1u], log_scales[3u * i + 2u]));
    f.m = mat3x3f(f.rot[0] * f.scale.x, f.rot[1] * f.scale.y, f.rot[2] * f.scale.z);
    let cov = f.m * transpose(f.m);
    f.cov_cam = w * cov * transpose(w);

    let fx = view.intrinsics.x;
    let fy = view.intrinsics.y;
    let ux_raw = p_cam.x / z;
    let uy_raw = p_cam.y / z;
    let ux = min(max(ux_raw, -view.lim.y), view.lim.x);
    let uy = min(max(uy_raw, -view.lim.w), view.lim.z);
    f.clamped = vec2<bool>(ux != ux_raw, uy != uy_raw);
    f.u = vec2f(ux, uy);
    f.jac0 = vec3f(fx / z, 0.0, -fx * ux / z);
    f.jac1 = vec3f(0.0, fy / z, -fy * uy / z);
    // cov2d = J cov_cam J^T + eps2d I; row r of J cov_cam is (J_r . column k of cov_cam).
    let jc0 = vec3f(dot(f.jac0, f.cov_cam[0]), dot(f.jac0, f.cov_cam[1]), dot(f.jac0, f.cov_cam[2]));
    let jc1 = vec3f(dot(f.jac1, f.cov_cam[0]), dot(f.jac1, f.cov_cam[1]), dot(f.jac1, f.cov_cam[2]));
    let a = dot(jc0, f.jac0) + EPS2D;
    let b = dot(jc0, f.jac1);
    let c = dot(jc1, f.jac1) + EPS2D;
    let det = a * c - b * b;
    if !(det > 0.0) || !finite(det) {
        return f;
    }
    f.conic = vec3f(c / det, -b / det, a / det);
    let mid = 0.5 * (a + c);
    let lambda = mid + sqrt(max(mid * mid - det, 0.1));
    f.radius = ceil(3.0 * sqrt(lambda));
    let z_proj = z + PROJECTION_EPS;
    f.mean2d = vec2f(fx * p_cam.x / z_proj + view.intrinsics.z,
        fy * p_cam.y / z_proj + view.intrinsics.w);
    if !finite3(f.conic) || !finite(f.mean2d.x) || !finite(f.mean2d.y) || !finite(f.radius) {
        return f;
    }
    // INRIA's only screen-space cull: an empty tile rectangle (its `getRect`, as the cpu
    // backend's `tile_rect`); a splat past the last column or row by more than its radius is
    // still drawn when its rectangle keeps the last tile.
    let tiles = vec2f(view.size.zw);
    let rect = inria_rect(f.mean2d, f.radius);
    if any(clamp(rect.hi, vec2f(0.0), tiles) <= clamp(rect.lo, vec2f(0.0), tiles)) {
        return f;
    }

    f.opacity = sigmoid(opacity_logits[i]);
    // At opacity exactly 1/255 the splat still reaches 1/255 where sigma is 0 (INRIA's skip is
    // `alpha < 1/255`).
    if f.opacity >= ALPHA_MIN {
        f.sigma_cut = log(f.opacity / ALPHA_MIN) + 1e-3;
    } else {
        f.sigma_cut = -1.0;
    }
    // The box of the ellipse sigma <= sigma_cut from the inverse of the stored conic (and the
    // 2D covariance's diagonal), with a 2 % and two-pixel margin: larger than the cpu backend's
    // box, as f32 cannot take the inverse as exactly; a larger box changes no output.
    var ex = a;
    var ey = c;
    let det_q = f.conic.x * f.conic.z - f.conic.y * f.conic.y;
    if det_q > 0.0 {
        ex = max(ex, f.conic.z / det_q);
        ey = max(ey, f.conic.x / det_q);
    }
    let reach = sqrt(2.0 * max(f.sigma_cut, 0.0)) * 1.02;
    f.extent = vec2f(reach * sqrt(ex) + 2.0, reach * sqrt(ey) + 2.0);

    let dv = mean - view.centre.xyz;
    f.dir_norm = sqrt(dot(dv, dv));
    if f.dir_norm > 0.0 {
        f.dir = dv / f.dir_norm;
    } else {
        f.dir = dv;
    }
    let basis = sh_basis(view.scene.y, f.dir);
    let k_rest = view.scene.z;
    for (var ch = 0u; ch < 3u; ch++) {
        var v = basis[0] * sh_dc[3u * i + ch] + 0.5;
        for (var k = 0u; k < k_rest; k++) {
            v += basis[k + 1u] * sh_rest[3u * k_rest * i + 3u * k + ch];
        }
        // INRIA's `clamped` is `result < 0`: at exactly 0 the gradient passes.
        f.color_active[ch] = v >= 0.0;
        f.color[ch] = max(v, 0.0);
    }
    f.valid = true;
    return f;
}
