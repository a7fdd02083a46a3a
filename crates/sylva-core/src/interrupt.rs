//! Ctrl-C without debris: the process's one cancellation token. [`install`] (called once by
//! the `sylva` binary) catches SIGINT and SIGTERM through `signal-hook`. While no temporary
//! file exists the signal ends the process at once, as if uncaught; while one does
//! ([`StagingGuard`], held by the atomic writers and output sets), the handler only marks the
//! process interrupted, the writers fail at their next write ([`check`]), long loops that poll
//! [`interrupted`] stop, the temporaries are removed, and the command ends with an error.

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

/// Catches SIGINT and SIGTERM as described above. Later calls do nothing.
pub fn install() {
    static INSTALLED: std::sync::Once = std::sync::Once::new();
    INSTALLED.call_once(|| {
        for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
            // SAFETY: the action only touches atomics and calls emulate_default_handler, all
            // async-signal-safe. Failing to register leaves the signal's default (ending the
            // process), which is safe too.
            let _ = unsafe {
                signal_hook::low_level::register(signal, move || {
                    INTERRUPTED.store(true, Ordering::SeqCst);
                    if STAGING.load(Ordering::SeqCst) == 0 {
                        // Nothing to clean up: end the process the way the signal would have.
                        let _ = signal_hook::low_level::emulate_default_handler(signal);
                    }
                })
            };
        }
    });
}
