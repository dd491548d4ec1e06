// Gradient accumulation with native f32 atomic add (adapters with SHADER_FLOAT32_ATOMIC). The
// importing kernel declares `accum: array<GradAtomic>`. Imported as `accumulate.wgsl`.

alias GradAtomic = atomic<f32>;

fn accumulate(i: u32, v: f32) {
    atomicAdd(&accum[i], v);
}
