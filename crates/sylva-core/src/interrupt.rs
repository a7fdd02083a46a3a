//! Ctrl-C without debris. [`install`] (called once by the `sylva` binary) catches SIGINT and
//! SIGTERM. While no temporary file exists the signal ends the process at once, as if
//! uncaught; while one does ([`StagingGuard`], held by the atomic writers and output sets),
//! the handler only marks the process interrupted, the writers fail at their next write
//! ([`check`]), the temporaries are removed, and the command ends with an error.

use std::io;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

static INTERRUPTED: AtomicBool = AtomicBool::new(false);
static STAGING: AtomicUsize = AtomicUsize::new(0);

/// True once SIGINT or SIGTERM arrived while a temporary file existed.
pub fn interrupted() -> bool {
    INTERRUPTED.load(Ordering::SeqCst)
}

/// An error once the process is interrupted.
pub fn check() -> io::Result<()> {
    if interrupted() {
        // Not ErrorKind::Interrupted: write_all retries those.
        Err(io::Error::other(
            "interrupted (Ctrl-C): nothing was replaced",
        ))
    } else {
        Ok(())
    }
}

/// Marks the process interrupted, as the signal handler does (for tests and for callers that
/// learn of a cancellation some other way).
pub fn mark_interrupted() {
    INTERRUPTED.store(true, Ordering::SeqCst);
}

/// Held while temporary files exist: a signal then interrupts instead of ending the process.
#[derive(Debug)]
pub struct StagingGuard(());

impl StagingGuard {
    pub fn new() -> StagingGuard {
        STAGING.fetch_add(1, Ordering::SeqCst);
        StagingGuard(())
    }
}

impl Default for StagingGuard {
    fn default() -> Self {
        StagingGuard::new()
    }
}

impl Drop for StagingGuard {
    fn drop(&mut self) {
        STAGING.fetch_sub(1, Ordering::SeqCst);
    }
}

#[cfg(unix)]
extern "C" fn on_signal(sig: libc::c_int) {
    INTERRUPTED.store(true, Ordering::SeqCst);
    if STAGING.load(Ordering::SeqCst) == 0 {
        // Nothing to clean up: end the process the way the signal would have.
        // SAFETY: signal and raise are async-signal-safe.
        unsafe {
            libc::signal(sig, libc::SIG_DFL);
            libc::raise(sig);
        }
    }
}

/// Catches SIGINT and SIGTERM as described above (a no-op off Unix).
pub fn install() {
    #[cfg(unix)]
    // SAFETY: the handler only touches atomics and calls async-signal-safe functions.
    unsafe {
        let handler = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
        libc::signal(libc::SIGINT, handler);
        libc::signal(libc::SIGTERM, handler);
    }
}
