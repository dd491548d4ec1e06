// The photometric loss of a fit, as gs_core::image_loss's `PhotometricObjective` computes it on the
// render that `ClampedObjective` hands it: `(1 - lambda) L1 + lambda (1 - SSIM)`, SSIM per channel
// with an 11x11 Gaussian window (sigma 1.5) and zero padding, as a separable blur whose every
// output sums its taps from zero in increasing order (gs_core's `blur`). Images are HWC; the
// planes of the blurs are channel after channel, `[3][height][width]`.

//#import helpers.wgsl

const SSIM_RADIUS: i32 = 5;
const SSIM_TAPS: i32 = 11;

// The loss's parameters (the Rust twin is `PhotometricUniform`).
struct Photometric {
    // width, height, 1 when the render is clamped to [0, 1] first, values (3 * width * height).
    size: vec4u,
    // The window's weights (gs_core's `window::<f32>()`), four a vector.
    window: array<vec4f, 3>,
    // lambda (the D-SSIM weight), 1 / values, the factor of dL/dimage (1 / the batch's
    // divisor), unused.
    weights: vec4f,
}

// SSIM's stabilizers, as gs_core's (0.01^2 and 0.03^2).
const SSIM_C1: f32 = 0.0001;
const SSIM_C2: f32 = 0.0009;

// Tap `t` of the window.
fn tap(window: array<vec4f, 3>, t: i32) -> f32 {
    let k = u32(t);
    return window[k / 4u][k % 4u];
}

// True for NaN, by its bits.
fn is_nan(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7fffffffu) > 0x7f800000u;
}

// The value the loss sees of a rendered value: clamped to [0, 1] when `clamped`, NaN staying NaN
// (as `f32::clamp` and `torch.clamp`), so that a NaN render makes the loss NaN.
fn seen(raw: f32, clamped: bool) -> f32 {
    if clamped && !is_nan(raw) {
        return clamp(raw, 0.0, 1.0);
    }
    return raw;
}

// The plane index (channel, row, column) of value `i` of a `[3][height][width]` plane set.
fn plane_position(i: u32, width: u32, height: u32) -> vec3u {
    let pixels = width * height;
    let ch = i / pixels;
    let p = i % pixels;
    return vec3u(ch, p / width, p % width);
}
