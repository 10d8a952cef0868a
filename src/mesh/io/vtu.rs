//! VTK XML unstructured grids (`.vtu`). Reads every piece with DataArrays in `ascii`,
//! inline `binary` (base64) or `appended` (raw or base64) format, header UInt32 or UInt64,
//! either byte order, uncompressed or zlib-compressed (`vtkZLibDataCompressor`). Cells and
//! data arrays follow the legacy reader's rules ([`super::vtk_legacy`]). Writes binary
//! base64 with a UInt64 header.

use super::cursor::{find, show, uint, Cursor, Num};
use super::vtk_legacy::{grid_mesh, offsets_cells, wanted, Array, Places};
use super::{file_err, read_bytes};
use crate::error::Result;
use crate::mesh::TetMesh;
use crate::output::vtu::base64;
use std::path::Path;

/// An XML start tag: name, attributes, and the text up to the next tag.
struct Tag<'a> {
    name: &'a [u8],
    attrs: Vec<(&'a [u8], &'a [u8])>,
    /// Byte offset of `<`.
    pos: usize,
    /// The text after the tag up to the next `<` (empty for `<…/>`).
    text: &'a [u8],
    /// Byte offset of `text`.
    text_pos: usize,
}

impl<'a> Tag<'a> {
    fn attr(&self, key: &str) -> Option<&'a str> {
        self.attrs
            .iter()
            .find(|(k, _)| *k == key.as_bytes())
            .and_then(|(_, v)| std::str::from_utf8(v).ok())
    }
}

