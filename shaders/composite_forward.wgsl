// Twin of gs_core::raster::composite::forward: one workgroup per 16x16 tile, one thread per
// pixel, the tile's splats front to back in batches staged in workgroup memory. A pixel stops
// before the splat that would take its transmittance below TRANSMITTANCE_MIN, and the
// workgroup stops when all of its pixels have.

//#import helpers.wgsl
//#import splat_parts.wgsl

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(5) var<storage, read> tile_ids: array<u32>;
@group(0) @binding(6) var<storage, read> ranges: array<vec2u>;
@group(0) @binding(7) var<storage, read_write> out_rgb: array<f32>;
@group(0) @binding(8) var<storage, read_write> out_alpha: array<f32>;
@group(0) @binding(9) var<storage, read_write> out_depth: array<f32>;
@group(0) @binding(10) var<storage, read_write> final_t: array<f32>;
@group(0) @binding(11) var<storage, read_write> n_contrib: array<u32>;

const BATCH: u32 = 128u;

var<workgroup> batch: array<Splat, BATCH>;
var<workgroup> done_count: atomic<u32>;
var<workgroup> all_done: u32;

@compute @workgroup_size(16, 16)
fn main(
    @builtin(workgroup_id) wid: vec3u,
    @builtin(local_invocation_id) lid3: vec3u,
    @builtin(local_invocation_index) lid: u32,
) {
    let origin = wid.xy * TILE_SIZE;
    let pix = origin + lid3.xy;
    let inside = pix.x < view.size.x && pix.y < view.size.y;
    let range = ranges[wid.y * view.size.z + wid.x];
    let px = f32(pix.x) + 0.5;
    let py = f32(pix.y) + 0.5;

    var trans = 1.0;
    var color = vec3f(0.0);
    var depth = 0.0;
    var last = 0u;
    var done = !inside;
    if lid == 0u {
        atomicStore(&done_count, 0u);
    }
    workgroupBarrier();
    if done {
        atomicAdd(&done_count, 1u);
    }
    for (var start = range.x; start < range.y; start += BATCH) {
        workgroupBarrier();
        if lid == 0u {
            all_done = atomicLoad(&done_count);
        }
        if workgroupUniformLoad(&all_done) == 256u {
            break;
        }
        if lid < BATCH && start + lid < range.y {
            batch[lid] = load_splat(tile_ids[start + lid]);
        }
        workgroupBarrier();
        let count = min(BATCH, range.y - start);
        for (var j = 0u; j < count && !done; j++) {
            let s = batch[j];
            if !in_box(s, origin, lid3.x, lid3.y) {
                continue;
            }
            let dx = s.mean_extent.x - px;
            let dy = s.mean_extent.y - py;
            let sigma = mahalanobis(s.conic_depth.xyz, dx, dy);
            if sigma < 0.0 || sigma > s.cut_radius.x {
                continue;
            }
            let alpha = min(s.color_opacity.w * exp(-sigma), ALPHA_MAX);
            if alpha < ALPHA_MIN {
                continue;
            }
            let next = trans * (1.0 - alpha);
            if next < TRANSMITTANCE_MIN {
                done = true;
                atomicAdd(&done_count, 1u);
                continue;
            }
            let w = alpha * trans;
            color += w * s.color_opacity.xyz;
            depth += w * s.conic_depth.w;
            trans = next;
            last = start + j - range.x + 1u;
        }
    }
    if inside {
        let p = pix.y * view.size.x + pix.x;
        for (var ch = 0u; ch < 3u; ch++) {
            out_rgb[3u * p + ch] = color[ch] + trans * view.background[ch];
        }
        out_alpha[p] = 1.0 - trans;
        out_depth[p] = depth;
        final_t[p] = trans;
        n_contrib[p] = last;
    }
}
