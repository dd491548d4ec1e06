//! Ctrl-C (and SIGTERM, SIGHUP) for long runs: the first stop asks the run to stop after its
//! current step (it then writes a checkpoint), a second quits at once.
//!
//! One stop may arrive twice: a scheduler that signals every process of a job, or a terminal's
//! Ctrl-C reaching a batch's job as well as the batch that passes it on. A run that may be
//! signalled so ([`stop_on_ctrl_c_once`]) takes a second stop within [`SAME_STOP`] of the first
//! as the same one.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Exit status of a run stopped by Ctrl-C (128 + SIGINT, as shells report it).
pub const INTERRUPTED_EXIT: u8 = 130;

/// How soon after a first stop a second one is taken as the same stop delivered twice.
pub const SAME_STOP: Duration = Duration::from_secs(2);

/// Installs the process's Ctrl-C handler and returns the flag it sets (for
/// [`crate::RunOptions::stop`]). A second Ctrl-C exits with [`INTERRUPTED_EXIT`].
pub fn stop_on_ctrl_c() -> Result<Arc<AtomicBool>, ctrlc::Error> {
    stop_on_ctrl_c_once(Duration::ZERO, INTERRUPTED_EXIT, || {})
}

/// [`stop_on_ctrl_c`] where a second stop within `same_within` of the first is the same stop,
/// and a later one runs `before_quit` (which records why the process ends) and exits with
/// `quit_code`.
pub fn stop_on_ctrl_c_once(
    same_within: Duration,
    quit_code: u8,
    before_quit: impl Fn() + Send + 'static,
) -> Result<Arc<AtomicBool>, ctrlc::Error> {
    let stop = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&stop);
    let first = Mutex::new(None);
    ctrlc::set_handler(move || match stop_kind(&first, same_within) {
        Stop::First => {
            flag.store(true, Ordering::SeqCst);
            eprintln!("\nstopping after the current step (Ctrl-C again to quit at once)");
        }
        Stop::Repeated => {}
        Stop::Again => {
            before_quit();
            std::process::exit(i32::from(quit_code));
        }
    })?;
    Ok(stop)
}

/// Installs a handler that only counts the process's stops (a stop within `same_within` of the
/// first is not counted again) and returns the count: for a process that passes each stop on to
/// others and waits for them, never quitting itself.
pub fn count_stops(same_within: Duration) -> Result<Arc<AtomicUsize>, ctrlc::Error> {
    let count = Arc::new(AtomicUsize::new(0));
    let counted = Arc::clone(&count);
    let first = Mutex::new(None);
    ctrlc::set_handler(move || {
        if stop_kind(&first, same_within) != Stop::Repeated {
            counted.fetch_add(1, Ordering::SeqCst);
        }
    })?;
    Ok(count)
}

/// What a stop is to a process first stopped at `first` (set by the first).
#[derive(Debug, PartialEq)]
enum Stop {
    /// The first.
    First,
    /// Within `same_within` of the first: the same stop, delivered twice.
    Repeated,
    /// A later one.
    Again,
}

fn stop_kind(first: &Mutex<Option<Instant>>, same_within: Duration) -> Stop {
    let now = Instant::now();
    let mut first = first
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner());
    match *first {
        None => {
            *first = Some(now);
            Stop::First
        }
        Some(at) if now.duration_since(at) < same_within => Stop::Repeated,
        Some(_) => Stop::Again,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stop_within_the_window_is_the_first_again() {
        let first = Mutex::new(None);
        assert_eq!(stop_kind(&first, Duration::from_secs(60)), Stop::First);
        assert_eq!(stop_kind(&first, Duration::from_secs(60)), Stop::Repeated);
        // No window: every later stop is another.
        let first = Mutex::new(None);
        assert_eq!(stop_kind(&first, Duration::ZERO), Stop::First);
        assert_eq!(stop_kind(&first, Duration::ZERO), Stop::Again);
    }
}