/// An XML event: a start tag, or the name and offset of an end tag.
enum Event<'a> {
    Start(Tag<'a>),
    End(&'a [u8], usize),
}

/// Tags of `xml` in order. Comments, declarations and processing instructions are skipped.
fn events<'a>(c: &Cursor<'a>, xml: &'a [u8]) -> Result<Vec<Event<'a>>> {
    let mut out = Vec::new();
    let mut i = 0;
    while let Some(k) = find(&xml[i..], b"<") {
        let lt = i + k;
        let rest = &xml[lt..];
        let closer: &[u8] = if rest.starts_with(b"<!--") {
            b"-->"
        } else if rest.starts_with(b"<![CDATA[") {
            b"]]>"
        } else {
            b">"
        };
        let gt = find(rest, closer)
            .map(|g| lt + g)
            .ok_or_else(|| c.err(lt, "unterminated XML tag"))?;
        i = gt + closer.len();
        if rest.starts_with(b"<!") || rest.starts_with(b"<?") {
            continue;
        }
        let inner = &xml[lt + 1..gt];
        if let Some(name) = inner.strip_prefix(b"/") {
            out.push(Event::End(name.trim_ascii(), lt));
            continue;
        }
        let (inner, closed) = match inner.strip_suffix(b"/") {
            Some(s) => (s, true),
            None => (inner, false),
        };
        let name_end = inner
            .iter()
            .position(|b| b.is_ascii_whitespace())
            .unwrap_or(inner.len());
        let name = &inner[..name_end];
        let attrs = attributes_of(&inner[name_end..])
            .ok_or_else(|| c.err(lt, format!("malformed attributes in tag {}", show(name))))?;
        let text_end = if closed {
            i
        } else {
            find(&xml[i..], b"<").map_or(xml.len(), |k| i + k)
        };
        out.push(Event::Start(Tag {
            name,
            attrs,
            pos: lt,
            text: &xml[i..text_end],
            text_pos: i,
        }));
        if closed {
            out.push(Event::End(name, lt));
        }
    }
    Ok(out)
}

/// `key="value"` pairs (either quote).
fn attributes_of(mut s: &[u8]) -> Option<Vec<(&[u8], &[u8])>> {
    let mut out = Vec::new();
    loop {
        s = s.trim_ascii_start();
        if s.is_empty() {
            return Some(out);
        }
        let eq = s.iter().position(|&b| b == b'=')?;
        let key = s[..eq].trim_ascii();
        let rest = s[eq + 1..].trim_ascii_start();
        let quote = *rest.first().filter(|q| **q == b'"' || **q == b'\'')?;
        let end = rest[1..].iter().position(|&b| b == quote)?;
        out.push((key, &rest[1..1 + end]));
        s = &rest[end + 2..];
    }
}

/// Decode base64 text, whitespace ignored; padded groups may be followed by more groups
/// (VTK encodes a block's header and its data separately). Err: offset of the bad byte.
fn base64_decode(text: &[u8]) -> Result<Vec<u8>, usize> {
    let mut out = Vec::with_capacity(text.len() / 4 * 3);
    let mut quad = [0u32; 4];
    let mut n = 0;
    for (i, &ch) in text.iter().enumerate() {
        let v = match ch {
            b'A'..=b'Z' => ch - b'A',
            b'a'..=b'z' => ch - b'a' + 26,
            b'0'..=b'9' => ch - b'0' + 52,
            b'+' => 62,
            b'/' => 63,
            b'=' => 64,
            _ if ch.is_ascii_whitespace() => continue,
            _ => return Err(i),
        };
        quad[n] = v as u32;
        n += 1;
        if n == 4 {
            let pad = match quad {
                [a, b, 64, 64] if a < 64 && b < 64 => 2,
                [a, b, c, 64] if a < 64 && b < 64 && c < 64 => 1,
                [a, b, c, d] if a < 64 && b < 64 && c < 64 && d < 64 => 0,
                _ => return Err(i),
            };
            let bits = quad.iter().fold(0u32, |acc, &q| (acc << 6) | (q & 63));
            out.extend_from_slice(&bits.to_be_bytes()[1..4 - pad]);
            n = 0;
        }
    }
    if n != 0 {
        return Err(text.len());
    }
    Ok(out)
}

/// Number of base64 characters encoding `n` bytes.
fn b64_len(n: u64) -> u64 {
    n.div_ceil(3).saturating_mul(4)
}

/// File-level settings of the `<VTKFile>` element.
struct Layout {
    big_endian: bool,
    /// 4 (UInt32) or 8 (UInt64).
    header: usize,
    compressed: bool,
}

impl Layout {
    fn header_values(&self, b: &[u8]) -> Vec<u64> {
        b.chunks_exact(self.header)
            .map(|h| uint(h, self.big_endian))
            .collect()
    }

    /// Header size in bytes of a block whose header starts with `first` (the block count
    /// when compressed).
    fn header_len(&self, first: u64) -> Option<u64> {
        if self.compressed {
            first.checked_add(3)?.checked_mul(self.header as u64)
        } else {
            Some(self.header as u64)
        }
    }

    /// The data of a binary block (header + data, possibly compressed) from its bytes.
    fn unpack(&self, b: &[u8]) -> Result<Vec<u8>, String> {
        let first = b
            .get(..self.header)
            .map(|h| uint(h, self.big_endian))
            .ok_or("the data block has no header")?;
        let hlen = self
            .header_len(first)
            .filter(|&l| l <= b.len() as u64)
            .ok_or_else(|| {
                format!("the data block header declares {first} blocks, more than the file holds")
            })? as usize;
        let h = self.header_values(&b[..hlen]);
        let body = &b[hlen..];
        if !self.compressed {
            let n = usize::try_from(first)
                .ok()
                .filter(|&n| n <= body.len())
                .ok_or_else(|| {
                    format!(
                        "the data block declares {first} bytes, only {} follow",
                        body.len()
                    )
                })?;
            return Ok(body[..n].to_vec());
        }
        let (n_blocks, block, last) = (h[0], h[1], h[2]);
        let mut out = Vec::new();
        let mut at = 0usize;
        for (k, &csize) in h[3..].iter().enumerate() {
            let expected = if k as u64 + 1 == n_blocks && last != 0 {
                last
            } else {
                block
            };
            let chunk = usize::try_from(csize)
                .ok()
                .and_then(|c| body.get(at..at.checked_add(c)?))
                .ok_or_else(|| {
                    format!("compressed block {k} of {csize} bytes runs past the end of the data")
                })?;
            // zlib expands at most ~1032:1; a larger claim is corrupt (and must not allocate).
            if expected > csize.saturating_mul(1032).saturating_add(64) {
                return Err(format!(
                    "compressed block {k} claims {expected} bytes from {csize} compressed bytes"
                ));
            }
            let data =
                miniz_oxide::inflate::decompress_to_vec_zlib_with_limit(chunk, expected as usize)
                    .map_err(|e| {
                    format!(
                        "compressed block {k} is not valid zlib data ({:?})",
                        e.status
                    )
                })?;
            if data.len() as u64 != expected {
                return Err(format!(
                    "compressed block {k} inflates to {} bytes, the header says {expected}",
                    data.len()
                ));
            }
            out.extend_from_slice(&data);
            at += chunk.len();
        }
        Ok(out)
    }
}

/// Binary type of a VTK XML type name.
fn num_type(name: &str) -> Option<Num> {
    Some(match name {
        "Int8" | "Char" => Num::Int(1),
        "UInt8" => Num::UInt(1),
        "Int16" => Num::Int(2),
        "UInt16" => Num::UInt(2),
        "Int32" => Num::Int(4),
        "UInt32" => Num::UInt(4),
        "Int64" => Num::Int(8),
        "UInt64" => Num::UInt(8),
        "Float32" => Num::Float(4),
        "Float64" => Num::Float(8),
        _ => return None,
    })
}

/// Where appended data starts, and its encoding.
struct Appended<'a> {
    data: &'a [u8],
    pos: usize,
    base64: bool,
}

