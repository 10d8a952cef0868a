//! Output files: VTU meshes with point and cell data (`state`), PVD series (`series`), and
//! the summary JSON (`summary`).
//! Every file is written to a temporary name and renamed into place, so a failed run never
//! leaves a half-written file under the final name.

pub mod particles;
pub mod png;
pub mod series;
pub mod state;
pub mod summary;
pub mod vtu;

use crate::error::{PalpateError, Result};
use std::path::Path;

/// Write `bytes` to `path` atomically (temporary file + rename).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let err = |source| PalpateError::OutputIo {
        path: path.to_path_buf(),
        source,
    };
    let tmp = path.with_extension(format!(
        "{}.partial",
        path.extension()
            .map(|e| e.to_string_lossy().into_owned())
            .unwrap_or_default()
    ));
    std::fs::write(&tmp, bytes).map_err(err)?;
    std::fs::rename(&tmp, path).map_err(err)
}

/// A ParaView collection (`.pvd`) listing `(time, file name)` pairs.
pub fn pvd(frames: &[(f64, String)]) -> String {
    let mut s = String::from(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n  <Collection>\n",
    );
    for (t, file) in frames {
        s.push_str(&format!(
            "    <DataSet timestep=\"{t:e}\" group=\"\" part=\"0\" file=\"{file}\"/>\n"
        ));
    }
    s.push_str("  </Collection>\n</VTKFile>\n");
    s
}
