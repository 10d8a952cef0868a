//! Mesh files in and out. [`read()`] and [`write()`] pick the format from the file extension.
//!
//! | extension               | read                                                  | write           |
//! |-------------------------|-------------------------------------------------------|-----------------|
//! | `.msh`                  | Gmsh 4.1 and 2.2, ASCII and binary                    | Gmsh 4.1 ASCII  |
//! | `.vtk`                  | VTK legacy, 4.2 and 5.1 cell layouts, ASCII and BINARY|                 |
//! | `.vtu`                  | VTK XML: ascii, base64, raw or base64 appended, zlib  | base64, UInt64  |
//! | `.node` / `.ele`        | TetGen, 0- or 1-based                                 |                 |
//! | `.pts` / `.elem` / `.lon` | openCARP, coordinates as written (usually µm)       |                 |
//!
//! Every reader refuses malformed input with a one-line [`PalpateError::MeshFile`] naming the
//! file and the line or byte offset, never panics, and never allocates from a count in a
//! header without capping it by what the file can hold. Readers keep linear tets and the
//! corners of quadratic ones (vertices used only as mid-edge nodes are then dropped), skip
//! lower-dimensional cells (points, lines, triangles, quads) and refuse other volume cells
//! (hexahedra, prisms, pyramids), so that a mesh never silently loses volume. Degenerate or
//! inverted tets are left to [`TetMesh::validate`].

mod carp;
mod cursor;
mod gmsh;
mod tetgen;
mod vtk_legacy;
mod vtu;

use super::TetMesh;
use crate::error::{PalpateError, Result};
use std::path::Path;

/// Read a tet mesh from a file; the format follows the extension (see the module table).
pub fn read(path: &Path) -> Result<TetMesh> {
    if path.is_dir() {
        return Err(file_err(path, "is a directory, not a mesh file".into()));
    }
    let ext = extension(path);
    let mut mesh = match ext.as_str() {
        "msh" => gmsh::read(path)?,
        "vtk" => vtk_legacy::read(path)?,
        "vtu" => vtu::read(path)?,
        "node" | "ele" => tetgen::read(path)?,
        "pts" | "elem" | "lon" => carp::read(path)?,
        _ => {
            return Err(file_err(
                path,
                if ext.is_empty() {
                    "the file name has no extension, which picks the format (supported: .msh, .vtk, .vtu, .node/.ele, .pts/.elem)".to_string()
                } else {
                    format!(
                        "unsupported mesh format '.{ext}' (supported: .msh, .vtk, .vtu, .node/.ele, .pts/.elem)"
                    )
                },
            ))
        }
    };
    finish(path, &mut mesh)?;
    Ok(mesh)
}

/// Write a tet mesh; the format follows the extension: `.vtu` (VTK XML, binary) or `.msh`
/// (Gmsh 4.1 ASCII). The file is written to a temporary name and renamed into place.
pub fn write(path: &Path, mesh: &TetMesh) -> Result<()> {
    let writer = writer_for(path)?;
    check_lengths(mesh).map_err(|m| file_err(path, format!("cannot write: {m}")))?;
    let bytes = writer(mesh).map_err(|m| file_err(path, format!("cannot write: {m}")))?;
    crate::output::write_atomic(path, &bytes)
}

/// Refuse a path [`write`] could not write a mesh to, before any work: an extension that
/// picks no format, a directory, or a folder that does not exist.
pub fn check_writable(path: &Path) -> Result<()> {
    writer_for(path)?;
    if path.is_dir() {
        return Err(file_err(
            path,
            "is a directory: give a file name ending in .vtu or .msh".into(),
        ));
    }
    let parent = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    if !parent.is_dir() {
        let what = if parent.exists() {
            "is not a folder"
        } else {
            "does not exist"
        };
        return Err(file_err(
            path,
            format!("cannot write: folder {} {what}", parent.display()),
        ));
    }
    Ok(())
}

/// A mesh format's writer: the file's bytes, or why it cannot write the mesh.
type MeshWriter = fn(&TetMesh) -> Result<Vec<u8>, String>;

/// The writer of the format `path`'s extension picks.
fn writer_for(path: &Path) -> Result<MeshWriter> {
    let ext = extension(path);
    Ok(match ext.as_str() {
        "vtu" => vtu::write,
        "msh" => gmsh::write,
        "" => {
            return Err(file_err(
                path,
                "needs a file name ending in .vtu or .msh (the extension picks the format)".into(),
            ))
        }
        _ => {
            return Err(file_err(
                path,
                format!("cannot write mesh format '.{ext}' (supported: .vtu, .msh)"),
            ))
        }
    })
}

fn extension(path: &Path) -> String {
    path.extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default()
}