struct Reader<'a> {
    c: Cursor<'a>,
    layout: Layout,
    appended: Option<Appended<'a>>,
}

impl Reader<'_> {
    /// The values of a `<DataArray>`.
    fn array(&self, tag: &Tag) -> Result<Vec<f64>> {
        let err = |m: String| self.c.err(tag.pos, m);
        let ty_name = tag.attr("type").unwrap_or("");
        let ty = num_type(ty_name).ok_or_else(|| {
            err(format!(
                "DataArray type {} is not supported",
                show(ty_name.as_bytes())
            ))
        })?;
        let bytes = match tag.attr("format").unwrap_or("ascii") {
            "ascii" => {
                let end = tag.text_pos + tag.text.len();
                let mut c = Cursor::new(self.c.path, &self.c.data[..end]);
                c.pos = tag.text_pos;
                let mut v = Vec::new();
                while let Some((p, t)) = c.token() {
                    let x = std::str::from_utf8(t)
                        .ok()
                        .and_then(|s| s.parse::<f64>().ok());
                    v.push(x.ok_or_else(|| c.err(p, format!("{} is not a number", show(t))))?);
                }
                return Ok(v);
            }
            "binary" => {
                let raw = base64_decode(tag.text)
                    .map_err(|k| self.c.err(tag.text_pos + k, "invalid base64 data"))?;
                self.layout.unpack(&raw).map_err(err)?
            }
            "appended" => self.appended_block(tag)?,
            f => {
                return Err(err(format!(
                    "DataArray format {} is not supported",
                    show(f.as_bytes())
                )))
            }
        };
        let size = ty.size();
        if bytes.len() % size != 0 {
            return Err(err(format!(
                "{} bytes is not a whole number of {ty_name} values",
                bytes.len()
            )));
        }
        Ok(bytes
            .chunks_exact(size)
            .map(|ch| ty.decode(ch, self.layout.big_endian))
            .collect())
    }

    /// The data of an appended block at the array's `offset`.
    fn appended_block(&self, tag: &Tag) -> Result<Vec<u8>> {
        let err = |m: String| self.c.err(tag.pos, m);
        let a = self
            .appended
            .as_ref()
            .ok_or_else(|| err("format=\"appended\" but the file has no <AppendedData>".into()))?;
        let offset: usize = tag
            .attr("offset")
            .and_then(|o| o.trim().parse().ok())
            .ok_or_else(|| err("appended DataArray without a valid offset".into()))?;
        let start = a
            .pos
            .checked_add(offset)
            .filter(|&s| s <= a.data.len())
            .ok_or_else(|| {
                err(format!(
                    "offset {offset} is past the end of the appended data"
                ))
            })?;
        let data = &a.data[start..];
        if !a.base64 {
            return self.layout.unpack(data).map_err(err);
        }
        // Base64: the header and the data are encoded separately; read the header first.
        let bad = |k: usize| self.c.err(start + k, "invalid base64 data");
        let h = self.layout.header as u64;
        let take = |n: u64| {
            data.get(..usize::try_from(b64_len(n)).unwrap_or(usize::MAX))
                .unwrap_or(data)
        };
        let first = base64_decode(take(h)).map_err(bad)?;
        let first = first
            .get(..self.layout.header)
            .map(|b| uint(b, self.layout.big_endian))
            .unwrap_or(0);
        let hlen = self.layout.header_len(first).unwrap_or(u64::MAX);
        let hchars = b64_len(hlen) as usize;
        let header = base64_decode(take(hlen)).map_err(bad)?;
        let body_len = if self.layout.compressed {
            self.layout
                .header_values(&header)
                .iter()
                .skip(3)
                .fold(0u64, |s, &c| s.saturating_add(c))
        } else {
            first
        };
        let body = data.get(hchars.min(data.len())..).unwrap_or(&[]);
        let body_chars = usize::try_from(b64_len(body_len))
            .unwrap_or(usize::MAX)
            .min(body.len());
        let mut block = header;
        block.extend(base64_decode(&body[..body_chars]).map_err(|k| bad(hchars + k))?);
        self.layout.unpack(&block).map_err(err)
    }
}

