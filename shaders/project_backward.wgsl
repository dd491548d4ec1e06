// Twin of gs_core::raster::project::project_backward: the gradient of every Gaussian parameter
// of the chunk from its splat's accumulated gradient (`accum`, SPLAT_GRADS per Gaussian). Only the groups
// whose flag is set in view.scene.w are computed and written; the others may be bound to
// placeholder buffers.

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
@group(0) @binding(7) var<storage, read> accum: array<f32>;
@group(0) @binding(8) var<storage, read_write> grad_means: array<f32>;
@group(0) @binding(9) var<storage, read_write> grad_log_scales: array<f32>;
@group(0) @binding(10) var<storage, read_write> grad_quats: array<f32>;
@group(0) @binding(11) var<storage, read_write> grad_opacity_logits: array<f32>;
@group(0) @binding(12) var<storage, read_write> grad_sh_dc: array<f32>;
@group(0) @binding(13) var<storage, read_write> grad_sh_rest: array<f32>;

// Entry (r, c) of a matrix in math notation (WGSL matrices are indexed by column).
fn at(m: mat3x3f, r: u32, c: u32) -> f32 {
    return m[c][r];
}

// The gradient with respect to the unit quaternion (w, x, y, z) given the gradient g of the
// rotation matrix quat_to_rotation builds from it.
fn quat_to_rotation_backward(q: vec4f, g: mat3x3f) -> vec4f {
    let w = q.x;
    let x = q.y;
    let y = q.z;
    let z = q.w;
    let gw = 2.0 * (x * (at(g, 2u, 1u) - at(g, 1u, 2u)) + y * (at(g, 0u, 2u) - at(g, 2u, 0u))
        + z * (at(g, 1u, 0u) - at(g, 0u, 1u)));
    let gx = 2.0 * (-2.0 * x * (at(g, 1u, 1u) + at(g, 2u, 2u)) + y * (at(g, 1u, 0u) + at(g, 0u, 1u))
        + z * (at(g, 2u, 0u) + at(g, 0u, 2u)) + w * (at(g, 2u, 1u) - at(g, 1u, 2u)));
    let gy = 2.0 * (-2.0 * y * (at(g, 0u, 0u) + at(g, 2u, 2u)) + x * (at(g, 1u, 0u) + at(g, 0u, 1u))
        + z * (at(g, 2u, 1u) + at(g, 1u, 2u)) + w * (at(g, 0u, 2u) - at(g, 2u, 0u)));
    let gz = 2.0 * (-2.0 * z * (at(g, 0u, 0u) + at(g, 1u, 1u)) + x * (at(g, 2u, 0u) + at(g, 0u, 2u))
        + y * (at(g, 2u, 1u) + at(g, 1u, 2u)) + w * (at(g, 1u, 0u) - at(g, 0u, 1u)));
    return vec4f(gw, gx, gy, gz);
}

fn outer(a: vec3f, b: vec3f) -> mat3x3f {
    return mat3x3f(a * b.x, a * b.y, a * b.z);
}

