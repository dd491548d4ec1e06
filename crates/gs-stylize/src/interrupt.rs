//! Ctrl-C for long runs: the first press asks the run to stop after its current step (it then
//! writes a checkpoint), a second press quits at once.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// Exit status of a run stopped by Ctrl-C (128 + SIGINT, as shells report it).
pub const INTERRUPTED_EXIT: u8 = 130;

/// Installs the process's Ctrl-C handler and returns the flag it sets (for
/// [`crate::RunOptions::stop`]). A second Ctrl-C exits with [`INTERRUPTED_EXIT`].
pub fn stop_on_ctrl_c() -> Result<Arc<AtomicBool>, ctrlc::Error> {
    let stop = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&stop);
    ctrlc::set_handler(move || {
        if flag.swap(true, Ordering::SeqCst) {
            std::process::exit(i32::from(INTERRUPTED_EXIT));
        }
        eprintln!("\nstopping after the current step (Ctrl-C again to quit at once)");
    })?;
    Ok(stop)
}