/// Read a `.vtu` file.
pub(super) fn read(path: &Path) -> Result<TetMesh> {
    let data = read_bytes(path)?;
    let c = Cursor::new(path, &data);
    // Raw appended data may hold any byte: the XML ends where <AppendedData> starts.
    let (xml, appended) = match find(&data, b"<AppendedData") {
        Some(k) => {
            let gt = find(&data[k..], b">")
                .map(|g| k + g)
                .ok_or_else(|| c.err(k, "unterminated <AppendedData> tag"))?;
            let head = &data[k..gt];
            let base64 = !(find(head, b"\"raw\"").is_some() || find(head, b"'raw'").is_some());
            let underscore = find(&data[gt..], b"_")
                .map(|u| gt + u + 1)
                .ok_or_else(|| c.err(gt, "<AppendedData> without the '_' marker"))?;
            (
                &data[..k],
                Some(Appended {
                    data: &data,
                    pos: underscore,
                    base64,
                }),
            )
        }
        None => (&data[..], None),
    };
    let events = events(&c, xml)?;
    let mut r = Reader {
        c,
        layout: Layout {
            big_endian: false,
            header: 4,
            compressed: false,
        },
        appended,
    };
    let mut mesh = TetMesh::default();
    let mut stack: Vec<&[u8]> = Vec::new();
    let mut piece: Option<Piece> = None;
    let mut seen_file = false;
    let mut first_piece = None;
    for e in &events {
        match e {
            Event::End(name, pos) => {
                if stack.pop() != Some(*name) {
                    return Err(r.c.err(*pos, format!("mismatched end tag {}", show(name))));
                }
                if *name == b"Piece" {
                    if let Some(p) = piece.take() {
                        p.finish(&r, &mut mesh)?;
                    }
                }
            }
            Event::Start(tag) => {
                let parent = stack.last().copied();
                stack.push(tag.name);
                match tag.name {
                    b"VTKFile" => {
                        seen_file = true;
                        r.layout = file_layout(&r.c, tag)?;
                    }
                    b"Piece" if parent == Some(&b"UnstructuredGrid"[..]) => {
                        let count = |key: &str| -> Result<Option<usize>> {
                            match tag.attr(key) {
                                None => Ok(None),
                                Some(v) => v.trim().parse().map(Some).map_err(|_| {
                                    r.c.err(
                                        tag.pos,
                                        format!(
                                            "<Piece> {key}={} is not a count",
                                            show(v.as_bytes())
                                        ),
                                    )
                                }),
                            }
                        };
                        let mut p = Piece::new(tag.pos);
                        p.declared_points = count("NumberOfPoints")?;
                        p.declared_cells = count("NumberOfCells")?;
                        piece = Some(p);
                        first_piece.get_or_insert(tag.pos);
                    }
                    b"DataArray" => {
                        let Some(p) = piece.as_mut() else { continue };
                        let name = tag.attr("Name").unwrap_or("").to_ascii_lowercase();
                        let comps: usize = tag
                            .attr("NumberOfComponents")
                            .and_then(|n| n.trim().parse().ok())
                            .unwrap_or(1);
                        match parent {
                            Some(b"Points") => {
                                // Absent (VTK's default would be 1, but point writers
                                // leave it out): read as xyz. Given, it must be 3.
                                let given = tag.attr("NumberOfComponents").map(str::trim);
                                if given.is_some_and(|n| n != "3") {
                                    return Err(r.c.err(
                                        tag.pos,
                                        format!(
                                            "the Points array has NumberOfComponents = {}: points need 3 (x, y, z)",
                                            show(given.unwrap_or("").as_bytes())
                                        ),
                                    ));
                                }
                                p.points = Some((tag.pos, r.array(tag)?));
                            }
                            Some(b"Cells") => match name.as_str() {
                                "connectivity" => p.connectivity = Some((tag.pos, r.array(tag)?)),
                                "offsets" => p.offsets = Some((tag.pos, r.array(tag)?)),
                                "types" => p.types = Some((tag.pos, r.array(tag)?)),
                                _ => {}
                            },
                            Some(section @ (b"PointData" | b"CellData")) => {
                                let point = section == b"PointData";
                                if wanted(point, &name, comps) {
                                    let a = Array {
                                        name,
                                        components: comps,
                                        values: r.array(tag)?,
                                        pos: tag.pos,
                                    };
                                    if point {
                                        p.point_data.push(a)
                                    } else {
                                        p.cell_data.push(a)
                                    }
                                }
                            }
                            _ => {}
                        }
                    }
                    _ => {}
                }
            }
        }
    }
    if !seen_file {
        return Err(file_err(
            path,
            "not a VTK XML file: no <VTKFile> element".into(),
        ));
    }
    if let Some(p) = piece.take() {
        p.finish(&r, &mut mesh)?;
    }
    let Some(first) = first_piece else {
        return Err(file_err(path, "no <Piece> in <UnstructuredGrid>".into()));
    };
    if mesh.tets.is_empty() {
        return Err(r
            .c
            .err(first, "no cell is a tetrahedron (VTK type 10 or 24)"));
    }
    Ok(mesh)
}

