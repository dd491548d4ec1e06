//! Which threads run candle's own CPU ops.
//!
//! candle runs its elementwise CPU ops (additions, copies of strided views, reductions) on a
//! worker pool of its own, beside rayon's, whose threads spin between ops. This crate's heavy
//! work (products, convolutions, fused kernels) runs on rayon's threads, and the style loss
//! evaluates CLIP's terms and the image-space terms at once, as two rayon tasks: with candle's
//! pool at the machine's width too, the cores are oversubscribed and the loss gets slower. With
//! candle's ops kept on the thread that calls them, the two tasks keep both cores busy (on the
//! 2-core machine of `docs/benchmarks.md` the loss at the main job's settings went from about
//! 2.3-2.7 s to 1.9-2.0 s).

/// The environment variable that sets the size of candle's CPU worker pool.
pub const CANDLE_THREADS_VARIABLE: &str = "CANDLE_NUM_THREADS";

/// Keeps candle's CPU ops on the calling thread (`CANDLE_NUM_THREADS=1`) unless the environment
/// already sets `CANDLE_NUM_THREADS`; returns whether it set it. candle reads the variable once,
/// at its first CPU op, so call this first thing in `main`, before other threads start (setting
/// a variable while another thread reads the environment is a data race in C's `getenv`). The
/// binaries call it; a pipeline that embeds this crate may do the same.
pub fn candle_ops_on_calling_thread() -> bool {
    if std::env::var_os(CANDLE_THREADS_VARIABLE).is_some() {
        return false;
    }
    std::env::set_var(CANDLE_THREADS_VARIABLE, "1");
    true
}
