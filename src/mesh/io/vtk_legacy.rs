//! VTK legacy `.vtk` unstructured grids, ASCII or BINARY (big-endian), with cells either as
//! a count-prefixed list (`CELLS n size`, file version ≤ 4.2) or as `OFFSETS` and
//! `CONNECTIVITY` arrays (version 5.1).
//!
//! Cells of type 10 (tet) and the corners of type 24 (quadratic tet) are kept; vertices,
//! lines and polygons are skipped; other volume cells are refused. Attribute or field arrays
//! give: regions (cell array named as in [`REGION_NAMES`]), fibres (cell array `fibres` or
//! `fibers`, 3 components), vertex tags (point array `vertex_tags`).

use super::cursor::{show, Cursor, Num};
use super::{cap, drop_unused_vertices, read_bytes, to_u32};
use crate::error::Result;
use crate::mesh::TetMesh;
use glam::DVec3;
use std::path::Path;

/// Cell array names taken as the region id, in order of preference (compared in lower case).
const REGION_NAMES: [&str; 8] = [
    "material",
    "materials",
    "region",
    "regions",
    "gmsh:physical",
    "cellentityids",
    "medit:ref",
    "subdomain",
];

/// Cell array names taken as fibre directions.
const FIBRE_NAMES: [&str; 4] = ["fibres", "fibers", "fibre", "fiber"];

/// Point array name taken as vertex tags.
const TAG_NAME: &str = "vertex_tags";

/// What a VTK cell type is to us: `Some(Ok(n))` a tet of `n` nodes (corners first),
/// `Some(Err(name))` a volume cell we refuse, `None` a lower-dimensional cell to skip.
fn cell_kind(ty: i64) -> Option<Result<usize, &'static str>> {
    match ty {
        10 => Some(Ok(4)),
        24 => Some(Ok(10)),
        11 | 12 | 25 | 29 | 33 | 72 | 79 => Some(Err("hexahedron")),
        13 | 26 | 32 | 73 | 80 => Some(Err("wedge")),
        14 | 27 | 74 | 81 => Some(Err("pyramid")),
        15 | 16 => Some(Err("prism")),
        42 => Some(Err("polyhedron")),
        71 | 78 => Some(Err("higher-order tetrahedron")),
        _ => None,
    }
}

/// The cells of a grid as flat connectivity with end offsets, and their types.
pub(super) struct Cells {
    pub connectivity: Vec<f64>,
    /// Start of each cell in `connectivity`, plus the end of the last.
    pub offsets: Vec<usize>,
    pub types: Vec<f64>,
}

/// The tets found among a grid's cells.
struct Assembled {
    pub tets: Vec<[u32; 4]>,
    /// Index of each kept tet among all cells.
    pub cell_of_tet: Vec<usize>,
    pub quadratic: bool,
}

/// The tets of `cells`, their point indices checked against `n_points`;
/// `Err((cell, message))` names the first bad cell.
fn assemble(cells: &Cells, n_points: usize) -> Result<Assembled, (usize, String)> {
    let mut out = Assembled {
        tets: Vec::new(),
        cell_of_tet: Vec::new(),
        quadratic: false,
    };
    for (c, &ty) in cells.types.iter().enumerate() {
        let (a, b) = (cells.offsets[c], cells.offsets[c + 1]);
        let kind = if ty.fract() == 0.0 && ty.abs() < 1e9 {
            cell_kind(ty as i64)
        } else {
            return Err((c, format!("cell type {ty} is not valid")));
        };
        let nodes = match kind {
            None => continue,
            Some(Err(name)) => {
                return Err((
                    c,
                    format!("a {name} (VTK type {ty}) is not supported: only tetrahedra"),
                ))
            }
            Some(Ok(n)) => n,
        };
        if b - a != nodes {
            return Err((
                c,
                format!("VTK type {ty} needs {nodes} points, the cell has {}", b - a),
            ));
        }
        let mut tet = [0u32; 4];
        for (t, &v) in tet.iter_mut().zip(&cells.connectivity[a..b]) {
            *t = to_u32(v)
                .filter(|&i| (i as usize) < n_points)
                .ok_or_else(|| (c, format!("point index {v} is not in 0..{n_points}")))?;
        }
        out.tets.push(tet);
        out.cell_of_tet.push(c);
        out.quadratic |= nodes > 4;
    }
    Ok(out)
}

/// A named data array with its components.
pub(super) struct Array {
    pub name: String,
    pub components: usize,
    pub values: Vec<f64>,
    /// Where it was read, for errors.
    pub pos: usize,
}

