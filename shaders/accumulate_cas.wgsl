// Gradient accumulation without f32 atomics: a compare-exchange loop on the value's bits. The
// importing kernel declares `view`, `accum0` to `accum3` and `background_grad`, all
// `array<GradAtomic>`. Imported as `accumulate.wgsl`.

//#import accumulate_parts.wgsl

alias GradAtomic = atomic<u32>;

// One compare-exchange on slot `i` of `part` (as `accumulate_slot`): (1 when exchanged, the
// value found).
fn exchange_slot(part: u32, i: u32, old: u32, replacement: u32) -> vec2u {
    switch part {
        case 0u: {
            let r = atomicCompareExchangeWeak(&accum0[i], old, replacement);
            return vec2u(select(0u, 1u, r.exchanged), r.old_value);
        }
        case 1u: {
            let r = atomicCompareExchangeWeak(&accum1[i], old, replacement);
            return vec2u(select(0u, 1u, r.exchanged), r.old_value);
        }
        case 2u: {
            let r = atomicCompareExchangeWeak(&accum2[i], old, replacement);
            return vec2u(select(0u, 1u, r.exchanged), r.old_value);
        }
        case 3u: {
            let r = atomicCompareExchangeWeak(&accum3[i], old, replacement);
            return vec2u(select(0u, 1u, r.exchanged), r.old_value);
        }
        default: {
            let r = atomicCompareExchangeWeak(&background_grad[i], old, replacement);
            return vec2u(select(0u, 1u, r.exchanged), r.old_value);
        }
    }
}

// Adds `v` to slot `i` of `part` (0 to 3: `accumN`; BACKGROUND_PART: `background_grad`).
fn accumulate_slot(part: u32, i: u32, v: f32) {
    // A first guess of zero costs one failed exchange at most and needs no atomic load.
    var old = 0u;
    loop {
        let r = exchange_slot(part, i, old, bitcast<u32>(bitcast<f32>(old) + v));
        if r.x == 1u {
            break;
        }
        old = r.y;
    }
}
