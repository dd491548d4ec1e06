// Gradient accumulation without f32 atomics: a compare-exchange loop on the value's bits. The
// importing kernel declares `accum: array<GradAtomic>`. Imported as `accumulate.wgsl`.

alias GradAtomic = atomic<u32>;

fn accumulate(i: u32, v: f32) {
    var old = atomicLoad(&accum[i]);
    loop {
        let r = atomicCompareExchangeWeak(&accum[i], old, bitcast<u32>(bitcast<f32>(old) + v));
        if r.exchanged {
            break;
        }
        old = r.old_value;
    }
}