fn file_layout(c: &Cursor, tag: &Tag) -> Result<Layout> {
    let err = |m: String| c.err(tag.pos, m);
    match tag.attr("type") {
        Some("UnstructuredGrid") => {}
        t => {
            return Err(err(format!(
                "VTKFile type {} is not supported: only UnstructuredGrid",
                show(t.unwrap_or("").as_bytes())
            )))
        }
    }
    let big_endian = match tag.attr("byte_order").unwrap_or("LittleEndian") {
        "LittleEndian" => false,
        "BigEndian" => true,
        b => {
            return Err(err(format!(
                "byte_order {} is not valid",
                show(b.as_bytes())
            )))
        }
    };
    let header = match tag.attr("header_type").unwrap_or("UInt32") {
        "UInt32" => 4,
        "UInt64" => 8,
        h => {
            return Err(err(format!(
                "header_type {} is not supported",
                show(h.as_bytes())
            )))
        }
    };
    let compressed = match tag.attr("compressor") {
        None | Some("") => false,
        Some("vtkZLibDataCompressor") => true,
        Some(z) => {
            return Err(err(format!(
                "compressor {} is not supported (only vtkZLibDataCompressor)",
                show(z.as_bytes())
            )))
        }
    };
    Ok(Layout {
        big_endian,
        header,
        compressed,
    })
}

