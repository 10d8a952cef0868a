//! One job at a time in an output folder: `palpate run` and `palpate haptic` hold an
//! exclusive `flock(2)` on `.palpate.lock` in `--out` (the file holds the holder's process
//! id, for the message) from before they remove an earlier run's files until they have
//! written their own, so that a second job into the same folder is refused instead of
//! deleting the first one's frames while it runs and mixing its files with them. The kernel
//! releases the lock when its holder ends however it ends (killed, or ended at once by a
//! second Ctrl-C), so a lock is never stale; the holder removes the file when it is done.
//! Unix only: elsewhere, and on a file system that has no locks, nothing is locked.

use crate::error::{PalpateError, Result};
use std::path::{Path, PathBuf};

/// The lock file's name in the output folder.
pub const LOCK_NAME: &str = ".palpate.lock";

/// A held lock on an output folder, released (its file removed) when dropped.
#[derive(Debug)]
pub struct OutLock {
    #[cfg(unix)]
    held: Option<(PathBuf, std::fs::File)>,
}

impl OutLock {
    /// The lock on `dir` for a job about to write or remove anything there, unless a stop was
    /// asked for while it was being built: then [`PalpateError::StoppedBeforeStart`] (before
    /// `starting`), the folder untouched.
    pub fn claim(dir: &Path, starting: &str) -> Result<OutLock> {
        if crate::interrupt::requested() {
            return Err(PalpateError::StoppedBeforeStart(starting.into()));
        }
        OutLock::acquire(dir)
    }

    /// Take the lock on `dir` (which exists), or fail naming the job that holds it.
    pub fn acquire(dir: &Path) -> Result<OutLock> {
        #[cfg(unix)]
        {
            use std::io::{Seek, Write};
            use std::os::unix::fs::MetadataExt;
            use std::os::unix::io::AsRawFd;
            let path = dir.join(LOCK_NAME);
            let io = |source| PalpateError::OutputIo {
                path: path.clone(),
                source,
            };
            // A holder removes the file as it ends: a lock taken on a file that the path no
            // longer names is tried again on the new one.
            for _ in 0..8 {
                let mut file = std::fs::OpenOptions::new()
                    .read(true)
                    .write(true)
                    .create(true)
                    .truncate(false)
                    .open(&path)
                    .map_err(io)?;
                // SAFETY: flock(2) on a descriptor this File owns.
                if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } != 0 {
                    let e = std::io::Error::last_os_error();
                    if e.raw_os_error() != Some(libc::EWOULDBLOCK) {
                        // A file system without locks (some network and FUSE mounts): the
                        // job runs unlocked there, as before locks, rather than not at all.
                        drop(file);
                        let _ = std::fs::remove_file(&path);
                        return Ok(OutLock { held: None });
                    }
                    let who = std::fs::read_to_string(&path)
                        .ok()
                        .and_then(|t| t.trim().parse::<u32>().ok())
                        .map_or(String::new(), |pid| format!(" (process {pid})"));
                    return Err(PalpateError::Usage(format!(
                        "{}: another palpate job{who} is writing its outputs here; wait for it to end or give another --out",
                        dir.display()
                    )));
                }
                let same = match (std::fs::metadata(&path), file.metadata()) {
                    (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
                    _ => false,
                };
                if !same {
                    continue;
                }
                let written = file
                    .set_len(0)
                    .and_then(|()| file.rewind())
                    .and_then(|()| writeln!(file, "{}", std::process::id()));
                if let Err(e) = written {
                    let _ = std::fs::remove_file(&path);
                    return Err(io(e));
                }
                return Ok(OutLock {
                    held: Some((path, file)),
                });
            }
            Err(PalpateError::Usage(format!(
                "{}: the output folder's lock ({LOCK_NAME}) kept changing hands as this job started (other jobs starting into it); give another --out",
                dir.display()
            )))
        }
        #[cfg(not(unix))]
        {
            let _ = dir;
            Ok(OutLock {})
        }
    }
}

impl Drop for OutLock {
    fn drop(&mut self) {
        // Removed while still held, then released: a job that opened the old file meanwhile
        // finds the path no longer names it, and tries again.
        #[cfg(unix)]
        if let Some((path, file)) = self.held.take() {
            let _ = std::fs::remove_file(&path);
            drop(file);
        }
    }
}

#[cfg(all(test, unix))]
mod tests {
    use super::{OutLock, LOCK_NAME};

    /// A folder is locked once: a second lock on it, from this process too, is refused
    /// while the first is held; once it is dropped the file is gone and the folder free. A
    /// lock file that no one holds (left by a job that was killed: the kernel released its
    /// lock) does not stand in the way.
    #[test]
    fn a_folder_is_locked_once_and_a_left_lock_file_is_free() {
        let dir = std::env::temp_dir().join(format!("palpate-lock-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let lock = OutLock::acquire(&dir).unwrap();
        let held = std::fs::read_to_string(dir.join(LOCK_NAME)).unwrap();
        assert_eq!(held.trim(), std::process::id().to_string());
        let e = OutLock::acquire(&dir).unwrap_err().to_string();
        assert!(
            e.contains(&format!(
                "another palpate job (process {})",
                std::process::id()
            )),
            "{e}"
        );
        drop(lock);
        assert!(!dir.join(LOCK_NAME).exists());
        std::fs::write(dir.join(LOCK_NAME), "4194305\n").unwrap();
        let lock = OutLock::acquire(&dir).unwrap();
        drop(lock);
        assert!(!dir.join(LOCK_NAME).exists());
    }
}