/// Whether an array of this (lower-case) name and components is one we use.
pub(super) fn wanted(point_data: bool, name: &str, components: usize) -> bool {
    if point_data {
        name == TAG_NAME && components == 1
    } else {
        (REGION_NAMES.contains(&name) && components == 1)
            || (FIBRE_NAMES.contains(&name) && components == 3)
    }
}

/// Regions, fibres (per tet) and vertex tags from the data arrays; `Err((pos, message))`.
fn attributes(
    mesh: &mut TetMesh,
    cell_of_tet: &[usize],
    n_cells: usize,
    cell_data: &[Array],
    point_data: &[Array],
) -> Result<(), (usize, String)> {
    let check = |a: &Array, n: usize, of: &str| {
        if a.values.len() != n * a.components {
            Err((
                a.pos,
                format!(
                    "array '{}' has {} values for {n} {of} of {} components",
                    a.name,
                    a.values.len(),
                    a.components
                ),
            ))
        } else {
            Ok(())
        }
    };
    let region = REGION_NAMES
        .iter()
        .find_map(|n| cell_data.iter().find(|a| a.name == *n && a.components == 1));
    mesh.regions = match region {
        Some(a) => {
            check(a, n_cells, "cells")?;
            cell_of_tet
                .iter()
                .map(|&c| {
                    let v = a.values[c];
                    to_u32(v).ok_or_else(|| {
                        (
                            a.pos,
                            format!("region {v} of cell {c} is not an integer in 0..=4294967295"),
                        )
                    })
                })
                .collect::<Result<_, _>>()?
        }
        None => vec![0; cell_of_tet.len()],
    };
    if let Some(a) = cell_data
        .iter()
        .find(|a| FIBRE_NAMES.contains(&a.name.as_str()) && a.components == 3)
    {
        check(a, n_cells, "cells")?;
        mesh.fibres = cell_of_tet
            .iter()
            .map(|&c| DVec3::new(a.values[3 * c], a.values[3 * c + 1], a.values[3 * c + 2]))
            .collect();
    }
    if let Some(a) = point_data
        .iter()
        .find(|a| a.name == TAG_NAME && a.components == 1)
    {
        check(a, mesh.positions.len(), "points")?;
        mesh.vertex_tags = a
            .values
            .iter()
            .enumerate()
            .map(|(i, &v)| {
                to_u32(v).ok_or_else(|| {
                    (
                        a.pos,
                        format!("vertex tag {v} of point {i} is not an integer in 0..=4294967295"),
                    )
                })
            })
            .collect::<Result<_, _>>()?;
    }
    Ok(())
}

/// Binary type of a legacy data type name.
fn num_type(name: &str) -> Option<Num> {
    Some(match name.to_ascii_lowercase().as_str() {
        "unsigned_char" | "vtktypeuint8" => Num::UInt(1),
        "char" | "signed_char" | "vtktypeint8" => Num::Int(1),
        "unsigned_short" | "vtktypeuint16" => Num::UInt(2),
        "short" | "vtktypeint16" => Num::Int(2),
        "unsigned_int" | "vtktypeuint32" => Num::UInt(4),
        "int" | "vtktypeint32" => Num::Int(4),
        "unsigned_long" | "vtktypeuint64" => Num::UInt(8),
        "long" | "vtktypeint64" | "vtkidtype" => Num::Int(8),
        "float" | "vtktypefloat32" => Num::Float(4),
        "double" | "vtktypefloat64" => Num::Float(8),
        _ => return None,
    })
}

#[derive(Clone, Copy, PartialEq)]
enum Attr {
    None,
    Point,
    Cell,
}

struct Reader<'a> {
    c: Cursor<'a>,
    binary: bool,
    attr: Attr,
    attr_count: u64,
    point_data: Vec<Array>,
    cell_data: Vec<Array>,
}

