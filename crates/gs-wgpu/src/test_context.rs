//! A GPU context for tests that need one, and what they do on a machine without a GPU adapter:
//! say plainly that they were skipped and pass, unless [`REQUIRE_GPU_TESTS`] is `1` (`.ci/run`
//! sets it and installs Mesa's software Vulkan device), where they fail naming what to install.

use std::io::Write;

use super::{AdapterChoice, GpuContext, GpuError, GpuOptions};

/// The environment variable that turns a missing GPU adapter from a skipped test into a failed
/// one (`1`).
pub const REQUIRE_GPU_TESTS: &str = "CLIPGAUSSIAN_REQUIRE_GPU_TESTS";

/// A context with `options` for the running test (a real GPU first, else a software device
/// such as Mesa's lavapipe), or `None` after a line on stderr saying the test (named after its
/// thread, as the test harness names it) was skipped because there is no adapter. Panics
/// instead when [`REQUIRE_GPU_TESTS`] is `1`, and on any other error (an adapter that fails to
/// open is a failure, not a skip).
pub fn test_context(options: GpuOptions) -> Option<GpuContext> {
    let thread = std::thread::current();
    let test = thread.name().unwrap_or("a GPU test");
    match GpuContext::with_options(AdapterChoice::AllowSoftware, options) {
        Ok(ctx) => Some(ctx),
        Err(GpuError::NoAdapter { seen, .. }) => {
            skip_or_fail(test, &format!("no GPU adapter (adapters seen: {seen})"));
            None
        }
        Err(e) => panic!("{test}: the GPU adapter failed to open: {e}"),
    }
}

/// Whether a GPU adapter (real or software) exists: for tests that run a binary with
/// `--device gpu`. Says the test was skipped (or panics, as [`test_context`]) when there is
/// none.
pub fn test_adapter_exists() -> bool {
    test_context(GpuOptions::default()).is_some()
}

fn skip_or_fail(test: &str, why: &str) {
    let hint = "install a Vulkan driver (Debian/Ubuntu: mesa-vulkan-drivers, Mesa's software \
                device lavapipe) to run it";
    if std::env::var(REQUIRE_GPU_TESTS).is_ok_and(|v| v == "1") {
        panic!("{test}: {why}; {REQUIRE_GPU_TESTS}=1 asks for every GPU test: {hint}");
    }
    // Straight to the process's stderr, past the test harness's capture: a skip is seen.
    let _ = writeln!(
        std::io::stderr(),
        "SKIPPED {test}: {why}; {hint}, or set {REQUIRE_GPU_TESTS}=1 to make this a failure"
    );
}