/// A [`PalpateError::MeshFile`]; line breaks from file content are escaped so the message
/// stays on one line.
fn file_err(path: &Path, message: String) -> PalpateError {
    PalpateError::MeshFile {
        path: path.to_path_buf(),
        message: message.replace('\n', "\\n").replace('\r', "\\r"),
    }
}

/// The bytes of a file.
fn read_bytes(path: &Path) -> Result<Vec<u8>> {
    let bytes = crate::input::read_regular(path, crate::input::MAX_MESH_BYTES)
        .map_err(|e| file_err(path, format!("cannot read: {e}")))?;
    if bytes.iter().all(u8::is_ascii_whitespace) {
        return Err(file_err(path, "empty file".into()));
    }
    Ok(bytes)
}

/// Capacity for `n` items of at least `min_bytes` bytes each read from `available` bytes:
/// never more than the file can hold, whatever a header claims.
fn cap(n: u64, available: usize, min_bytes: usize) -> usize {
    n.min((available / min_bytes.max(1)) as u64) as usize
}

/// A region id or tag mask from a file value: an integer in 0..=u32::MAX.
fn to_u32(v: f64) -> Option<u32> {
    (v.fract() == 0.0 && (0.0..=u32::MAX as f64).contains(&v)).then_some(v as u32)
}

/// Array lengths of a mesh agree with its vertex and tet counts.
fn check_lengths(mesh: &TetMesh) -> Result<(), String> {
    let (nv, nt) = (mesh.positions.len(), mesh.tets.len());
    let bad = |what: &str, n: usize, of: &str, m: usize| Err(format!("{n} {what} for {m} {of}"));
    if mesh.regions.len() != nt {
        return bad("region ids", mesh.regions.len(), "tets", nt);
    }
    if !mesh.vertex_tags.is_empty() && mesh.vertex_tags.len() != nv {
        return bad("vertex tags", mesh.vertex_tags.len(), "vertices", nv);
    }
    if !mesh.fibres.is_empty() && mesh.fibres.len() != nt {
        return bad("fibre directions", mesh.fibres.len(), "tets", nt);
    }
    if let Some((t, v)) = mesh
        .tets
        .iter()
        .enumerate()
        .find_map(|(t, tet)| tet.iter().find(|&&v| v as usize >= nv).map(|v| (t, *v)))
    {
        return Err(format!("tet {t} refers to vertex {v} of {nv}"));
    }
    Ok(())
}

/// Common checks and clean-up after every reader: lengths agree, no tets means an error,
/// fibres are unit (zero vectors, "no fibre" in openCARP, stay zero), and vertices that no
/// tet uses are dropped when they were mid-edge nodes of quadratic tets.
fn finish(path: &Path, mesh: &mut TetMesh) -> Result<()> {
    if mesh.tets.is_empty() {
        return Err(file_err(path, "the file holds no tetrahedra".into()));
    }
    check_lengths(mesh).map_err(|m| file_err(path, m))?;
    for (t, f) in mesh.fibres.iter_mut().enumerate() {
        if !f.is_finite() {
            return Err(file_err(
                path,
                format!(
                    "fibre of tet {t} is not finite: ({}, {}, {})",
                    f.x, f.y, f.z
                ),
            ));
        }
        // Scaled first (crate::scene::unit_direction): a direction whose length over- or
        // underflows (1e300, 1e-200) keeps its direction instead of becoming zero.
        *f = crate::scene::unit_direction(f.to_array()).unwrap_or(glam::DVec3::ZERO);
    }
    Ok(())
}

/// Drop the vertices that no tet uses (the mid-edge nodes of quadratic tets once only their
/// corners are kept) and renumber the rest in order; tags follow their vertices.
fn drop_unused_vertices(mesh: &mut TetMesh) {
    let mut new_index = vec![u32::MAX; mesh.positions.len()];
    for &v in mesh.tets.iter().flatten() {
        if let Some(slot) = new_index.get_mut(v as usize) {
            *slot = 0;
        }
    }
    for (next, slot) in new_index.iter_mut().filter(|s| **s == 0).enumerate() {
        *slot = next as u32;
    }
    let keep = |i: &usize| new_index[*i] != u32::MAX;
    mesh.positions = (0..mesh.positions.len())
        .filter(keep)
        .map(|i| mesh.positions[i])
        .collect();
    if !mesh.vertex_tags.is_empty() {
        mesh.vertex_tags = (0..mesh.vertex_tags.len())
            .filter(keep)
            .map(|i| mesh.vertex_tags[i])
            .collect();
    }
    for v in mesh.tets.iter_mut().flatten() {
        if let Some(&n) = new_index.get(*v as usize) {
            *v = n;
        }
    }
}