impl Reader<'_> {
    /// A data type token.
    fn data_type(&mut self) -> Result<Num> {
        let (pos, t) = self.c.word("data type")?;
        num_type(t).ok_or_else(|| {
            self.c.err(
                pos,
                format!("data type {} is not supported", show(t.as_bytes())),
            )
        })
    }

    /// `count` values of type `ty` (binary data starts on the next line).
    fn values(&mut self, count: u64, ty: Num, what: &str) -> Result<Vec<f64>> {
        if self.binary {
            self.c.end_line()?;
            let size = ty.size();
            let pos = self.c.pos;
            let bytes = count
                .checked_mul(size as u64)
                .filter(|&b| b <= self.c.remaining() as u64)
                .ok_or_else(|| {
                    self.c.err(
                        pos,
                        format!(
                            "file ends inside {what}: {count} values of {size} bytes declared, {} bytes left",
                            self.c.remaining()
                        ),
                    )
                })?;
            let b = self.c.take(bytes as usize, what)?;
            return Ok(b.chunks_exact(size).map(|ch| ty.decode(ch, true)).collect());
        }
        let mut v = Vec::with_capacity(cap(count, self.c.remaining(), 2));
        for _ in 0..count {
            v.push(self.c.num::<f64>(what)?);
        }
        Ok(v)
    }

    /// Values of an attribute array: kept when wanted, else read and dropped.
    fn attribute(
        &mut self,
        pos: usize,
        name: &str,
        components: u64,
        tuples: u64,
        ty: Num,
    ) -> Result<()> {
        let count = tuples.checked_mul(components).ok_or_else(|| {
            self.c.err(
                pos,
                format!("{tuples} tuples of {components} components is too many"),
            )
        })?;
        let values = self.values(count, ty, name)?;
        let name = name.to_ascii_lowercase();
        let point = self.attr == Attr::Point;
        if self.attr != Attr::None && wanted(point, &name, components as usize) {
            let a = Array {
                name,
                components: components as usize,
                values,
                pos,
            };
            if point {
                self.point_data.push(a);
            } else {
                self.cell_data.push(a);
            }
        }
        Ok(())
    }

    /// A `METADATA` block (after its keyword): up to a blank line.
    fn skip_metadata(&mut self) {
        self.c.line();
        while let Some((_, l)) = self.c.line() {
            if l.trim_ascii().is_empty() {
                break;
            }
        }
    }

    /// Bytes (binary) or floats (ASCII) of colour and lookup-table data.
    fn colours(&mut self, count: u64, what: &str) -> Result<()> {
        let ty = if self.binary {
            Num::UInt(1)
        } else {
            Num::Float(4)
        };
        self.values(count, ty, what).map(|_| ())
    }
}

