// Where a splat's gradient slots live: SPLAT_GRADS slots per Gaussian, split into parts of
// `view.parts.x` Gaussians as the splats are (splat_parts.wgsl); the background's three slots
// have a part of their own. Shared by both variants of `accumulate.wgsl`.

//#import helpers.wgsl

// The part that stands for `background_grad`.
const BACKGROUND_PART: u32 = 4u;

// Adds `v` to gradient slot `q` of Gaussian `id`.
fn accumulate(id: u32, q: u32, v: f32) {
    let part = id / view.parts.x;
    let i = (id - part * view.parts.x) * SPLAT_GRADS + q;
    accumulate_slot(part, i, v);
}
