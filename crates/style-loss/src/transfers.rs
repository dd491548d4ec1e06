//! Counts of the data that crosses between the host and the loss device, per thread: the
//! uploads and reads of a step are what a GPU waits on, so they are counted where they happen
//! (this crate's, and a modality's through [`record_upload`] and [`record_read`]) and a test or
//! a benchmark reads them with [`snapshot`]. On the CPU the same crossings are copies.

use std::cell::Cell;

/// Uploads and reads so far on this thread: how many, and their bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Transfers {
    /// Host-to-device copies.
    pub uploads: u64,
    /// Their bytes.
    pub uploaded_bytes: u64,
    /// Device-to-host reads (each a synchronisation on a GPU).
    pub reads: u64,
    /// Their bytes.
    pub read_bytes: u64,
}

impl std::ops::Sub for Transfers {
    type Output = Self;

    /// What happened between two snapshots (`later - earlier`).
    fn sub(self, earlier: Self) -> Self {
        Self {
            uploads: self.uploads - earlier.uploads,
            uploaded_bytes: self.uploaded_bytes - earlier.uploaded_bytes,
            reads: self.reads - earlier.reads,
            read_bytes: self.read_bytes - earlier.read_bytes,
        }
    }
}

thread_local! {
    static COUNTS: Cell<Transfers> = const {
        Cell::new(Transfers { uploads: 0, uploaded_bytes: 0, reads: 0, read_bytes: 0 })
    };
}

/// This thread's counts so far.
pub fn snapshot() -> Transfers {
    COUNTS.get()
}

/// Counts one upload of `bytes` from the host to the loss device.
pub fn record_upload(bytes: usize) {
    let mut c = COUNTS.get();
    c.uploads += 1;
    c.uploaded_bytes += bytes as u64;
    COUNTS.set(c);
}

/// Counts one read of `bytes` from the loss device to the host.
pub fn record_read(bytes: usize) {
    let mut c = COUNTS.get();
    c.reads += 1;
    c.read_bytes += bytes as u64;
    COUNTS.set(c);
}

/// Adds `counts` to this thread's.
fn add(counts: Transfers) {
    let c = COUNTS.get();
    COUNTS.set(Transfers {
        uploads: c.uploads + counts.uploads,
        uploaded_bytes: c.uploaded_bytes + counts.uploaded_bytes,
        reads: c.reads + counts.reads,
        read_bytes: c.read_bytes + counts.read_bytes,
    });
}

/// Runs `f` and returns its value with what it transferred and the thread it ran on.
fn counted<R>(f: impl FnOnce() -> R) -> (R, Transfers, std::thread::ThreadId) {
    let before = snapshot();
    let value = f();
    (value, snapshot() - before, std::thread::current().id())
}

/// `rayon::join(a, b)`, with what either closure transfers counted on this thread, as if both
/// had run here (rayon runs them on its own threads when it chooses).
pub(crate) fn join_counted<RA: Send, RB: Send>(
    a: impl FnOnce() -> RA + Send,
    b: impl FnOnce() -> RB + Send,
) -> (RA, RB) {
    let here = std::thread::current().id();
    let ((ra, a_counts, a_thread), (rb, b_counts, b_thread)) =
        rayon::join(|| counted(a), || counted(b));
    for (counts, thread) in [(a_counts, a_thread), (b_counts, b_thread)] {
        if thread != here {
            add(counts);
        }
    }
    (ra, rb)
}
