//! One job at a time in an output folder: `palpate run` and `palpate haptic` hold
//! `.palpate.lock` (the holder's process id) in `--out` from before they remove an earlier
//! run's files until they have written their own, so that a second job into the same folder
//! is refused instead of deleting the first one's frames while it runs and mixing its files
//! with them. A lock whose process is gone (killed, or ended at once by a second Ctrl-C) is
//! stale and taken over. Unix only: elsewhere nothing is locked.

use crate::error::{PalpateError, Result};
use std::path::{Path, PathBuf};

/// The lock file's name in the output folder.
pub const LOCK_NAME: &str = ".palpate.lock";

/// A held lock on an output folder, released (its file removed) when dropped.
#[derive(Debug)]
pub struct OutLock {
    path: Option<PathBuf>,
}

impl OutLock {
    /// Take the lock on `dir` (which exists), or fail naming the job that holds it.
    pub fn acquire(dir: &Path) -> Result<OutLock> {
        #[cfg(unix)]
        {
            let path = dir.join(LOCK_NAME);
            let me = std::process::id();
            // Twice at most: a stale lock is removed and the folder tried again (another job
            // may take it in between: then that one holds it).
            for _ in 0..2 {
                match create_new(&path, me) {
                    Ok(()) => return Ok(OutLock { path: Some(path) }),
                    Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                        match holder(&path) {
                            Some(pid) if pid != me && is_palpate(pid) => {
                                return Err(PalpateError::Usage(format!(
                                    "{}: another palpate job (process {pid}) is writing its outputs here; wait for it to end or give another --out (a lock left by a job that is gone is taken over: {} names that process)",
                                    dir.display(),
                                    LOCK_NAME
                                )))
                            }
                            _ => {
                                let _ = std::fs::remove_file(&path);
                            }
                        }
                    }
                    Err(source) => return Err(PalpateError::OutputIo { path, source }),
                }
            }
            Err(PalpateError::Usage(format!(
                "{}: another palpate job took the output folder's lock ({LOCK_NAME}) as this one started; give another --out",
                dir.display()
            )))
        }
        #[cfg(not(unix))]
        {
            let _ = dir;
            Ok(OutLock { path: None })
        }
    }
}

impl Drop for OutLock {
    fn drop(&mut self) {
        // Only a lock that is still ours (a stale-lock takeover by another job replaced it
        // only if this process was gone, which it is not while it drops).
        if let Some(path) = &self.path {
            if holder(path) == Some(std::process::id()) {
                let _ = std::fs::remove_file(path);
            }
        }
    }
}

/// Create `path` only if it does not exist, holding `pid`.
#[cfg(unix)]
fn create_new(path: &Path, pid: u32) -> std::io::Result<()> {
    use std::io::Write;
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(path)?;
    writeln!(f, "{pid}")
}

/// The process id a lock file holds (None: unreadable, not a regular file, or not a number).
fn holder(path: &Path) -> Option<u32> {
    if !std::fs::symlink_metadata(path).ok()?.is_file() {
        return None;
    }
    std::fs::read_to_string(path).ok()?.trim().parse().ok()
}

/// Whether process `pid` is alive and, where /proc tells, a palpate (not another program
/// that was given the id of a palpate long gone).
#[cfg(unix)]
fn is_palpate(pid: u32) -> bool {
    let Ok(id) = libc::pid_t::try_from(pid) else {
        return false;
    };
    // SAFETY: kill(2) with signal 0 only checks that the process exists.
    let alive = unsafe { libc::kill(id, 0) } == 0
        || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM);
    if !alive {
        return false;
    }
    match std::fs::read_to_string(format!("/proc/{pid}/comm")) {
        Ok(comm) => comm.trim().starts_with("palpate"),
        Err(_) => true,
    }
}

#[cfg(all(test, unix))]
mod tests {
    use super::{OutLock, LOCK_NAME};

    #[test]
    fn a_folder_is_locked_once_and_a_stale_lock_is_taken_over() {
        let dir = std::env::temp_dir().join(format!("palpate-lock-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let lock = OutLock::acquire(&dir).unwrap();
        let held = std::fs::read_to_string(dir.join(LOCK_NAME)).unwrap();
        assert_eq!(held.trim(), std::process::id().to_string());
        // This process again (the lock is its own): taken over, not refused.
        drop(OutLock::acquire(&dir).unwrap());
        drop(lock);
        assert!(!dir.join(LOCK_NAME).exists());
        // A lock of a process that is gone (pid 2^22 + 1 is above Linux's largest), or of
        // one that is not palpate (pid 1, init), is stale.
        for stale in ["4194305\n", "1\n", "not a pid\n"] {
            std::fs::write(dir.join(LOCK_NAME), stale).unwrap();
            let lock = OutLock::acquire(&dir).unwrap();
            drop(lock);
            assert!(!dir.join(LOCK_NAME).exists(), "{stale}");
        }
    }
}
