//! openCARP meshes: `.pts` (points), `.elem` (elements) and, when present beside them,
//! `.lon` (fibres). Any of the three paths may be given.
//!
//! Coordinates are kept as written. openCARP meshes are usually in micrometres: a scene that
//! reads one sets its mesh `scale` (1e-6 for µm); the reader does not rescale.
//!
//! - `.pts`: a count line, then `x y z` per point.
//! - `.elem`: a count line, then `Tt i0 i1 i2 i3 [region]` per element (0-based indices;
//!   a missing region is 0). Other element types are refused.
//! - `.lon`: an optional header line with the number of directions per element (1 or 2), then
//!   one line of 3 or 6 values per element; the first direction is the fibre, a second
//!   (sheet) direction is ignored. Zero vectors (no fibre) stay zero.

use super::cursor::{show, Cursor};
use super::{cap, file_err, read_bytes, to_u32};
use crate::error::Result;
use crate::mesh::TetMesh;
use glam::DVec3;
use std::path::Path;

/// Read an openCARP mesh.
pub(super) fn read(path: &Path) -> Result<TetMesh> {
    let positions = read_pts(&path.with_extension("pts"))?;
    let (tets, regions) = read_elem(&path.with_extension("elem"), positions.len())?;
    let lon = path.with_extension("lon");
    let fibres = if lon.exists() {
        read_lon(&lon, tets.len())?
    } else {
        Vec::new()
    };
    Ok(TetMesh {
        positions,
        tets,
        regions,
        vertex_tags: Vec::new(),
        fibres,
    })
}

/// The tokens of the next non-blank line as text, and its start.
fn tokens<'a>(c: &mut Cursor<'a>) -> Result<Option<(usize, Vec<&'a str>)>> {
    let Some((start, line)) = c.nonblank_line() else {
        return Ok(None);
    };
    let text = std::str::from_utf8(line).map_err(|_| c.err(start, "line is not text"))?;
    Ok(Some((start, text.split_ascii_whitespace().collect())))
}

/// The count on the first line.
fn header(c: &mut Cursor, what: &str) -> Result<u64> {
    let Some((start, toks)) = tokens(c)? else {
        return Err(c.err(0, "empty file"));
    };
    toks.first()
        .and_then(|t| t.parse().ok())
        .filter(|_| toks.len() == 1)
        .ok_or_else(|| {
            c.err(
                start,
                format!("expected the {what} alone on the first line"),
            )
        })
}

/// After the declared items, only blank space may follow.
fn check_end(c: &mut Cursor, n: u64, what: &str) -> Result<()> {
    if c.at_end() {
        Ok(())
    } else {
        Err(c.err_here(format!(
            "more data after the {n} {what} the header declares"
        )))
    }
}

fn read_pts(path: &Path) -> Result<Vec<DVec3>> {
    let data = read_bytes(path)?;
    let mut c = Cursor::new(path, &data);
    let n = header(&mut c, "point count")?;
    let mut positions = Vec::with_capacity(cap(n, c.remaining(), 6));
    for _ in 0..n {
        positions.push(DVec3::new(
            c.float("coordinate")?,
            c.float("coordinate")?,
            c.float("coordinate")?,
        ));
    }
    check_end(&mut c, n, "points")?;
    Ok(positions)
}

fn read_elem(path: &Path, n_points: usize) -> Result<(Vec<[u32; 4]>, Vec<u32>)> {
    let data = read_bytes(path)?;
    let mut c = Cursor::new(path, &data);
    let m = header(&mut c, "element count")?;
    if m == 0 {
        return Err(c.err(0, "no tetrahedra (the header declares 0 elements)"));
    }
    let k = cap(m, c.remaining(), 10);
    let (mut tets, mut regions) = (Vec::with_capacity(k), Vec::with_capacity(k));
    for e in 0..m {
        let (start, toks) = tokens(&mut c)?.ok_or_else(|| {
            file_err(
                path,
                format!("header declares {m} elements but the file has {e}"),
            )
        })?;
        match toks[0] {
            "Tt" if toks.len() == 5 || toks.len() == 6 => {}
            "Tt" => {
                return Err(c.err(
                    start,
                    format!("element {e}: Tt needs 4 indices and an optional region"),
                ))
            }
            "Tr" | "Qd" | "Ln" | "Hx" | "Py" | "Pr" | "Oc" => {
                return Err(c.err(
                    start,
                    format!(
                        "element {e}: type {} is not supported: only Tt (tetrahedra)",
                        toks[0]
                    ),
                ))
            }
            t => {
                return Err(c.err(
                    start,
                    format!("element {e}: unknown element type {}", show(t.as_bytes())),
                ))
            }
        }
        let mut tet = [0u32; 4];
        for (k, v) in tet.iter_mut().enumerate() {
            *v = toks[1 + k]
                .parse::<u32>()
                .ok()
                .filter(|&i| (i as usize) < n_points)
                .ok_or_else(|| {
                    c.err(
                        start,
                        format!(
                            "element {e}: node index {} is not in 0..{n_points}",
                            show(toks[1 + k].as_bytes())
                        ),
                    )
                })?;
        }
        let region = match toks.get(5) {
            None => 0,
            Some(r) => r.parse::<f64>().ok().and_then(to_u32).ok_or_else(|| {
                c.err(
                    start,
                    format!(
                        "element {e}: region {} is not an integer in 0..=4294967295",
                        show(r.as_bytes())
                    ),
                )
            })?,
        };
        tets.push(tet);
        regions.push(region);
    }
    check_end(&mut c, m, "elements")?;
    Ok((tets, regions))
}

fn read_lon(path: &Path, n_elements: usize) -> Result<Vec<DVec3>> {
    let data = read_bytes(path)?;
    let mut c = Cursor::new(path, &data);
    let Some((start, first)) = tokens(&mut c)? else {
        return Err(c.err(0, "empty file"));
    };
    // A header line with the number of directions, or the first data line (old files).
    let (dirs, mut pending) = match first.as_slice() {
        ["1"] => (1, None),
        ["2"] => (2, None),
        t if t.len() == 3 || t.len() == 6 => (t.len() / 3, Some((start, first))),
        _ => {
            return Err(c.err(
                start,
                "expected 1 or 2 (directions per element) or a line of 3 or 6 values",
            ))
        }
    };
    let mut fibres = Vec::with_capacity(n_elements.min(c.remaining() / 6 + 1));
    for e in 0..n_elements {
        let (start, toks) = match pending.take() {
            Some(p) => p,
            None => tokens(&mut c)?.ok_or_else(|| {
                file_err(
                    path,
                    format!("the mesh has {n_elements} elements but the file has {e} fibres"),
                )
            })?,
        };
        let v: Vec<f64> = toks.iter().filter_map(|t| t.parse().ok()).collect();
        if toks.len() != 3 * dirs || v.len() != toks.len() || v.iter().any(|x| !x.is_finite()) {
            let found = if toks.len() != 3 * dirs {
                format!("{} values", toks.len())
            } else {
                "a value that is not a finite number".to_string()
            };
            return Err(c.err(
                start,
                format!(
                    "element {e}: expected {} finite numbers ({dirs} direction{} an element, as the header says), found {found}",
                    3 * dirs,
                    if dirs == 1 { "" } else { "s" }
                ),
            ));
        }
        fibres.push(DVec3::new(v[0], v[1], v[2]));
    }
    check_end(&mut c, n_elements as u64, "fibres")?;
    Ok(fibres)
}
