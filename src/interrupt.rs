//! Ctrl-C (SIGINT) and SIGTERM end a `palpate run` or `palpate haptic` cleanly: the first
//! signal asks the job to stop after its current batch and write its outputs as usual (status
//! `interrupted`, exit status 130); a second one ends the process at once, unless it came
//! within [`REPEAT_WINDOW`] of the first: that is the same stop delivered twice (GNU
//! `timeout` signals its command and then the command's process group, microseconds apart),
//! not a user asking again. While the job is still being set up (the scene built: its
//! particles sampled and their neighbour lists, for a large layer a minute or more) a signal
//! ends the process at once: nothing has been written then, and earlier outputs are kept.
//! The job calls [`setup_done`] once it is built. Nothing is
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

/// Whether handlers are installed ([`install`]).
static INSTALLED: AtomicBool = AtomicBool::new(false);

/// Whether the job is still being set up: a signal then ends the process at once.
static SETTING_UP: AtomicBool = AtomicBool::new(false);

/// The job is built and about to write or step: from now on a first signal asks it to stop
/// after its batch and write its outputs.
pub fn setup_done() {
    SETTING_UP.store(false, Ordering::SeqCst);
}

/// What a signal during the setup prints (on stderr) before ending the process.
pub const SETUP_NOTE: &str = "\nerror: stopped while the scene was being built (Ctrl-C or SIGTERM): nothing was written, earlier outputs kept\n";

/// Forget a stop asked for, and the signals counted (before starting another job in the
/// same process, which is set up again).
pub fn clear() {
    SETTING_UP.store(INSTALLED.load(Ordering::SeqCst), Ordering::SeqCst);
    REQUESTED.store(false, Ordering::SeqCst);
    SIGNALS.store(0, Ordering::SeqCst);
    FIRST_AT.store(0, Ordering::SeqCst);
}

/// What the first signal prints (on stderr).
pub const FIRST_NOTE: &str =
    "\nnote: stopping after the current batch and writing the outputs (a later second Ctrl-C or SIGTERM stops at once)\n";

/// What the second signal prints (on stderr) before ending the process.
pub const SECOND_NOTE: &str = "\nerror: interrupted twice: stopped at once; the outputs were not written (frames already written stay, listed in series.pvd)\n";

/// Signals received since [`install`] or [`clear`] (repeats within [`REPEAT_WINDOW`] of the
/// first not counted).
static SIGNALS: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);

/// A signal this soon after the first is that one delivered again, and ignored.
pub const REPEAT_WINDOW: std::time::Duration = std::time::Duration::from_millis(250);

/// When the first signal came, ns on the monotonic clock (0: none yet).
static FIRST_AT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

/// The monotonic clock in ns, at least 1 (clock_gettime is async-signal-safe); None if it
/// fails (then every signal counts).
#[cfg(unix)]
fn monotonic_ns() -> Option<u64> {
    // SAFETY: a zeroed timespec is valid, and clock_gettime only writes the one it is given.
    let (ok, t) = unsafe {
        let mut t: libc::timespec = std::mem::zeroed();
        let r = libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut t);
        (r == 0, t)
    };
    ok.then(|| {
        (t.tv_sec as u64)
            .saturating_mul(1_000_000_000)
            .saturating_add(t.tv_nsec as u64)
            .max(1)
    })
}

#[cfg(unix)]
extern "C" fn on_signal(_: libc::c_int) {
    // Only async-signal-safe calls here: atomics, clock_gettime, write(2) and _exit.
    // Installed with SA_NODEFER: a second signal interrupts a first handler blocked in write
    // (a full pipe on stderr), and a third exits without writing (each counted outside the
    // repeat window). The first signal's time is taken before it is counted, so a repeat
    // nested in its handler is seen as one.
    if let Some(now) = monotonic_ns() {
        if let Err(first) = FIRST_AT.compare_exchange(0, now, Ordering::SeqCst, Ordering::SeqCst) {
            if now.saturating_sub(first) < REPEAT_WINDOW.as_nanos() as u64 {
                return;
            }
        }
    }
    let n = SIGNALS.fetch_add(1, Ordering::SeqCst) + 1;
    REQUESTED.store(true, Ordering::SeqCst);
    let setting_up = SETTING_UP.load(Ordering::SeqCst);
    let note = match n {
        1 if setting_up => SETUP_NOTE,
        1 => FIRST_NOTE,
        2 => SECOND_NOTE,
        _ => "",
    };
    #[cfg(target_os = "linux")]
    // SAFETY: the calling thread's errno slot; saved and restored around write(2), which may
    // change it under the code the signal interrupted.
    let errno = unsafe { *libc::__errno_location() };
    // SAFETY: write(2) on stderr with a valid buffer and length; its result is not needed.
    unsafe { libc::write(2, note.as_ptr().cast(), note.len()) };
    #[cfg(target_os = "linux")]
    // SAFETY: as above.
    unsafe {
        *libc::__errno_location() = errno
    };
    if n >= 2 || setting_up {
        // SAFETY: _exit is async-signal-safe.
        unsafe { libc::_exit(EXIT_STATUS as libc::c_int) };
    }
}

/// Route SIGINT and SIGTERM to [`requested`] (each unless inherited as ignored); returns
/// whether a handler was installed for both.
pub fn install() -> bool {
    #[cfg(unix)]
    {
        let handler = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
        // SAFETY: `on_signal` only touches atomics and calls `write` and `_exit`, all
        // async-signal-safe; `sigaction` gets valid signal numbers and zero-initialised
        // (valid) structures, and an inherited SIG_IGN is put back as it was.
        let installed = [libc::SIGINT, libc::SIGTERM].map(|sig| unsafe {
            let mut action: libc::sigaction = std::mem::zeroed();
            action.sa_sigaction = handler;
            action.sa_flags = libc::SA_NODEFER | libc::SA_RESTART;
            libc::sigemptyset(&mut action.sa_mask);
            let mut before: libc::sigaction = std::mem::zeroed();
            if libc::sigaction(sig, &action, &mut before) != 0 {
                return false;
            }
            if before.sa_sigaction == libc::SIG_IGN {
                libc::sigaction(sig, &before, std::ptr::null_mut());
                return false;
            }
            true
        });
        let all = installed.iter().all(|&ok| ok);
        INSTALLED.store(true, Ordering::SeqCst);
        SETTING_UP.store(true, Ordering::SeqCst);
        all
    }
    #[cfg(not(unix))]
    {
        false
    }
}
