// Shared constants, types and small functions of the rasterizer kernels; the values are those of
// gs_core::raster (docs/conventions.md).

const TILE_SIZE: u32 = 16u;
const EPS2D: f32 = 0.3;
const NEAR_PLANE: f32 = 0.2;
const PROJECTION_EPS: f32 = 1e-7;
const CONIC_GRAD_EPS: f32 = 1e-7;
const FAR_PLANE: f32 = 1e10;
const ALPHA_MAX: f32 = 0.99;
const ALPHA_MIN: f32 = 1.0 / 255.0;
const TRANSMITTANCE_MIN: f32 = 1e-4;
// Gradient slots per splat in the accumulation buffer: mean2d (2), conic (3), opacity,
// colour (3), depth.
const SPLAT_GRADS: u32 = 10u;
// Parts a splat array (and the splat gradients) may be split into.
const SPLAT_PARTS: u32 = 4u;

// The camera, image and scene of one render (the Rust twin is `ViewUniform`).
struct View {
    // World-to-camera rotation rows; `w` holds the translation.
    rot0: vec4f,
    rot1: vec4f,
    rot2: vec4f,
    // Camera centre in world space (xyz).
    centre: vec4f,
    // fx, fy, cx, cy.
    intrinsics: vec4f,
    // Jacobian clamp of x/z and y/z: [-lim.y, lim.x] and [-lim.w, lim.z].
    lim: vec4f,
    // Background RGB.
    background: vec4f,
    // width, height, tiles_x, tiles_y.
    size: vec4u,
    // Gaussian count, SH degree, SH coefficients per channel minus one, gradient flags.
    scene: vec4u,
    // Splats (and splat gradient records) per part of a split array (splat_parts.wgsl).
    parts: vec4u,
}

// Gradient flags in `View.scene.w`: the parameter groups that need a gradient, and which
// output gradients are given.
const NEED_MEANS: u32 = 1u;
const NEED_SCALES: u32 = 2u;
const NEED_QUATS: u32 = 4u;
const NEED_OPACITY: u32 = 8u;
const NEED_SH_DC: u32 = 16u;
const NEED_SH_REST: u32 = 32u;
const HAS_GRAD_ALPHA: u32 = 64u;
const HAS_GRAD_DEPTH: u32 = 128u;
const NEED_GEOMETRY: u32 = 7u;

// A projected Gaussian: what compositing needs.
struct Splat {
    // mean2d (xy), half-extents of the box where it can reach ALPHA_MIN (zw).
    mean_extent: vec4f,
    // Conic (a, b, c) and camera depth.
    conic_depth: vec4f,
    // RGB and opacity.
    color_opacity: vec4f,
    // sigma_cut, radius, 1 when visible (0 when culled), unused.
    cut_radius: vec4f,
}

// The flat index of item `local` of a workgroup of `size` threads in a grid that may be split
// over x and y (dispatches past the 65535-workgroup limit per dimension).
fn flat_index(wid: vec3u, nwg: vec3u, local: u32, size: u32) -> u32 {
    return (wid.y * nwg.x + wid.x) * size + local;
}

// The flat index of a workgroup in a grid split over x and y.
fn flat_workgroup(wid: vec3u, nwg: vec3u) -> u32 {
    return wid.y * nwg.x + wid.x;
}

// True unless `x` is NaN or infinite (by its bits: no fast-math assumption can remove it).
fn finite(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

fn finite3(v: vec3f) -> bool {
    return finite(v.x) && finite(v.y) && finite(v.z);
}

// The Mahalanobis term of the conic (a, b, c) at the offset mean2d - pixel centre, in the
// order of operations of the cpu backend.
fn mahalanobis(conic: vec3f, dx: f32, dy: f32) -> f32 {
    return 0.5 * (conic.x * dx * dx + conic.z * dy * dy) + conic.y * dx * dy;
}

// Logistic sigmoid without overflow for large |x|.
fn sigmoid(x: f32) -> f32 {
    if x >= 0.0 {
        return 1.0 / (1.0 + exp(-x));
    }
    let e = exp(x);
    return e / (1.0 + e);
}

// INRIA's `getRect` of a splat at `mean2d` of radius `r`, in tiles and not yet cut to the
// grid (as the cpu backend's `tile_rect`): floor((p - r) / 16) to floor((p + r + 15) / 16)
// with p = mean2d - 0.5, INRIA's pixel coordinates.
struct TileSpan {
    lo: vec2f,
    hi: vec2f,
}

fn inria_rect(mean2d: vec2f, r: f32) -> TileSpan {
    let t = f32(TILE_SIZE);
    let p = mean2d - vec2f(0.5);
    return TileSpan(floor((p - vec2f(r)) / t), floor((p + vec2f(r + t - 1.0)) / t));
}

// The tiles [x0, x1) x [y0, y1) a splat is binned into: INRIA's rectangle of its radius
// (`inria_rect`) cut to the tiles its box mean2d +- extent touches (with a one-pixel
// margin), outside of which it reaches no pixel.
fn tile_rect(s: Splat, tiles: vec2u) -> vec4u {
    let t = f32(TILE_SIZE);
    let m = s.mean_extent.xy;
    let e = s.mean_extent.zw + vec2f(1.0);
    let n = vec2f(tiles);
    let rect = inria_rect(m, s.cut_radius.y);
    let lo = max(rect.lo, floor((m - e) / t));
    let hi = min(rect.hi, floor((m + e) / t) + 1.0);
    let lo_u = vec2u(clamp(lo, vec2f(0.0), n));
    let hi_u = vec2u(clamp(hi, vec2f(0.0), n));
    return vec4u(lo_u.x, max(hi_u.x, lo_u.x), lo_u.y, max(hi_u.y, lo_u.y));
}

// True when the pixel at tile-local `(lx, ly)` of the tile with origin `origin` lies inside
// the splat's box mean2d +- extent, computed as the cpu backend clips.
fn in_box(s: Splat, origin: vec2u, lx: u32, ly: u32) -> bool {
    let o = vec2f(origin) + vec2f(0.5);
    let m = s.mean_extent.xy;
    let e = s.mean_extent.zw;
    let lo = ceil(m - e - o);
    let hi = floor(m + e - o);
    let l = vec2f(f32(lx), f32(ly));
    return all(l >= lo) && all(l <= hi);
}

// Sizes of one prefix-sum or radix-sort pass (the Rust twin is `PassUniform`).
struct Pass {
    // Number of items.
    n: u32,
    // Bit offset of the radix digit.
    shift: u32,
    // Number of blocks of BLOCK_ITEMS items.
    blocks: u32,
    unused: u32,
}

// Items per workgroup of the prefix-sum and radix-sort kernels: 256 threads of 4 items.
const BLOCK_ITEMS: u32 = 1024u;
