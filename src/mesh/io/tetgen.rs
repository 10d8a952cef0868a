//! TetGen `.node` + `.ele` pairs.

use super::{file_err, read_bytes, to_u32};
use crate::error::Result;
use crate::mesh::TetMesh;
use glam::DVec3;
use std::path::Path;

fn read_text(path: &Path) -> Result<String> {
    String::from_utf8(read_bytes(path)?).map_err(|e| {
        file_err(
            path,
            format!(
                "not a text file (invalid UTF-8 at byte {})",
                e.utf8_error().valid_up_to()
            ),
        )
    })
}

/// Data lines of a TetGen file: (1-based line number, tokens), comments and blanks dropped.
fn tetgen_lines(text: &str) -> impl Iterator<Item = (usize, Vec<&str>)> {
    text.lines().enumerate().filter_map(|(i, l)| {
        let l = l.split('#').next().unwrap_or("");
        let toks: Vec<&str> = l.split_whitespace().collect();
        (!toks.is_empty()).then_some((i + 1, toks))
    })
}

fn parse<T: std::str::FromStr>(
    path: &Path,
    line: usize,
    tok: Option<&&str>,
    what: &str,
) -> Result<T> {
    let tok = tok.ok_or_else(|| file_err(path, format!("line {line}: missing {what}")))?;
    tok.parse().map_err(|_| {
        file_err(
            path,
            format!("line {line}: {what} '{tok}' is not a valid number"),
        )
    })
}

/// TetGen `.node` + `.ele` (either path may be given; the other is found beside it).
/// Indices may start at 0 or 1 (the first node's index decides); every `.node` row has the
/// index, x, y, z and the header's attributes and boundary marker (unused). The first `.ele` attribute
/// column, a non-negative integer, becomes the region id; 10-node tets keep their corners.
pub(super) fn read(path: &Path) -> Result<TetMesh> {
    let node_path = path.with_extension("node");
    let ele_path = path.with_extension("ele");
    let node_text = read_text(&node_path)?;
    let mut lines = tetgen_lines(&node_text);
    let (hl, header) = lines
        .next()
        .ok_or_else(|| file_err(&node_path, "empty file: no header line".into()))?;
    let n: usize = parse(&node_path, hl, header.first(), "node count")?;
    let dim: usize = parse(&node_path, hl, header.get(1), "dimension")?;
    if dim != 3 {
        return Err(file_err(
            &node_path,
            format!("line {hl}: dimension {dim}, expected 3"),
        ));
    }
    let n_attr: usize = match header.get(2) {
        Some(_) => parse(&node_path, hl, header.get(2), "attribute count")?,
        None => 0,
    };
    let n_marker: usize = match header.get(3) {
        Some(_) => parse(&node_path, hl, header.get(3), "boundary marker count")?,
        None => 0,
    };
    if n_marker > 1 {
        return Err(file_err(
            &node_path,
            format!("line {hl}: boundary marker count {n_marker}, expected 0 or 1"),
        ));
    }
    // Index, x, y, z, the attributes and the marker: a row of another width is a file whose
    // header does not describe it (a 2-D file, a lost column), whose columns would be misread.
    let want = n_attr.checked_add(4 + n_marker).ok_or_else(|| {
        file_err(
            &node_path,
            format!("line {hl}: attribute count {n_attr} is too large"),
        )
    })?;
    let mut positions = Vec::with_capacity(n.min(node_text.len() / 8 + 1));
    let mut first_index = None;
    for (ln, toks) in lines.by_ref().take(n) {
        if toks.len() != want {
            return Err(file_err(
                &node_path,
                format!(
                    "line {ln}: {} values, but the header (line {hl}) declares {n_attr} attributes and {n_marker} boundary markers per node: expected {want}",
                    toks.len()
                ),
            ));
        }
        let idx: i64 = parse(&node_path, ln, toks.first(), "node index")?;
        let base = *first_index.get_or_insert(idx);
        if idx.checked_sub(base) != Some(positions.len() as i64) {
            return Err(file_err(
                &node_path,
                format!("line {ln}: node index {idx} out of sequence"),
            ));
        }
        let mut p = [0.0f64; 3];
        for (k, c) in p.iter_mut().enumerate() {
            *c = parse(&node_path, ln, toks.get(1 + k), "coordinate")?;
            if !c.is_finite() {
                return Err(file_err(
                    &node_path,
                    format!("line {ln}: coordinate {c} is not finite"),
                ));
            }
        }
        positions.push(DVec3::from_array(p));
    }
    if positions.len() != n {
        return Err(file_err(
            &node_path,
            format!(
                "header declares {n} nodes but the file has {}",
                positions.len()
            ),
        ));
    }
    let base = first_index.unwrap_or(0);
    if base != 0 && base != 1 {
        return Err(file_err(
            &node_path,
            format!("first node index {base}: expected 0 or 1"),
        ));
    }
    let ele_text = read_text(&ele_path)?;
    let mut lines = tetgen_lines(&ele_text);
    let (hl, header) = lines
        .next()
        .ok_or_else(|| file_err(&ele_path, "empty file: no header line".into()))?;
    let m: usize = parse(&ele_path, hl, header.first(), "element count")?;
    let npe: usize = parse(&ele_path, hl, header.get(1), "nodes per element")?;
    if npe != 4 && npe != 10 {
        return Err(file_err(
            &ele_path,
            format!("line {hl}: {npe} nodes per element, expected 4 or 10"),
        ));
    }
    let n_attr: usize = match header.get(2) {
        Some(_) => parse(&ele_path, hl, header.get(2), "attribute count")?,
        None => 0,
    };
    let mut tets = Vec::with_capacity(m.min(ele_text.len() / 8 + 1));
    let mut regions = Vec::with_capacity(tets.capacity());
    for (ln, toks) in lines.take(m) {
        let want = 1 + npe + n_attr;
        if toks.len() != want {
            return Err(file_err(
                &ele_path,
                format!(
                    "line {ln}: {} values, but the header (line {hl}) declares {npe} nodes and {n_attr} attributes per element: expected {want}",
                    toks.len()
                ),
            ));
        }
        let mut t = [0u32; 4];
        for (k, v) in t.iter_mut().enumerate() {
            let i: i64 = parse(&ele_path, ln, toks.get(1 + k), "node index")?;
            let local = i.saturating_sub(base);
            if local < 0 || local >= n as i64 {
                return Err(file_err(
                    &ele_path,
                    format!(
                        "line {ln}: node index {i} out of range ({base}..{})",
                        n as i64 + base - 1
                    ),
                ));
            }
            *v = local as u32;
        }
        let region = if n_attr > 0 {
            let a: f64 = parse(&ele_path, ln, toks.get(1 + npe), "attribute")?;
            to_u32(a).ok_or_else(|| {
                file_err(
                    &ele_path,
                    format!("line {ln}: region attribute {a} is not an integer in 0..=4294967295"),
                )
            })?
        } else {
            0
        };
        tets.push(t);
        regions.push(region);
    }
    if tets.len() != m {
        return Err(file_err(
            &ele_path,
            format!(
                "header declares {m} elements but the file has {}",
                tets.len()
            ),
        ));
    }
    if tets.is_empty() {
        return Err(file_err(
            &ele_path,
            format!("line {hl}: no tetrahedra (the header declares 0 elements)"),
        ));
    }
    let mut mesh = TetMesh {
        positions,
        tets,
        regions,
        ..Default::default()
    };
    if npe == 10 {
        super::drop_unused_vertices(&mut mesh);
    }
    Ok(mesh)
}
