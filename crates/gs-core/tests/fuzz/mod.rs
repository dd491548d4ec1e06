//! The fuzz harness of the readers' tests (included by path from other crates' tests): a
//! counting allocator that refuses any single request above [`LIMIT`], mutations of small
//! valid files, and the loop that checks a reader against them.

// A `GlobalAlloc` is an unsafe trait; this one only passes each request on to the system
// allocator (and counts it).
#![allow(unsafe_code)]
// Each test crate uses what it needs of this module.
#![allow(dead_code)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::panic::AssertUnwindSafe;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

use rand::{Rng, SeedableRng};

/// The system allocator, counting the bytes held and refusing (null) any single request above
/// [`LIMIT`], as a machine out of memory would, so a reader that sizes a buffer from a file
/// fails the test instead of the machine.
pub struct Counting;

static HELD: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);
/// The largest allocation a reader of these small files may ask for.
pub const LIMIT: usize = 256 << 20;

thread_local! {
    /// The largest single request this thread may make (see [`with_cap`]).
    static CAP: std::cell::Cell<usize> = const { std::cell::Cell::new(LIMIT) };
}

/// Runs `f` with this thread's requests above `cap` bytes refused, as on a machine short of
/// memory for a file that is valid but large.
pub fn with_cap<R>(cap: usize, f: impl FnOnce() -> R) -> R {
    CAP.with(|c| c.set(cap.min(LIMIT)));
    let out = f();
    CAP.with(|c| c.set(LIMIT));
    out
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if layout.size() > CAP.with(|c| c.get()) {
            return std::ptr::null_mut();
        }
        let held = HELD.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
        PEAK.fetch_max(held, Ordering::Relaxed);
        // SAFETY: the layout is passed on unchanged to the system allocator.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        HELD.fetch_sub(layout.size(), Ordering::Relaxed);
        // SAFETY: `ptr` came from `alloc` with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }
}

/// The bytes held now, from which the peak is measured again.
pub fn held() -> usize {
    let held = HELD.load(Ordering::Relaxed);
    PEAK.store(held, Ordering::Relaxed);
    held
}

/// The most bytes held above `before` (from [`held`]) since it was taken.
pub fn peak_since(before: usize) -> usize {
    PEAK.load(Ordering::Relaxed).saturating_sub(before)
}

/// How many mutations each fuzz test runs: `FUZZ_CASES`, 500 by default.
pub fn cases() -> usize {
    std::env::var("FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(500)
}

/// One mutation of `bytes`: a truncation, bit flips, a run of one byte, or a number in the
/// text (a header count, a json value) replaced by a huge, negative or odd one.
pub fn mutate(bytes: &[u8], rng: &mut impl Rng) -> Vec<u8> {
    let mut out = bytes.to_vec();
    match rng.random_range(0..5) {
        0 => out.truncate(rng.random_range(0..=bytes.len())),
        1 => {
            for _ in 0..rng.random_range(1..8) {
                let i = rng
                    .random_range(0..out.len().max(1))
                    .min(out.len().saturating_sub(1));
                if let Some(b) = out.get_mut(i) {
                    *b ^= 1 << rng.random_range(0..8);
                }
            }
        }
        2 => {
            let at = rng.random_range(0..out.len().max(1));
            let len = rng.random_range(1..64).min(out.len().saturating_sub(at));
            let value = [0u8, 0xff, 0x7f, 0x80][rng.random_range(0..4)];
            out[at..at + len].fill(value);
        }
        _ => {
            // A run of ASCII digits, replaced.
            let starts: Vec<usize> = (0..out.len())
                .filter(|&i| out[i].is_ascii_digit() && (i == 0 || !out[i - 1].is_ascii_digit()))
                .collect();
            if let Some(&start) = starts.get(rng.random_range(0..starts.len().max(1))) {
                let end = (start..out.len())
                    .find(|&i| !out[i].is_ascii_digit())
                    .unwrap_or(out.len());
                let number = [
                    "4294967295",
                    "99999999999999999999",
                    "-1",
                    "0",
                    "1e300",
                    "65537",
                ][rng.random_range(0..6)];
                out.splice(start..end, number.bytes());
            }
        }
    }
    out
}

/// Runs `read` on `cases()` mutations of `valid` written as `name` in a fresh folder: asserts
/// no panic, a peak of held memory below `LIMIT`, and errors that name the file. Returns how
/// many mutations were refused. A failing case is found again from its seed and number.
pub fn fuzz(
    name: &str,
    valid: &[u8],
    seed: u64,
    read: impl Fn(&Path) -> Result<(), String>,
) -> usize {
    fuzz_with(name, seed, |rng| mutate(valid, rng), read)
}

/// [`fuzz`] over the files `make` writes from the case's random numbers (a mutation inside a
/// container, for instance, where a mutation of the container would only fail its checksum).
pub fn fuzz_with(
    name: &str,
    seed: u64,
    make: impl Fn(&mut rand::rngs::StdRng) -> Vec<u8>,
    read: impl Fn(&Path) -> Result<(), String>,
) -> usize {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut refused = 0;
    for case in 0..cases() {
        let bytes = make(&mut rng);
        std::fs::write(&path, &bytes).unwrap();
        let before = held();
        let outcome = std::panic::catch_unwind(AssertUnwindSafe(|| read(&path)));
        let peak = peak_since(before);
        match outcome {
            Err(_) => panic!("{name} case {case} (seed {seed}): the reader panicked"),
            Ok(Err(e)) => {
                refused += 1;
                assert!(
                    e.contains(name),
                    "{name} case {case}: {e:?} does not name the file"
                );
            }
            Ok(Ok(())) => {}
        }
        assert!(
            peak < LIMIT,
            "{name} case {case}: {peak} bytes held at the peak"
        );
    }
    // The line scripts/fuzz_campaign.sh tabulates.
    eprintln!(
        "fuzz {name} (seed {seed}): {} cases, {refused} refused, {} read, 0 panics",
        cases(),
        cases() - refused
    );
    refused
}
