//! The process's memory: the allocator setting for runs of large tensors, and the peak
//! resident size the benchmarks report ([`peak_resident_mb`]).
//!
//! Every candle op allocates its output, and a stylization step makes and frees gigabytes of
//! tensors. glibc hands each block over 32 MB straight back to the kernel when it is freed, so
//! the next step faults every page in again, zeroed; on the 2-vCPU VM of `docs/benchmarks.md`
//! that page zeroing took a third of the style loss's CPU time. [`keep_freed_memory`] makes
//! glibc keep freed memory for reuse instead. The binaries call it first thing; a pipeline that
//! embeds this crate may do the same (or use an allocator of its own).

/// Makes glibc's `malloc` keep freed memory in the process for reuse: no `mmap` per large block,
/// no trimming of the heap, one arena. The resident size then stays at the run's peak. Returns
/// whether the setting took effect (false on other C libraries and platforms, where it does
/// nothing). Call it before other threads start allocating.
pub fn keep_freed_memory() -> bool {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    #[allow(unsafe_code)]
    {
        // SAFETY: `mallopt` only sets allocator parameters, under glibc's own arena lock; the
        // values are the documented ones (mallopt(3): M_MMAP_MAX 0 disables mmap, M_TRIM_THRESHOLD
        // -1 disables trimming).
        unsafe {
            libc::mallopt(libc::M_MMAP_MAX, 0) == 1
                && libc::mallopt(libc::M_TRIM_THRESHOLD, -1) == 1
                && libc::mallopt(libc::M_ARENA_MAX, 1) == 1
        }
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        false
    }
}

/// The process's peak resident memory so far, MB (`VmHWM` of `/proc/self/status`); `None` where
/// that cannot be read (other systems).
pub fn peak_resident_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let kb: f64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))?
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kb / 1024.0)
}

#[cfg(test)]
mod tests {
    #[test]
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    fn glibc_takes_the_setting_and_large_blocks_still_allocate() {
        assert!(super::keep_freed_memory());
        // A block well over glibc's mmap threshold now comes from the heap; it must still work.
        let block = vec![1u8; 64 << 20];
        assert_eq!(block.iter().map(|&b| b as usize).sum::<usize>(), 64 << 20);
    }

    #[test]
    #[cfg(target_os = "linux")]
    fn the_peak_counts_memory_the_process_touched() {
        let block = vec![1u8; 32 << 20];
        let peak = super::peak_resident_mb().unwrap();
        assert!(peak >= 32.0, "{peak} MB");
        assert_eq!(block[block.len() - 1], 1);
    }
}
