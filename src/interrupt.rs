//! Ctrl-C (SIGINT) and SIGTERM end a `palpate run` or `palpate haptic` cleanly: the first
//! signal asks the job to stop after its current batch and write its outputs as usual (status
//! `interrupted`, exit status 130); a second one ends the process at once. Nothing is
//! installed unless [`install`] is called (the command line does; a library user keeps the
//! default behaviour), and a signal the process inherited as ignored (a background job of a
//! non-interactive shell) stays ignored. A stop asked for stays asked for until [`clear`].
//! Unix only: elsewhere [`install`] does nothing.

use std::sync::atomic::{AtomicBool, Ordering};

static REQUESTED: AtomicBool = AtomicBool::new(false);

/// Exit status of a job ended by a signal (128 + SIGINT).
pub const EXIT_STATUS: u8 = 130;

/// Whether a stop was asked for (by a signal, or [`request`]).
pub fn requested() -> bool {
    REQUESTED.load(Ordering::SeqCst)
}

/// Ask the running job to stop after its current batch (what the first signal does).
pub fn request() {
    REQUESTED.store(true, Ordering::SeqCst);
}

/// Forget a stop asked for (before starting another job in the same process).
pub fn clear() {
    REQUESTED.store(false, Ordering::SeqCst);
}

/// What the first signal prints (on stderr).
pub const FIRST_NOTE: &str =
    "\nnote: stopping after the current batch and writing the outputs (a second Ctrl-C stops at once)\n";

/// What the second signal prints (on stderr) before ending the process.
pub const SECOND_NOTE: &str = "\nerror: interrupted twice: stopped at once, outputs not written (the next run into the folder removes what is left)\n";

#[cfg(unix)]
extern "C" fn on_signal(_: libc::c_int) {
    // Only async-signal-safe calls here: an atomic swap, write(2) and _exit.
    let second = REQUESTED.swap(true, Ordering::SeqCst);
    let note = if second { SECOND_NOTE } else { FIRST_NOTE };
    // SAFETY: write(2) on stderr with a valid buffer and length; its result is not needed.
    unsafe { libc::write(2, note.as_ptr().cast(), note.len()) };
    if second {
        unsafe { libc::_exit(EXIT_STATUS as libc::c_int) };
    }
}

/// Route SIGINT and SIGTERM to [`requested`] (each unless inherited as ignored); returns
/// whether a handler was installed for both.
pub fn install() -> bool {
    #[cfg(unix)]
    {
        let handler = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
        // SAFETY: `on_signal` only touches an atomic and calls `write` and `_exit`, all
        // async-signal-safe; `signal` is called with valid signal numbers and with the
        // disposition it returned.
        let installed = [libc::SIGINT, libc::SIGTERM].map(|sig| unsafe {
            let before = libc::signal(sig, handler);
            if before == libc::SIG_IGN {
                libc::signal(sig, libc::SIG_IGN);
                return false;
            }
            before != libc::SIG_ERR
        });
        installed.iter().all(|&ok| ok)
    }
    #[cfg(not(unix))]
    {
        false
    }
}