fn write_zero(i: u32, flags: u32) {
    let k_rest = view.scene.z;
    for (var k = 0u; k < 3u; k++) {
        if (flags & NEED_MEANS) != 0u {
            grad_means[3u * i + k] = 0.0;
        }
        if (flags & NEED_SCALES) != 0u {
            grad_log_scales[3u * i + k] = 0.0;
        }
        if (flags & NEED_SH_DC) != 0u {
            grad_sh_dc[3u * i + k] = 0.0;
        }
    }
    if (flags & NEED_QUATS) != 0u {
        for (var k = 0u; k < 4u; k++) {
            grad_quats[4u * i + k] = 0.0;
        }
    }
    if (flags & NEED_OPACITY) != 0u {
        grad_opacity_logits[i] = 0.0;
    }
    if (flags & NEED_SH_REST) != 0u {
        for (var k = 0u; k < 3u * k_rest; k++) {
            grad_sh_rest[3u * k_rest * i + k] = 0.0;
        }
    }
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
    let flags = view.scene.w;
    let f = project_gaussian(i);
    if !f.valid {
        write_zero(i, flags);
        return;
    }
    let base = SPLAT_GRADS * i;
    let sg_mean2d = vec2f(accum[base], accum[base + 1u]);
    let sg_conic = vec3f(accum[base + 2u], accum[base + 3u], accum[base + 4u]);
    let sg_opacity = accum[base + 5u];
    let sg_color = vec3f(accum[base + 6u], accum[base + 7u], accum[base + 8u]);
    let sg_depth = accum[base + 9u];

    let o = f.opacity;
    if (flags & NEED_OPACITY) != 0u {
        grad_opacity_logits[i] = sg_opacity * o * (1.0 - o);
    }
    let g_raw = select(vec3f(0.0), sg_color, f.color_active);
    let degree = view.scene.y;
    let k_rest = view.scene.z;
    let basis = sh_basis(degree, f.dir);
    if (flags & NEED_SH_DC) != 0u {
        for (var ch = 0u; ch < 3u; ch++) {
            grad_sh_dc[3u * i + ch] = basis[0] * g_raw[ch];
        }
    }
    if (flags & NEED_SH_REST) != 0u {
        for (var k = 0u; k < k_rest; k++) {
            for (var ch = 0u; ch < 3u; ch++) {
                grad_sh_rest[3u * k_rest * i + 3u * k + ch] = basis[k + 1u] * g_raw[ch];
            }
        }
    }
    if (flags & NEED_GEOMETRY) == 0u {
        return;
    }

    var g_mean = vec3f(0.0);
    if k_rest > 0u {
        let basis_grad = sh_basis_grad(degree, f.dir);
        var g_dir = vec3f(0.0);
        for (var k = 0u; k < k_rest; k++) {
            let r = 3u * k_rest * i + 3u * k;
            let w = sh_rest[r] * g_raw.x + sh_rest[r + 1u] * g_raw.y + sh_rest[r + 2u] * g_raw.z;
            g_dir += w * basis_grad[k + 1u];
        }
        if f.dir_norm > 0.0 {
            g_mean = (g_dir - f.dir * dot(f.dir, g_dir)) / f.dir_norm;
        }
    }

    // Conic -> 2D covariance: d(S^-1) = -S^-1 dS S^-1, times INRIA's
    // det^2 / (det^2 + CONIC_GRAD_EPS) (det of S; `1 / det` is the conic's).
    let inv = mat2x2f(vec2f(f.conic.x, f.conic.y), vec2f(f.conic.y, f.conic.z));
    let det_conic = f.conic.x * f.conic.z - f.conic.y * f.conic.y;
    let damp = 1.0 / (1.0 + CONIC_GRAD_EPS * det_conic * det_conic);
    let gm = mat2x2f(vec2f(sg_conic.x, 0.5 * sg_conic.y), vec2f(0.5 * sg_conic.y, sg_conic.z));
    let g_cov2d = (inv * gm * inv) * -damp;
    let g00 = g_cov2d[0][0];
    let g01 = g_cov2d[1][0];
    let g10 = g_cov2d[0][1];
    let g11 = g_cov2d[1][1];

    // cov2d = J Sc J^T: dSc = J^T G J, dJ = 2 G J Sc.
    let j0 = f.jac0;
    let j1 = f.jac1;
    let g_cov_cam = g00 * outer(j0, j0) + g01 * outer(j0, j1) + g10 * outer(j1, j0)
        + g11 * outer(j1, j1);
    let c = f.cov_cam;
    let jc0 = vec3f(dot(j0, c[0]), dot(j0, c[1]), dot(j0, c[2]));
    let jc1 = vec3f(dot(j1, c[0]), dot(j1, c[1]), dot(j1, c[2]));
    let g_jac0 = 2.0 * (g00 * jc0 + g01 * jc1);
    let g_jac1 = 2.0 * (g10 * jc0 + g11 * jc1);

    // Jacobian and mean2d -> camera-space position.
    let tx = f.p_cam.x;
    let ty = f.p_cam.y;
    let tz = f.p_cam.z;
    let fx = view.intrinsics.x;
    let fy = view.intrinsics.y;
    let tz2 = tz * tz;
    var g_p = vec3f(0.0);
    g_p.z += g_jac0.x * (-fx / tz2) + g_jac1.y * (-fy / tz2) + g_jac0.z * (fx * f.u.x / tz2)
        + g_jac1.z * (fy * f.u.y / tz2);
    let g_u = vec2f(g_jac0.z * (-fx / tz), g_jac1.z * (-fy / tz));
    // Where x/z is clamped, INRIA's `dL_dtz` takes J02 = -fx t.x / tz^2 with the clamped
    // t.x = u tz as if t.x did not depend on tz: twice the derivative through the clamp.
    if !f.clamped.x {
        g_p.x += g_u.x / tz;
        g_p.z -= g_u.x * tx / tz2;
    } else {
        g_p.z -= g_u.x * f.u.x / tz;
    }
    if !f.clamped.y {
        g_p.y += g_u.y / tz;
        g_p.z -= g_u.y * ty / tz2;
    } else {
        g_p.z -= g_u.y * f.u.y / tz;
    }
    // mean2d = f t / (tz + PROJECTION_EPS) + c.
    let tz_proj = tz + PROJECTION_EPS;
    g_p.x += sg_mean2d.x * fx / tz_proj;
    g_p.y += sg_mean2d.y * fy / tz_proj;
    g_p.z -= (sg_mean2d.x * fx * tx + sg_mean2d.y * fy * ty) / (tz_proj * tz_proj);
    g_p.z += sg_depth;
    let w = camera_rotation();
    let g_world = transpose(w) * g_p;
    if (flags & NEED_MEANS) != 0u {
        let gm3 = g_mean + g_world;
        grad_means[3u * i] = gm3.x;
        grad_means[3u * i + 1u] = gm3.y;
        grad_means[3u * i + 2u] = gm3.z;
    }

    // cov_cam = W cov W^T: dcov = W^T dSc W; cov = M M^T: dM = (dcov + dcov^T) M.
    let g_cov = transpose(w) * g_cov_cam * w;
    let g_m = (g_cov + transpose(g_cov)) * f.m;
    let g_rot = mat3x3f(g_m[0] * f.scale.x, g_m[1] * f.scale.y, g_m[2] * f.scale.z);
    if (flags & NEED_SCALES) != 0u {
        for (var k = 0u; k < 3u; k++) {
            grad_log_scales[3u * i + k] = dot(g_m[k], f.rot[k]) * f.scale[k];
        }
    }
    if (flags & NEED_QUATS) == 0u {
        return;
    }
    let g_qn = quat_to_rotation_backward(f.qn, g_rot);
    let qdot = dot(f.qn, g_qn);
    let g_q = (g_qn - f.qn * qdot) / f.q_norm;
    for (var k = 0u; k < 4u; k++) {
        grad_quats[4u * i + k] = g_q[k];
    }
}
