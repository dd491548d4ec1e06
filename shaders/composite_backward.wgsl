// Twin of gs_core::raster::composite::backward: one workgroup per tile, one thread per pixel,
// each pixel walking back to front from its last contributor and adding its share of each
// splat's gradient to the splat's slots in `accum0` to `accum3` (SPLAT_GRADS per Gaussian, in
// parts as the splats are) and the background's to `background_grad`, with atomic adds, as
// the reference 3DGS rasterizer does; slots of frozen parameter groups cost nothing.

//#import helpers.wgsl
//#import splat_parts.wgsl
//#import accumulate.wgsl

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(5) var<storage, read> tile_ids: array<u32>;
@group(0) @binding(6) var<storage, read> ranges: array<vec2u>;
@group(0) @binding(7) var<storage, read> final_t: array<f32>;
@group(0) @binding(8) var<storage, read> n_contrib: array<u32>;
@group(0) @binding(9) var<storage, read> grad_rgb: array<f32>;
@group(0) @binding(10) var<storage, read> grad_alpha: array<f32>;
@group(0) @binding(11) var<storage, read> grad_depth: array<f32>;
@group(0) @binding(12) var<storage, read_write> accum0: array<GradAtomic>;
@group(0) @binding(13) var<storage, read_write> accum1: array<GradAtomic>;
@group(0) @binding(14) var<storage, read_write> accum2: array<GradAtomic>;
@group(0) @binding(15) var<storage, read_write> accum3: array<GradAtomic>;
@group(0) @binding(16) var<storage, read_write> background_grad: array<GradAtomic>;

const BATCH: u32 = 64u;

var<workgroup> batch: array<Splat, BATCH>;
var<workgroup> batch_ids: array<u32, BATCH>;
var<workgroup> partial: array<vec3f, 256>;
var<workgroup> max_count: atomic<u32>;
var<workgroup> shared_u32: u32;

// True when gradient slot q of a splat is needed by some unfrozen parameter group.
fn slot_needed(q: u32) -> bool {
    let flags = view.scene.w;
    let geometry = (flags & NEED_GEOMETRY) != 0u;
    if q < 5u || q == 9u {
        return geometry;
    }
    if q == 5u {
        return (flags & NEED_OPACITY) != 0u;
    }
    return geometry || (flags & (NEED_SH_DC | NEED_SH_REST)) != 0u;
}

@compute @workgroup_size(16, 16)
fn main(
    @builtin(workgroup_id) wid: vec3u,
    @builtin(local_invocation_id) lid3: vec3u,
    @builtin(local_invocation_index) lid: u32,
) {
    let flags = view.scene.w;
    let geometry = (flags & NEED_GEOMETRY) != 0u;
    let origin = wid.xy * TILE_SIZE;
    let pix = origin + lid3.xy;
    let inside = pix.x < view.size.x && pix.y < view.size.y;
    let range = ranges[wid.y * view.size.z + wid.x];
    let px = f32(pix.x) + 0.5;
    let py = f32(pix.y) + 0.5;

    var trans = 0.0;
    var t_final = 0.0;
    var count = 0u;
    var g_rgb = vec3f(0.0);
    var g_a = 0.0;
    var g_d = 0.0;
    if inside {
        let p = pix.y * view.size.x + pix.x;
        trans = final_t[p];
        t_final = trans;
        count = n_contrib[p];
        g_rgb = vec3f(grad_rgb[3u * p], grad_rgb[3u * p + 1u], grad_rgb[3u * p + 2u]);
        if (flags & HAS_GRAD_ALPHA) != 0u {
            g_a = grad_alpha[p];
        }
        if (flags & HAS_GRAD_DEPTH) != 0u {
            g_d = grad_depth[p];
        }
    }
    var behind = view.background.xyz;
    var behind_depth = 0.0;

    // The background's gradient: every pixel shows it with weight T_final; summed over the
    // tile, then added once.
    partial[lid] = t_final * g_rgb;
    if lid == 0u {
        atomicStore(&max_count, 0u);
    }
    for (var stride = 128u; stride > 0u; stride /= 2u) {
        workgroupBarrier();
        if lid < stride {
            partial[lid] += partial[lid + stride];
        }
    }
    workgroupBarrier();
    if lid < 3u {
        accumulate_slot(BACKGROUND_PART, lid, partial[0][lid]);
    }
    atomicMax(&max_count, count);
    workgroupBarrier();
    if lid == 0u {
        shared_u32 = atomicLoad(&max_count);
    }
    let end = range.x + workgroupUniformLoad(&shared_u32);

    var hi = end;
    while hi > range.x {
        var lo = range.x;
        if hi - range.x > BATCH {
            lo = hi - BATCH;
        }
        workgroupBarrier();
        if lid < hi - lo {
            let gid = tile_ids[lo + lid];
            batch_ids[lid] = gid;
            batch[lid] = load_splat(gid);
        }
        workgroupBarrier();
        for (var j = hi - lo; j > 0u; j--) {
            let s = batch[j - 1u];
            let k = lo + j - 1u - range.x;
            var g: array<f32, SPLAT_GRADS>;
            if inside && k < count && in_box(s, origin, lid3.x, lid3.y) {
                let dx = s.mean_extent.x - px;
                let dy = s.mean_extent.y - py;
                let sigma = mahalanobis(s.conic_depth.xyz, dx, dy);
                let falloff = exp(-sigma);
                let opacity = s.color_opacity.w;
                let a = min(opacity * falloff, ALPHA_MAX);
                if sigma >= 0.0 && sigma <= s.cut_radius.x && a >= ALPHA_MIN {
                    let one_minus = 1.0 - a;
                    let t_before = trans / one_minus;
                    let w = a * t_before;
                    var g_alpha = g_a * t_final / one_minus;
                    for (var ch = 0u; ch < 3u; ch++) {
                        let c = s.color_opacity[ch];
                        g[6u + ch] = w * g_rgb[ch];
                        g_alpha += t_before * (c - behind[ch]) * g_rgb[ch];
                        behind[ch] = a * c + one_minus * behind[ch];
                    }
                    let z = s.conic_depth.w;
                    g[9] = w * g_d;
                    g_alpha += t_before * (z - behind_depth) * g_d;
                    behind_depth = a * z + one_minus * behind_depth;
                    trans = t_before;
                    // The cap at ALPHA_MAX passes the gradient as if it were not there
                    // (INRIA's rule, as the cpu backward).
                    g[5] = g_alpha * falloff;
                    if geometry {
                        let conic = s.conic_depth.xyz;
                        let g_sigma = -g_alpha * opacity * falloff;
                        g[2] = g_sigma * 0.5 * dx * dx;
                        g[3] = g_sigma * dx * dy;
                        g[4] = g_sigma * 0.5 * dy * dy;
                        g[0] = g_sigma * (conic.x * dx + conic.y * dy);
                        g[1] = g_sigma * (conic.y * dx + conic.z * dy);
                    }
                    for (var q = 0u; q < SPLAT_GRADS; q++) {
                        if g[q] != 0.0 && slot_needed(q) {
                            accumulate(batch_ids[j - 1u], q, g[q]);
                        }
                    }
                }
            }
        }
        hi = lo;
    }
}