/// The arrays of one `<Piece>`.
struct Piece {
    pos: usize,
    points: Option<(usize, Vec<f64>)>,
    connectivity: Option<(usize, Vec<f64>)>,
    offsets: Option<(usize, Vec<f64>)>,
    types: Option<(usize, Vec<f64>)>,
    point_data: Vec<Array>,
    cell_data: Vec<Array>,
    /// The tag's NumberOfPoints, where given.
    declared_points: Option<usize>,
    /// The tag's NumberOfCells, where given.
    declared_cells: Option<usize>,
}

impl Piece {
    fn new(pos: usize) -> Self {
        Piece {
            declared_points: None,
            declared_cells: None,
            pos,
            points: None,
            connectivity: None,
            offsets: None,
            types: None,
            point_data: Vec::new(),
            cell_data: Vec::new(),
        }
    }

    /// Append this piece to `mesh`.
    fn finish(self, r: &Reader, mesh: &mut TetMesh) -> Result<()> {
        let c = &r.c;
        let missing = |what: &str| c.err(self.pos, format!("<Piece> has no {what} array"));
        let (ppos, coords) = self.points.ok_or_else(|| missing("Points"))?;
        let (cpos, connectivity) = self.connectivity.ok_or_else(|| missing("connectivity"))?;
        let (opos, ends) = self.offsets.ok_or_else(|| missing("offsets"))?;
        let (tpos, types) = self.types.ok_or_else(|| missing("types"))?;
        // VTU offsets are cell ends; the legacy 5.1 form starts with 0.
        let starts: Vec<f64> = std::iter::once(0.0).chain(ends).collect();
        let mut cells = offsets_cells(&starts, connectivity).map_err(|m| c.err(opos, m))?;
        cells.types = types;
        let places = Places {
            points: ppos,
            cells: cpos,
            types: tpos,
        };
        let part = grid_mesh(&coords, &cells, &places, &self.cell_data, &self.point_data)
            .map_err(|(p, m)| c.err(p, m))?;
        // The tag's counts, once the arrays themselves are sound.
        let disagree = |key: &str, n: usize, what: &str, held: usize| {
            c.err(
                self.pos,
                format!("<Piece> {key}=\"{n}\" but its {what} array holds {held}"),
            )
        };
        if let Some(n) = self
            .declared_points
            .filter(|&n| n.checked_mul(3) != Some(coords.len()))
        {
            return Err(disagree("NumberOfPoints", n, "Points", coords.len() / 3));
        }
        if let Some(n) = self.declared_cells.filter(|&n| n != cells.types.len()) {
            return Err(disagree("NumberOfCells", n, "types", cells.types.len()));
        }
        merge(mesh, part).map_err(|m| c.err(self.pos, m))
    }
}

/// Append `part` to `mesh`, shifting its indices; tags and fibres must be given by every
/// piece or by none.
fn merge(mesh: &mut TetMesh, part: TetMesh) -> Result<(), String> {
    let first = mesh.positions.is_empty() && mesh.tets.is_empty();
    if !first
        && (mesh.vertex_tags.is_empty() != part.vertex_tags.is_empty()
            || mesh.fibres.is_empty() != part.fibres.is_empty())
    {
        return Err("pieces disagree on which of vertex_tags and fibres they carry".into());
    }
    let shift = u32::try_from(mesh.positions.len()).map_err(|_| "too many points")?;
    mesh.tets
        .extend(part.tets.iter().map(|t| t.map(|v| v + shift)));
    mesh.positions.extend(part.positions);
    mesh.regions.extend(part.regions);
    mesh.vertex_tags.extend(part.vertex_tags);
    mesh.fibres.extend(part.fibres);
    Ok(())
}

