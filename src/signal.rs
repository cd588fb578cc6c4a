//! SIGINT (Ctrl-C) and SIGTERM (what Slurm and Kubernetes send before SIGKILL) stop a long
//! command at the next safe point: the command polls [`interrupted`], removes what it had not
//! finished and exits non-zero. Nothing else happens in the handler.

use std::sync::atomic::{AtomicBool, Ordering};

static INTERRUPTED: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    INTERRUPTED.store(true, Ordering::SeqCst);
}

/// Installs the handlers (once) and clears an earlier interruption.
pub fn install() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
    ONCE.call_once(|| unsafe {
        libc::signal(libc::SIGINT, on_signal as *const () as libc::sighandler_t);
        libc::signal(libc::SIGTERM, on_signal as *const () as libc::sighandler_t);
    });
    INTERRUPTED.store(false, Ordering::SeqCst);
}

/// Whether SIGINT or SIGTERM arrived since [`install`].
pub fn interrupted() -> bool {
    INTERRUPTED.load(Ordering::Relaxed)
}
