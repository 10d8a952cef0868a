//! Reading a user's input file (scene, mesh, trajectory): a regular file (after symlinks) of
//! bounded size, so that a path to a device or a FIFO (`/dev/zero`, `/dev/stdin`) is a clear
//! error instead of a read that never ends.

use std::io;
use std::path::Path;

/// The largest mesh file read, bytes (a 1M-tet mesh is about 100 MB as text).
pub const MAX_MESH_BYTES: u64 = 8 << 30;
/// The largest scene file read, bytes.
pub const MAX_SCENE_BYTES: u64 = 64 << 20;
/// The largest scripted trajectory read, bytes.
pub const MAX_TRAJECTORY_BYTES: u64 = 1 << 30;

/// The bytes of `path` when it is a regular file of at most `max_bytes`; otherwise an
/// `InvalidInput` error saying which.
pub fn read_regular(path: &Path, max_bytes: u64) -> io::Result<Vec<u8>> {
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            "not a regular file (a directory, device or pipe)",
        ));
    }
    if meta.len() > max_bytes {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("{} bytes, more than the {} read", meta.len(), max_bytes),
        ));
    }
    std::fs::read(path)
}

/// [`read_regular`] as UTF-8 text.
pub fn read_regular_text(path: &Path, max_bytes: u64) -> io::Result<String> {
    String::from_utf8(read_regular(path, max_bytes)?)
        .map_err(|e| io::Error::new(io::ErrorKind::InvalidData, e))
}