/// One `<DataArray>` in binary base64 with a UInt64 byte-count header.
fn data_array(out: &mut String, ty: &str, name: &str, comps: usize, bytes: &[u8]) {
    let mut block = (bytes.len() as u64).to_le_bytes().to_vec();
    block.extend_from_slice(bytes);
    out.push_str(&format!(
        "        <DataArray type=\"{ty}\" Name=\"{name}\" NumberOfComponents=\"{comps}\" format=\"binary\">{}</DataArray>\n",
        base64(&block)
    ));
}

fn le_bytes<T: Copy, const N: usize>(v: &[T], f: impl Fn(T) -> [u8; N]) -> Vec<u8> {
    v.iter().flat_map(|&x| f(x)).collect()
}

/// A `.vtu` document: Float64 points, Int64 connectivity and offsets, UInt8 types; point
/// data `vertex_tags` (Int32); cell data `material` (Int32, the region) and `fibres`
/// (Float32 × 3). Fails when a region or tag does not fit an Int32.
pub(super) fn write(mesh: &TetMesh) -> Result<Vec<u8>, String> {
    let to_i32 = |v: &[u32], what: &str| -> Result<Vec<u8>, String> {
        v.iter()
            .map(|&x| {
                i32::try_from(x)
                    .map(i32::to_le_bytes)
                    .map_err(|_| format!("{what} {x} does not fit an Int32"))
            })
            .collect::<Result<Vec<_>, _>>()
            .map(|b| b.concat())
    };
    let mut s = String::from("<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n  <UnstructuredGrid>\n");
    s.push_str(&format!(
        "    <Piece NumberOfPoints=\"{}\" NumberOfCells=\"{}\">\n      <PointData>\n",
        mesh.positions.len(),
        mesh.tets.len()
    ));
    if !mesh.vertex_tags.is_empty() {
        data_array(
            &mut s,
            "Int32",
            "vertex_tags",
            1,
            &to_i32(&mesh.vertex_tags, "vertex tag")?,
        );
    }
    s.push_str("      </PointData>\n      <CellData>\n");
    data_array(
        &mut s,
        "Int32",
        "material",
        1,
        &to_i32(&mesh.regions, "region")?,
    );
    if !mesh.fibres.is_empty() {
        let f: Vec<f32> = mesh
            .fibres
            .iter()
            .flat_map(|f| f.to_array())
            .map(|x| x as f32)
            .collect();
        data_array(
            &mut s,
            "Float32",
            "fibres",
            3,
            &le_bytes(&f, f32::to_le_bytes),
        );
    }
    s.push_str("      </CellData>\n      <Points>\n");
    let p: Vec<f64> = mesh.positions.iter().flat_map(|p| p.to_array()).collect();
    data_array(
        &mut s,
        "Float64",
        "Points",
        3,
        &le_bytes(&p, f64::to_le_bytes),
    );
    s.push_str("      </Points>\n      <Cells>\n");
    let conn: Vec<i64> = mesh.tets.iter().flatten().map(|&i| i as i64).collect();
    let ends: Vec<i64> = (1..=mesh.tets.len() as i64).map(|k| 4 * k).collect();
    data_array(
        &mut s,
        "Int64",
        "connectivity",
        1,
        &le_bytes(&conn, i64::to_le_bytes),
    );
    data_array(
        &mut s,
        "Int64",
        "offsets",
        1,
        &le_bytes(&ends, i64::to_le_bytes),
    );
    data_array(&mut s, "UInt8", "types", 1, &vec![10u8; mesh.tets.len()]);
    s.push_str("      </Cells>\n    </Piece>\n  </UnstructuredGrid>\n</VTKFile>\n");
    Ok(s.into_bytes())
}
