//! Run-time choice of vector width for CPU kernels.
//!
//! A release build targets the x86-64 baseline, whose vectors are SSE2's 128 bits: a loop the
//! compiler vectorizes runs there at a quarter of AVX-512's width and half of AVX2's.
//! [`widest_simd`](crate::widest_simd) compiles a kernel once per instruction set and calls the
//! widest one the CPU has. The clones run the same operations in the same order (Rust never
//! fuses a multiply and an add into an FMA by itself), so every CPU gets the same bits.

/// Compiles the function it wraps for AVX-512 (F, BW, DQ, VL), for AVX2 with FMA and for the
/// baseline, and calls the first of those the CPU supports (`multiversion`'s dispatch, the CPU's
/// features detected once per process). Closures inside the function are functions of their
/// own and keep the baseline: a kernel's loop body belongs in the wrapped function (or in
/// `#[inline(always)]` functions it calls), not in a closure handed to rayon. The crate that
/// uses it must depend on `multiversion`, whose expansion names it.
#[macro_export]
macro_rules! widest_simd {
    ($item:item) => {
        #[multiversion::multiversion(targets(
            "x86_64+avx512f+avx512bw+avx512dq+avx512vl",
            "x86_64+avx2+fma",
        ))]
        $item
    };
}
