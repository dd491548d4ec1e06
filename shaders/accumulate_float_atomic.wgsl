// Gradient accumulation with native f32 atomic add (adapters with SHADER_FLOAT32_ATOMIC). The
// importing kernel declares `view`, `accum0` to `accum3` and `background_grad`, all
// `array<GradAtomic>`. Imported as `accumulate.wgsl`.

//#import accumulate_parts.wgsl

alias GradAtomic = atomic<f32>;

// Adds `v` to slot `i` of `part` (0 to 3: `accumN`; BACKGROUND_PART: `background_grad`).
fn accumulate_slot(part: u32, i: u32, v: f32) {
    switch part {
        case 0u: {
            atomicAdd(&accum0[i], v);
        }
        case 1u: {
            atomicAdd(&accum1[i], v);
        }
        case 2u: {
            atomicAdd(&accum2[i], v);
        }
        case 3u: {
            atomicAdd(&accum3[i], v);
        }
        default: {
            atomicAdd(&background_grad[i], v);
        }
    }
}