/// Read a legacy `.vtk` file.
pub(super) fn read(path: &Path) -> Result<TetMesh> {
    let data = read_bytes(path)?;
    let mut c = Cursor::new(path, &data);
    let (_, first) = c.line().unwrap_or((0, b""));
    if !first
        .trim_ascii()
        .to_ascii_lowercase()
        .starts_with(b"# vtk datafile version")
    {
        return Err(c.err(
            0,
            format!("not a VTK legacy file: first line is {}", show(first)),
        ));
    }
    c.line(); // title
    let (fpos, format) = c.word("ASCII or BINARY")?;
    let binary = match format.to_ascii_uppercase().as_str() {
        "ASCII" => false,
        "BINARY" => true,
        _ => {
            return Err(c.err(
                fpos,
                format!(
                    "expected ASCII or BINARY, found {}",
                    show(format.as_bytes())
                ),
            ))
        }
    };
    c.binary = binary;
    let mut r = Reader {
        c,
        binary,
        attr: Attr::None,
        attr_count: 0,
        point_data: Vec::new(),
        cell_data: Vec::new(),
    };
    let mut dataset = false;
    let mut points: Option<(usize, Vec<f64>)> = None;
    let mut cells: Option<(usize, Cells)> = None;
    let mut types: Option<(usize, Vec<f64>)> = None;
    while let Some((pos, kw)) = r.c.token() {
        let kw = String::from_utf8_lossy(kw).to_ascii_uppercase();
        r.c.context = "";
        if !dataset && kw != "DATASET" {
            return Err(r.c.err(
                pos,
                format!("expected DATASET, found {}", show(kw.as_bytes())),
            ));
        }
        match kw.as_str() {
            "DATASET" => {
                let (p, t) = r.c.word("dataset type")?;
                if !t.eq_ignore_ascii_case("UNSTRUCTURED_GRID") || dataset {
                    return Err(r.c.err(
                        p,
                        format!(
                            "DATASET {} is not supported: only one UNSTRUCTURED_GRID",
                            show(t.as_bytes())
                        ),
                    ));
                }
                dataset = true;
            }
            "POINTS" => {
                r.c.context = "POINTS";
                let n: u64 = r.c.num("number of points")?;
                let ty = r.data_type()?;
                let count = n.saturating_mul(3);
                points = Some((pos, r.values(count, ty, "point coordinates")?));
            }
            "CELLS" => {
                r.c.context = "CELLS";
                let a: u64 = r.c.num("number of cells")?;
                let b: u64 = r.c.num("size of the cell list")?;
                let list = if r
                    .c
                    .peek()
                    .is_some_and(|t| t.eq_ignore_ascii_case(b"OFFSETS"))
                {
                    r.c.token();
                    let ty = r.data_type()?;
                    let offsets = r.values(a, ty, "cell offsets")?;
                    r.c.expect("CONNECTIVITY")?;
                    let ty = r.data_type()?;
                    let connectivity = r.values(b, ty, "cell connectivity")?;
                    offsets_cells(&offsets, connectivity)
                } else {
                    let list = r.values(b, Num::Int(4), "cell list")?;
                    list_cells(a, &list)
                };
                let list = list.map_err(|m| r.c.err(pos, m))?;
                cells = Some((pos, list));
            }
            "CELL_TYPES" => {
                r.c.context = "CELL_TYPES";
                let n: u64 = r.c.num("number of cells")?;
                types = Some((pos, r.values(n, Num::Int(4), "cell types")?));
            }
            "CELL_DATA" | "POINT_DATA" => {
                r.attr = if kw == "CELL_DATA" {
                    Attr::Cell
                } else {
                    Attr::Point
                };
                r.attr_count = r.c.num("number of values")?;
            }
            "SCALARS" => {
                r.c.context = "SCALARS";
                let (_, name) = r.c.word("array name")?;
                let ty = r.data_type()?;
                let mut comps = 1;
                if let Some(k) =
                    r.c.peek_on_line()
                        .and_then(|t| std::str::from_utf8(t).ok()?.parse::<u64>().ok())
                {
                    r.c.token();
                    comps = k;
                }
                if r.c
                    .peek()
                    .is_some_and(|t| t.eq_ignore_ascii_case(b"LOOKUP_TABLE"))
                {
                    r.c.token();
                    r.c.word("lookup table name")?;
                }
                r.attribute(pos, name, comps, r.attr_count, ty)?;
            }
            "VECTORS" | "NORMALS" | "TENSORS" | "TENSORS6" | "GLOBAL_IDS" | "PEDIGREE_IDS" => {
                let comps = match kw.as_str() {
                    "VECTORS" | "NORMALS" => 3,
                    "TENSORS" => 9,
                    "TENSORS6" => 6,
                    _ => 1,
                };
                let (_, name) = r.c.word("array name")?;
                let ty = r.data_type()?;
                r.attribute(pos, name, comps, r.attr_count, ty)?;
            }
            "TEXTURE_COORDINATES" => {
                let (_, name) = r.c.word("array name")?;
                let dim: u64 = r.c.num("dimension")?;
                let ty = r.data_type()?;
                r.attribute(pos, name, dim, r.attr_count, ty)?;
            }
            "COLOR_SCALARS" => {
                r.c.word("array name")?;
                let k: u64 = r.c.num("number of values")?;
                r.colours(k.saturating_mul(r.attr_count), "colour scalars")?;
            }
            "LOOKUP_TABLE" => {
                r.c.word("table name")?;
                let k: u64 = r.c.num("table size")?;
                r.colours(k.saturating_mul(4), "lookup table")?;
            }
            "FIELD" => {
                r.c.word("field name")?;
                let n: u64 = r.c.num("number of arrays")?;
                for _ in 0..n {
                    // VTK writes a METADATA block after each array.
                    while r
                        .c
                        .peek()
                        .is_some_and(|t| t.eq_ignore_ascii_case(b"METADATA"))
                    {
                        r.c.token();
                        r.skip_metadata();
                    }
                    let (apos, name) = r.c.word("array name")?;
                    let comps: u64 = r.c.num("number of components")?;
                    let tuples: u64 = r.c.num("number of tuples")?;
                    let ty = r.data_type()?;
                    let lower = name.to_ascii_lowercase();
                    if r.attr != Attr::None
                        && tuples != r.attr_count
                        && wanted(r.attr == Attr::Point, &lower, comps as usize)
                    {
                        return Err(r.c.err(
                            apos,
                            format!(
                                "array '{name}' has {tuples} tuples, the data section declares {}",
                                r.attr_count
                            ),
                        ));
                    }
                    r.attribute(apos, name, comps, tuples, ty)?;
                }
            }
            "METADATA" => r.skip_metadata(),
            _ => {
                return Err(r
                    .c
                    .err(pos, format!("unknown keyword {}", show(kw.as_bytes()))))
            }
        }
    }
    let c = &r.c;
    let (ppos, coords) = points.ok_or_else(|| c.err(c.data.len(), "no POINTS"))?;
    let (cpos, mut cells) = cells.ok_or_else(|| c.err(c.data.len(), "no CELLS"))?;
    let (tpos, types) = types.ok_or_else(|| c.err(c.data.len(), "no CELL_TYPES"))?;
    cells.types = types;
    let places = Places {
        points: ppos,
        cells: cpos,
        types: tpos,
    };
    let mesh =
        grid_mesh(&coords, &cells, &places, &r.cell_data, &r.point_data).map_err(|(p, m)| {
            // Named by the section it is about (at its keyword's line), not by the last one
            // read.
            let mut at = c.clone();
            at.context = match p {
                _ if p == ppos => "POINTS",
                _ if p == cpos => "CELLS",
                _ if p == tpos => "CELL_TYPES",
                _ => "",
            };
            at.err(p, m)
        })?;
    if mesh.tets.is_empty() {
        return Err(c.err(tpos, "no cell is a tetrahedron (VTK type 10 or 24)"));
    }
    Ok(mesh)
}

/// Where the arrays of a grid were read, for errors.
pub(super) struct Places {
    pub points: usize,
    pub cells: usize,
    pub types: usize,
}

/// The tet mesh of a grid: coordinates (xyz per point), cells, and data arrays. Vertices
/// used only as mid-edge nodes of quadratic tets are dropped. `Err((position, message))`.
pub(super) fn grid_mesh(
    coords: &[f64],
    cells: &Cells,
    places: &Places,
    cell_data: &[Array],
    point_data: &[Array],
) -> Result<TetMesh, (usize, String)> {
    if !coords.len().is_multiple_of(3) {
        let m = format!("{} point coordinates is not a multiple of 3", coords.len());
        return Err((places.points, m));
    }
    let positions: Vec<DVec3> = coords
        .chunks_exact(3)
        .map(|p| DVec3::new(p[0], p[1], p[2]))
        .collect();
    if let Some(i) = positions.iter().position(|p| !p.is_finite()) {
        return Err((
            places.points,
            format!("point {i} has a non-finite coordinate"),
        ));
    }
    if cells.types.len() + 1 != cells.offsets.len() {
        let m = format!(
            "{} cell types for {} cells",
            cells.types.len(),
            cells.offsets.len().saturating_sub(1)
        );
        return Err((places.types, m));
    }
    let a = assemble(cells, positions.len())
        .map_err(|(k, m)| (places.cells, format!("cell {k}: {m}")))?;
    let mut mesh = TetMesh {
        positions,
        tets: a.tets,
        ..Default::default()
    };
    attributes(
        &mut mesh,
        &a.cell_of_tet,
        cells.types.len(),
        cell_data,
        point_data,
    )?;
    if a.quadratic {
        drop_unused_vertices(&mut mesh);
    }
    Ok(mesh)
}

/// Cells from a count-prefixed list `[n, i0, …, n, …]` of `n_cells` cells.
fn list_cells(n_cells: u64, list: &[f64]) -> Result<Cells, String> {
    let mut offsets = Vec::with_capacity(cap(n_cells, list.len(), 1) + 1);
    let mut connectivity = Vec::with_capacity(list.len());
    let mut i = 0;
    offsets.push(0);
    for c in 0..n_cells {
        let n = list
            .get(i)
            .and_then(|&n| to_u32(n))
            .ok_or_else(|| format!("cell {c}: the cell list ends or has a bad point count"))?
            as usize;
        let nodes = list
            .get(i + 1..i + 1 + n)
            .ok_or_else(|| format!("cell {c}: the cell list ends inside the cell"))?;
        connectivity.extend_from_slice(nodes);
        offsets.push(connectivity.len());
        i += 1 + n;
    }
    if i != list.len() {
        return Err(format!(
            "the cell list holds {} values, {n_cells} cells use {i}",
            list.len()
        ));
    }
    Ok(Cells {
        connectivity,
        offsets,
        types: Vec::new(),
    })
}

/// Cells from offsets (starting at 0, one more than the cells) and connectivity.
pub(super) fn offsets_cells(offsets: &[f64], connectivity: Vec<f64>) -> Result<Cells, String> {
    let mut out = Vec::with_capacity(offsets.len());
    for &o in offsets {
        let o = to_u32(o)
            .map(|o| o as usize)
            .filter(|&o| o <= connectivity.len() && out.last().is_none_or(|&prev| o >= prev))
            .ok_or_else(|| {
                format!(
                    "offset {o} decreases or is not in 0..={} (the connectivity length)",
                    connectivity.len()
                )
            })?;
        out.push(o);
    }
    if out.first().is_some_and(|&o| o != 0)
        || out.last().is_some_and(|&o| o != connectivity.len())
        || out.is_empty()
    {
        return Err(format!(
            "offsets must run from 0 to {} (the connectivity length)",
            connectivity.len()
        ));
    }
    Ok(Cells {
        connectivity,
        offsets: out,
        types: Vec::new(),
    })
}
