//! Gmsh `.msh`: reads format 4.1 and 2.x (2.0–2.2), ASCII and binary; writes 4.1 ASCII.
//!
//! - Tets (type 4) and the corners of higher-order tets (types 11, 29, 30, 31) are kept;
//!   points, lines, triangles and quads are read for tags only; hexahedra, prisms and
//!   pyramids are refused.
//! - Region of a tet: the first physical tag of its volume entity (4.1, `$Entities`) or its
//!   first element tag (2.x); without a physical tag, the elementary entity tag.
//! - Vertex tags: nodes of lower-dimensional elements in a physical group named
//!   `endocardium`, `epicardium` or `base` (any case) get that bit; a `$NodeData` view named
//!   `vertex_tags` adds its values.
//! - Fibres: an `$ElementData` view named `fibres` or `fibers` with 3 components.
//! - Node and element tags may be sparse and in any order.

use super::cursor::{show, sint, uint, Cursor};
use super::{cap, drop_unused_vertices, file_err, read_bytes, to_u32};
use crate::error::{PalpateError, Result};
use crate::mesh::{tags, TetMesh};
use glam::DVec3;
use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::Path;

/// Read a `.msh` file.
pub(super) fn read(path: &Path) -> Result<TetMesh> {
    let data = read_bytes(path)?;
    let mut r = Reader {
        c: Cursor::new(path, &data),
        version: None,
        swap: false,
        size_t: 8,
        names: HashMap::new(),
        entity_phys: HashMap::new(),
        node_tags: Vec::new(),
        node_map: None,
        positions: Vec::new(),
        tets: Vec::new(),
        regions: Vec::new(),
        tet_elem_tags: Vec::new(),
        vertex_tags: Vec::new(),
        fibres: Vec::new(),
        quadratic: false,
        buf: Vec::new(),
    };
    r.sections()?;
    if r.node_map.is_none() {
        return Err(file_err(path, "no $Nodes section".into()));
    }
    if r.tets.is_empty() {
        return Err(file_err(path, "no $Elements section".into()));
    }
    let mut mesh = TetMesh {
        positions: r.positions,
        tets: r.tets,
        regions: r.regions,
        vertex_tags: r.vertex_tags,
        fibres: r.fibres,
    };
    if r.quadratic {
        drop_unused_vertices(&mut mesh);
    }
    Ok(mesh)
}

#[derive(Clone, Copy, PartialEq)]
enum Version {
    V2,
    V41,
}

/// What an element type is to us.
enum Kind {
    /// A tetrahedron, linear or not (its first four nodes are the corners).
    Tet { higher_order: bool },
    /// A volume element we cannot use.
    OtherVolume(&'static str),
    /// A point, line or surface element of this dimension.
    Lower(i64),
}

/// Number of nodes and kind of a Gmsh element type.
fn element_type(ty: i64) -> Option<(usize, Kind)> {
    use Kind::*;
    let hex = OtherVolume("hexahedron");
    let prism = OtherVolume("prism");
    let pyramid = OtherVolume("pyramid");
    Some(match ty {
        15 => (1, Lower(0)),
        1 => (2, Lower(1)),
        8 => (3, Lower(1)),
        26 => (4, Lower(1)),
        27 => (5, Lower(1)),
        28 => (6, Lower(1)),
        2 => (3, Lower(2)),
        3 => (4, Lower(2)),
        9 => (6, Lower(2)),
        10 => (9, Lower(2)),
        16 => (8, Lower(2)),
        20 => (9, Lower(2)),
        21 => (10, Lower(2)),
        22 => (12, Lower(2)),
        23 | 24 => (15, Lower(2)),
        25 => (21, Lower(2)),
        4 => (
            4,
            Tet {
                higher_order: false,
            },
        ),
        11 => (10, Tet { higher_order: true }),
        29 => (20, Tet { higher_order: true }),
        30 => (35, Tet { higher_order: true }),
        31 => (56, Tet { higher_order: true }),
        5 => (8, hex),
        12 => (27, hex),
        17 => (20, hex),
        92 => (64, hex),
        93 => (125, hex),
        6 => (6, prism),
        13 => (18, prism),
        18 => (15, prism),
        7 => (5, pyramid),
        14 => (14, pyramid),
        19 => (13, pyramid),
        _ => return None,
    })
}

/// Node tag → vertex index: a table when tags are dense, a hash map otherwise.
enum NodeMap {
    Dense { min: u64, index: Vec<u32> },
    Sparse(HashMap<u64, u32>),
}

impl NodeMap {
    /// Build from the node tags in file order; Err(tag) names a repeated tag.
    fn new(tags: &[u64]) -> Result<Self, u64> {
        let (min, max) = tags
            .iter()
            .fold((u64::MAX, 0), |(lo, hi), &t| (lo.min(t), hi.max(t)));
        let span = max.saturating_sub(min);
        if tags.is_empty() || span > 2 * tags.len() as u64 + 64 {
            let mut map = HashMap::with_capacity(tags.len());
            for (i, &t) in tags.iter().enumerate() {
                if map.insert(t, i as u32).is_some() {
                    return Err(t);
                }
            }
            return Ok(NodeMap::Sparse(map));
        }
        let mut index = vec![u32::MAX; span as usize + 1];
        for (i, &t) in tags.iter().enumerate() {
            let slot = &mut index[(t - min) as usize];
            if *slot != u32::MAX {
                return Err(t);
            }
            *slot = i as u32;
        }
        Ok(NodeMap::Dense { min, index })
    }

    fn get(&self, tag: u64) -> Option<u32> {
        match self {
            NodeMap::Dense { min, index } => tag
                .checked_sub(*min)
                .and_then(|k| index.get(k as usize))
                .copied()
                .filter(|&i| i != u32::MAX),
            NodeMap::Sparse(map) => map.get(&tag).copied(),
        }
    }
}

struct Reader<'a> {
    c: Cursor<'a>,
    version: Option<Version>,
    /// Binary data is big-endian.
    swap: bool,
    /// Bytes of a `size_t` in 4.1 binary files.
    size_t: usize,
    /// Physical names by (dimension, physical tag).
    names: HashMap<(i64, i64), String>,
    /// Physical tags of each (dimension, entity tag).
    entity_phys: HashMap<(i64, i64), Vec<i64>>,
    node_tags: Vec<u64>,
    node_map: Option<NodeMap>,
    positions: Vec<DVec3>,
    tets: Vec<[u32; 4]>,
    regions: Vec<u32>,
    tet_elem_tags: Vec<u64>,
    vertex_tags: Vec<u32>,
    fibres: Vec<DVec3>,
    quadratic: bool,
    /// Node tags of the element being read.
    buf: Vec<u64>,
}

impl Reader<'_> {
    fn err(&self, pos: usize, msg: impl std::fmt::Display) -> PalpateError {
        self.c.err(pos, msg)
    }

    fn sections(&mut self) -> Result<()> {
        while let Some((start, line)) = self.c.nonblank_line() {
            self.c.context = "";
            let Some(name) = line.strip_prefix(b"$") else {
                return Err(self.err(
                    start,
                    format!(
                        "expected a section header such as $Nodes, found {}",
                        show(line)
                    ),
                ));
            };
            if self.version.is_none() && name != b"MeshFormat" {
                return Err(self.err(
                    start,
                    format!(
                        "not a Gmsh file: expected $MeshFormat, found {}",
                        show(line)
                    ),
                ));
            }
            let v41 = self.version == Some(Version::V41);
            self.c.context = match name {
                b"MeshFormat" => "$MeshFormat",
                b"PhysicalNames" => "$PhysicalNames",
                b"Entities" => "$Entities",
                b"Nodes" => "$Nodes",
                b"Elements" => "$Elements",
                b"NodeData" => "$NodeData",
                b"ElementData" => "$ElementData",
                _ => "",
            };
            match name {
                b"MeshFormat" => self.mesh_format(start)?,
                b"PhysicalNames" => self.physical_names()?,
                b"Entities" if v41 => self.entities()?,
                b"PartitionedEntities" => {
                    return Err(self.err(
                        start,
                        "partitioned meshes are not supported (save the mesh unpartitioned)",
                    ))
                }
                b"Nodes" if self.node_map.is_some() => {
                    return Err(self.err(start, "a second $Nodes section"))
                }
                b"Nodes" if v41 => self.nodes_41()?,
                b"Nodes" => self.nodes_2()?,
                b"Elements" | b"NodeData" | b"ElementData" if self.node_map.is_none() => {
                    return Err(self.err(start, "this section comes before $Nodes"))
                }
                b"Elements" if !self.tets.is_empty() => {
                    return Err(self.err(start, "a second $Elements section"))
                }
                b"Elements" if v41 => self.elements_41()?,
                b"Elements" => self.elements_2()?,
                b"NodeData" => {
                    if !self.data_view(false)? {
                        continue;
                    }
                }
                b"ElementData" => {
                    if !self.data_view(true)? {
                        continue;
                    }
                }
                _ => {
                    // A section we do not use ($Periodic, $Comments, …): skip to its end.
                    let mut end = b"$End".to_vec();
                    end.extend_from_slice(name);
                    if !self.c.skip_past(&end) {
                        return Err(self.err(
                            start,
                            format!("section {} has no {}", show(line), show(&end)),
                        ));
                    }
                    continue;
                }
            }
            self.end_of_section(name)?;
        }
        Ok(())
    }

    fn end_of_section(&mut self, name: &[u8]) -> Result<()> {
        match self.c.token() {
            Some((_, t)) if t.strip_prefix(b"$End") == Some(name) => Ok(()),
            Some((pos, t)) => Err(self.err(
                pos,
                format!(
                    "expected $End{}, found {} (a count in the section does not match its data)",
                    String::from_utf8_lossy(name),
                    show(t)
                ),
            )),
            None => Err(self.err_here_end(name)),
        }
    }

    fn err_here_end(&self, name: &[u8]) -> PalpateError {
        self.c.err_here(format!(
            "file ends before $End{}",
            String::from_utf8_lossy(name)
        ))
    }

    fn mesh_format(&mut self, start: usize) -> Result<()> {
        if self.version.is_some() {
            return Err(self.err(start, "a second $MeshFormat section"));
        }
        let (vpos, v) = self.c.word("version")?;
        let version = match v {
            "4.1" => Version::V41,
            "2" | "2.0" | "2.1" | "2.2" => Version::V2,
            "4" | "4.0" => {
                return Err(self.err(
                    vpos,
                    "Gmsh format 4.0 is not supported (save as format 4.1 or 2.2)",
                ))
            }
            _ => {
                return Err(self.err(
                    vpos,
                    format!(
                        "Gmsh format version {} is not supported (4.1, 2.2)",
                        show(v.as_bytes())
                    ),
                ))
            }
        };
        let file_type: u32 = self.c.num("file type")?;
        let dpos = self.c.pos;
        let data_size: usize = self.c.num("data size")?;
        match (version, data_size) {
            (Version::V41, 4 | 8) | (Version::V2, 8) => self.size_t = data_size,
            _ => return Err(self.err(dpos, format!("data size {data_size} is not supported"))),
        }
        match file_type {
            0 => {}
            1 => {
                self.c.end_line()?;
                self.c.binary = true;
                let pos = self.c.pos;
                let one = self.c.take(4, "the endianness marker")?;
                if uint(one, false) == 1 {
                    self.swap = false;
                } else if uint(one, true) == 1 {
                    self.swap = true;
                } else {
                    return Err(self.err(
                        pos,
                        format!("endianness marker is {}, expected 1", uint(one, false)),
                    ));
                }
            }
            _ => return Err(self.err(dpos, format!("file type {file_type}, expected 0 or 1"))),
        }
        self.version = Some(version);
        Ok(())
    }

    /// A `size_t` (4.1 binary) or an unsigned integer token.
    fn size(&mut self, what: &str) -> Result<u64> {
        if !self.c.binary {
            return self.c.num(what);
        }
        let b = self.c.take(self.size_t, what)?;
        Ok(uint(b, self.swap))
    }

    /// An `int` (binary) or an integer token.
    fn int(&mut self, what: &str) -> Result<i64> {
        if !self.c.binary {
            return self.c.num(what);
        }
        let b = self.c.take(4, what)?;
        Ok(sint(b, self.swap))
    }

    /// A `double` (binary) or a number token, possibly not finite.
    fn double(&mut self, what: &str) -> Result<f64> {
        if !self.c.binary {
            return self.c.num(what);
        }
        let b = self.c.take(8, what)?;
        Ok(f64::from_bits(uint(b, self.swap)))
    }

    /// Where the next value starts, for its errors: past the spaces and line breaks before it
    /// in an ASCII file (else an error names the line before it), at the cursor in binary.
    fn next_value_at(&mut self) -> usize {
        if !self.c.binary {
            self.c.skip_ws();
        }
        self.c.pos
    }

    /// In an ASCII file, refuse a record's next value that is not on the record's line (a
    /// value missing there would otherwise be taken from the next line, and the error blame
    /// a later line and item).
    fn on_line(&self, what: &str) -> Result<()> {
        if self.c.binary || self.c.peek_on_line().is_some() {
            return Ok(());
        }
        Err(self.err(
            self.c.pos,
            format!("the line ends where {what} was expected"),
        ))
    }

    /// In an ASCII file, the end of a record's line: nothing but blanks may follow it.
    fn end_record(&mut self) -> Result<()> {
        if self.c.binary {
            return Ok(());
        }
        self.c.end_line()
    }

    /// A coordinate on the record's line: a finite double.
    fn coordinate_on_line(&mut self, axis: &str) -> Result<f64> {
        self.on_line(&format!("the {axis} coordinate"))?;
        self.coordinate()
    }

    /// A coordinate: a finite double.
    fn coordinate(&mut self) -> Result<f64> {
        let pos = self.next_value_at();
        let v = self.double("coordinate")?;
        if !v.is_finite() {
            return Err(self.err(pos, format!("coordinate is not finite ({v})")));
        }
        Ok(v)
    }

    /// A node tag read as an `int` (2.x) and checked to be positive.
    fn int_tag(&mut self, what: &str) -> Result<u64> {
        let pos = self.next_value_at();
        let t = self.int(what)?;
        u64::try_from(t).map_err(|_| self.err(pos, format!("{what} {t} is negative")))
    }

    /// Minimum bytes of one item of `ints` ints/tokens and `doubles` doubles, for capacity caps.
    fn item_bytes(&self, ints: usize, doubles: usize) -> usize {
        if self.c.binary {
            4 * ints + 8 * doubles
        } else {
            2 * (ints + doubles)
        }
    }

    fn physical_names(&mut self) -> Result<()> {
        let n: u64 = self.c.num("number of physical names")?;
        for _ in 0..n {
            let dim: i64 = self.c.num("physical dimension")?;
            let tag: i64 = self.c.num("physical tag")?;
            let (_, rest) = self.c.line().unwrap_or((0, b""));
            let name = String::from_utf8_lossy(rest.trim_ascii()).replace('"', "");
            self.names.insert((dim, tag), name);
        }
        Ok(())
    }

    fn entities(&mut self) -> Result<()> {
        let mut counts = [0u64; 4];
        for (dim, n) in counts.iter_mut().enumerate() {
            *n = self.size(
                [
                    "number of points",
                    "number of curves",
                    "number of surfaces",
                    "number of volumes",
                ][dim],
            )?;
        }
        for (dim, n) in counts.into_iter().enumerate() {
            for _ in 0..n {
                let tag = self.int("entity tag")?;
                for _ in 0..if dim == 0 { 3 } else { 6 } {
                    self.double("bounding box")?;
                }
                let n_phys = self.size("number of physical tags")?;
                let mut phys = Vec::with_capacity(cap(n_phys, self.c.remaining(), 2));
                for _ in 0..n_phys {
                    phys.push(self.int("physical tag")?);
                }
                if dim > 0 {
                    let n_bound = self.size("number of bounding entities")?;
                    for _ in 0..n_bound {
                        self.int("bounding entity tag")?;
                    }
                }
                self.entity_phys.insert((dim as i64, tag), phys);
            }
        }
        Ok(())
    }

    fn reserve_nodes(&mut self, n: u64) {
        let per_node = self.item_bytes(1, 3);
        let k = cap(n, self.c.remaining(), per_node);
        self.positions.reserve(k);
        self.node_tags.reserve(k);
    }

    fn nodes_41(&mut self) -> Result<()> {
        let n_blocks = self.size("number of node blocks")?;
        let hpos = self.c.pos;
        let n_nodes = self.size("number of nodes")?;
        self.size("minimum node tag")?;
        self.size("maximum node tag")?;
        self.reserve_nodes(n_nodes);
        for _ in 0..n_blocks {
            let dim = self.int("entity dimension")?;
            self.int("entity tag")?;
            let ppos = self.c.pos;
            let parametric = self.int("parametric flag")?;
            let n = self.size("number of nodes in block")?;
            let params = match (parametric, dim) {
                (0, _) => 0,
                (1, 0..=3) => dim as usize,
                _ => {
                    return Err(self.err(
                        ppos,
                        format!("parametric flag {parametric} for dimension {dim}"),
                    ))
                }
            };
            let first = self.node_tags.len();
            for _ in 0..n {
                let t = self.size("node tag")?;
                self.node_tags.push(t);
            }
            for _ in first..self.node_tags.len() {
                let p = DVec3::new(self.coordinate()?, self.coordinate()?, self.coordinate()?);
                self.positions.push(p);
                for _ in 0..params {
                    self.double("parametric coordinate")?;
                }
            }
        }
        if self.positions.len() as u64 != n_nodes {
            return Err(self.err(
                hpos,
                format!(
                    "header declares {n_nodes} nodes but the blocks hold {}",
                    self.positions.len()
                ),
            ));
        }
        self.build_node_map()
    }

    fn nodes_2(&mut self) -> Result<()> {
        let n: u64 = self.c.num("number of nodes")?;
        if self.c.binary {
            self.c.end_line()?;
        }
        self.reserve_nodes(n);
        for _ in 0..n {
            // One node a line in ASCII: tag x y z.
            let t = self.int_tag("node tag")?;
            let p = DVec3::new(
                self.coordinate_on_line("x")?,
                self.coordinate_on_line("y")?,
                self.coordinate_on_line("z")?,
            );
            self.end_record()?;
            self.node_tags.push(t);
            self.positions.push(p);
        }
        self.build_node_map()
    }

    fn build_node_map(&mut self) -> Result<()> {
        if self.positions.len() > u32::MAX as usize / 2 {
            return Err(self.c.err_here("too many nodes"));
        }
        let map = NodeMap::new(&self.node_tags)
            .map_err(|t| self.c.err_here(format!("node tag {t} appears twice")))?;
        self.node_map = Some(map);
        self.node_tags = Vec::new();
        Ok(())
    }

    fn node(&self, pos: usize, elem: u64, tag: u64) -> Result<u32> {
        self.node_map
            .as_ref()
            .and_then(|m| m.get(tag))
            .ok_or_else(|| {
                self.err(
                    pos,
                    format!("element {elem} refers to node tag {tag}, which is not in $Nodes"),
                )
            })
    }

    /// Tag bits of a lower-dimensional element in these physical groups.
    fn tag_bits(&self, dim: i64, physical: &[i64]) -> u32 {
        physical
            .iter()
            .filter_map(|p| self.names.get(&(dim, *p)))
            .filter_map(|n| tags::by_name(&n.trim().to_ascii_lowercase()))
            .fold(0, |a, b| a | b)
    }

    fn region_id(&self, pos: usize, v: i64) -> Result<u32> {
        u32::try_from(v).map_err(|_| {
            self.err(
                pos,
                format!("region (physical or entity tag) {v} is not in 0..=4294967295"),
            )
        })
    }

    /// Read the node tags of one element of `n` nodes into `buf`.
    fn element_nodes(&mut self, n: usize) -> Result<()> {
        self.buf.clear();
        for _ in 0..n {
            self.on_line("a node tag of the element")?;
            let t = if self.version == Some(Version::V41) {
                self.size("node tag")?
            } else {
                self.int_tag("node tag")?
            };
            self.buf.push(t);
        }
        // One element a line in ASCII.
        self.end_record()
    }

    /// Record the element whose node tags are in `buf`.
    fn element(
        &mut self,
        pos: usize,
        elem: u64,
        kind: &Kind,
        region: u32,
        bits: u32,
    ) -> Result<()> {
        match kind {
            Kind::Tet { higher_order } => {
                let mut tet = [0u32; 4];
                for (v, &tag) in tet.iter_mut().zip(&self.buf) {
                    *v = self.node(pos, elem, tag)?;
                }
                self.tets.push(tet);
                self.regions.push(region);
                self.tet_elem_tags.push(elem);
                self.quadratic |= *higher_order;
            }
            Kind::Lower(_) if bits != 0 => {
                if self.vertex_tags.is_empty() {
                    self.vertex_tags = vec![0; self.positions.len()];
                }
                for k in 0..self.buf.len() {
                    let v = self.node(pos, elem, self.buf[k])?;
                    self.vertex_tags[v as usize] |= bits;
                }
            }
            Kind::Lower(_) => {}
            Kind::OtherVolume(name) => {
                return Err(self.err(
                    pos,
                    format!("element {elem} is a {name}: only tetrahedra are supported"),
                ))
            }
        }
        Ok(())
    }

    fn element_kind(&self, pos: usize, ty: i64) -> Result<(usize, Kind)> {
        let (n, kind) =
            element_type(ty).ok_or_else(|| self.err(pos, format!("unknown element type {ty}")))?;
        if let Kind::OtherVolume(name) = kind {
            return Err(self.err(
                pos,
                format!("element type {ty} ({name}) is not supported: only tetrahedra"),
            ));
        }
        Ok((n, kind))
    }

    fn reserve_elements(&mut self, n: u64) {
        let k = cap(n, self.c.remaining(), self.item_bytes(5, 0));
        self.tets.reserve(k);
        self.regions.reserve(k);
        self.tet_elem_tags.reserve(k);
    }

    fn elements_41(&mut self) -> Result<()> {
        let n_blocks = self.size("number of element blocks")?;
        let hpos = self.c.pos;
        let n_elements = self.size("number of elements")?;
        self.size("minimum element tag")?;
        self.size("maximum element tag")?;
        self.reserve_elements(n_elements);
        let mut read = 0u64;
        for _ in 0..n_blocks {
            let bpos = self.c.pos;
            let dim = self.int("entity dimension")?;
            let entity = self.int("entity tag")?;
            let tpos = self.c.pos;
            let ty = self.int("element type")?;
            let n = self.size("number of elements in block")?;
            let (nn, kind) = self.element_kind(tpos, ty)?;
            let physical = self
                .entity_phys
                .get(&(dim, entity))
                .cloned()
                .unwrap_or_default();
            let (mut region, mut bits) = (0, 0);
            match kind {
                Kind::Tet { .. } => {
                    region = self.region_id(bpos, physical.first().copied().unwrap_or(entity))?
                }
                Kind::Lower(d) => bits = self.tag_bits(d, &physical),
                Kind::OtherVolume(_) => {}
            }
            for _ in 0..n {
                let pos = self.next_value_at();
                let elem = self.size("element tag")?;
                self.element_nodes(nn)?;
                self.element(pos, elem, &kind, region, bits)?;
                read += 1;
            }
        }
        if read != n_elements {
            return Err(self.err(
                hpos,
                format!("header declares {n_elements} elements but the blocks hold {read}"),
            ));
        }
        self.check_tets(hpos)
    }

    fn elements_2(&mut self) -> Result<()> {
        let hpos = self.c.pos;
        let m: u64 = self.c.num("number of elements")?;
        self.reserve_elements(m);
        let mut element_tags = Vec::new();
        if !self.c.binary {
            for _ in 0..m {
                let pos = self.next_value_at();
                let elem = self.int_tag("element number")?;
                self.on_line("the element type")?;
                let tpos = self.next_value_at();
                let ty = self.int("element type")?;
                let (nn, kind) = self.element_kind(tpos, ty)?;
                self.on_line("the number of tags")?;
                let n_tags = self.size("number of tags")?;
                element_tags.clear();
                for _ in 0..n_tags {
                    self.on_line("an element tag")?;
                    element_tags.push(self.int("element tag")?);
                }
                self.element_nodes(nn)?;
                self.element_2(pos, elem, &kind, &element_tags)?;
            }
            return self.check_tets(hpos);
        }
        self.c.end_line()?;
        let mut read = 0u64;
        while read < m {
            let tpos = self.c.pos;
            let ty = self.int("element type")?;
            let (nn, kind) = self.element_kind(tpos, ty)?;
            let npos = self.c.pos;
            let follow = self.int_tag("number of elements following")?;
            let n_tags = self.int_tag("number of tags")?;
            if follow > m - read {
                return Err(self.err(
                    npos,
                    format!(
                        "{follow} elements follow but only {} remain of the {m} declared",
                        m - read
                    ),
                ));
            }
            for _ in 0..follow {
                let pos = self.next_value_at();
                let elem = self.int_tag("element number")?;
                element_tags.clear();
                for _ in 0..n_tags {
                    element_tags.push(self.int("element tag")?);
                }
                self.element_nodes(nn)?;
                self.element_2(pos, elem, &kind, &element_tags)?;
            }
            read += follow;
        }
        self.check_tets(hpos)
    }

    fn check_tets(&self, pos: usize) -> Result<()> {
        if self.tets.is_empty() {
            return Err(self.err(
                pos,
                "no tetrahedron among the elements (types 4, 11, 29, 30, 31)",
            ));
        }
        Ok(())
    }

    /// One 2.x element: tags are [physical, elementary, …].
    fn element_2(
        &mut self,
        pos: usize,
        elem: u64,
        kind: &Kind,
        element_tags: &[i64],
    ) -> Result<()> {
        let (mut region, mut bits) = (0, 0);
        match kind {
            Kind::Tet { .. } => {
                let r = match element_tags {
                    [p, ..] if *p != 0 => *p,
                    [_, e, ..] => *e,
                    _ => 0,
                };
                region = self.region_id(pos, r)?;
            }
            Kind::Lower(d) => bits = self.tag_bits(*d, &element_tags[..element_tags.len().min(1)]),
            Kind::OtherVolume(_) => {}
        }
        self.element(pos, elem, kind, region, bits)
    }

    /// A `$NodeData` or `$ElementData` view. Returns false when it was skipped whole (past
    /// its end marker).
    fn data_view(&mut self, elements: bool) -> Result<bool> {
        let end: &[u8] = if elements {
            b"$EndElementData"
        } else {
            b"$EndNodeData"
        };
        let hpos = self.c.pos;
        let n_str: u64 = self.c.num("number of string tags")?;
        let mut name = String::new();
        for k in 0..n_str {
            let (_, line) = self
                .c
                .nonblank_line()
                .ok_or_else(|| self.c.err_here("file ends inside the string tags"))?;
            if k == 0 {
                name = String::from_utf8_lossy(line)
                    .replace('"', "")
                    .trim()
                    .to_ascii_lowercase();
            }
        }
        let n_real: u64 = self.c.num("number of real tags")?;
        for _ in 0..n_real {
            self.c.num::<f64>("real tag")?;
        }
        let n_int: u64 = self.c.num("number of integer tags")?;
        let mut ints = Vec::with_capacity(cap(n_int, self.c.remaining(), 2));
        for _ in 0..n_int {
            ints.push(self.c.num::<i64>("integer tag")?);
        }
        let (Some(&comps), Some(&n_items)) = (ints.get(1), ints.get(2)) else {
            return Err(self.err(
                hpos,
                "a data view needs at least 3 integer tags (step, components, count)",
            ));
        };
        let wanted = matches!(
            (elements, name.as_str(), comps),
            (false, "vertex_tags", 1) | (true, "fibres" | "fibers", 3)
        );
        if !wanted {
            return if self.c.skip_past(end) {
                Ok(false)
            } else {
                Err(self.c.err_here(format!("no {}", show(end))))
            };
        }
        if self.c.binary {
            self.c.end_line()?;
        }
        let tet_of_element: HashMap<u64, u32> = if elements {
            self.tet_elem_tags
                .iter()
                .enumerate()
                .map(|(i, &e)| (e, i as u32))
                .collect()
        } else {
            HashMap::new()
        };
        let mut seen = vec![false; if elements { self.tets.len() } else { 0 }];
        if elements {
            self.fibres = vec![DVec3::ZERO; self.tets.len()];
        }
        if !elements && self.vertex_tags.is_empty() {
            self.vertex_tags = vec![0; self.positions.len()];
        }
        for _ in 0..n_items {
            let pos = self.next_value_at();
            let tag = self.int_tag(if elements { "element tag" } else { "node tag" })?;
            if elements {
                let v = DVec3::new(
                    self.double("fibre")?,
                    self.double("fibre")?,
                    self.double("fibre")?,
                );
                if let Some(&t) = tet_of_element.get(&tag) {
                    self.fibres[t as usize] = v;
                    seen[t as usize] = true;
                }
            } else {
                let v = self.double("vertex tag")?;
                let i = self.node(pos, tag, tag)?;
                let bits = to_u32(v).ok_or_else(|| {
                    self.err(
                        pos,
                        format!("vertex tag {v} of node {tag} is not an integer in 0..=4294967295"),
                    )
                })?;
                self.vertex_tags[i as usize] |= bits;
            }
        }
        if elements {
            if let Some(t) = seen.iter().position(|s| !s) {
                return Err(self.err(
                    hpos,
                    format!(
                        "view '{name}' gives no fibre for element {}",
                        self.tet_elem_tags[t]
                    ),
                ));
            }
        }
        Ok(true)
    }
}

/// Gmsh 4.1 ASCII: one volume entity per region, whose physical tag is the region id (no
/// `$PhysicalNames`: Gmsh mislabels a named physical group 0); vertex tags as a `$NodeData`
/// view `vertex_tags`, fibres as an `$ElementData` view `fibres`. Coordinates are written in
/// shortest round-trip form, so a read gives back the same f64 values.
pub(super) fn write(mesh: &TetMesh) -> Result<Vec<u8>, String> {
    let mut s = String::with_capacity(64 * (mesh.positions.len() + mesh.tets.len()) + 256);
    write_41(&mut s, mesh).map_err(|e| e.to_string())?;
    Ok(s.into_bytes())
}

fn write_41(s: &mut String, mesh: &TetMesh) -> std::fmt::Result {
    let (nv, nt) = (mesh.positions.len(), mesh.tets.len());
    // Tets grouped by region; region k (in increasing order) is volume entity k + 1.
    let mut order: Vec<usize> = (0..nt).collect();
    order.sort_by_key(|&t| mesh.regions[t]);
    let groups: Vec<&[usize]> = order
        .chunk_by(|&a, &b| mesh.regions[a] == mesh.regions[b])
        .collect();
    writeln!(s, "$MeshFormat\n4.1 0 8\n$EndMeshFormat")?;
    writeln!(s, "$Entities\n0 0 0 {}", groups.len())?;
    for (k, group) in groups.iter().enumerate() {
        let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        for &v in group.iter().flat_map(|&t| &mesh.tets[t]) {
            lo = lo.min(mesh.positions[v as usize]);
            hi = hi.max(mesh.positions[v as usize]);
        }
        let r = mesh.regions[group[0]];
        writeln!(
            s,
            "{} {} {} {} {} {} {} 1 {r} 0",
            k + 1,
            lo.x,
            lo.y,
            lo.z,
            hi.x,
            hi.y,
            hi.z
        )?;
    }
    writeln!(s, "$EndEntities")?;
    // All nodes in one block, classified on the first volume.
    writeln!(s, "$Nodes\n1 {nv} 1 {nv}\n3 1 0 {nv}")?;
    for i in 1..=nv {
        writeln!(s, "{i}")?;
    }
    for p in &mesh.positions {
        writeln!(s, "{} {} {}", p.x, p.y, p.z)?;
    }
    writeln!(s, "$EndNodes")?;
    writeln!(s, "$Elements\n{} {nt} 1 {nt}", groups.len())?;
    for (k, group) in groups.iter().enumerate() {
        writeln!(s, "3 {} 4 {}", k + 1, group.len())?;
        for &t in group.iter() {
            let [a, b, c, d] = mesh.tets[t].map(|v| v + 1);
            writeln!(s, "{} {a} {b} {c} {d}", t + 1)?;
        }
    }
    writeln!(s, "$EndElements")?;
    if !mesh.vertex_tags.is_empty() {
        writeln!(s, "$NodeData\n1\n\"vertex_tags\"\n1\n0.0\n3\n0\n1\n{nv}")?;
        for (i, t) in mesh.vertex_tags.iter().enumerate() {
            writeln!(s, "{} {t}", i + 1)?;
        }
        writeln!(s, "$EndNodeData")?;
    }
    if !mesh.fibres.is_empty() {
        writeln!(s, "$ElementData\n1\n\"fibres\"\n1\n0.0\n3\n0\n3\n{nt}")?;
        for (t, f) in mesh.fibres.iter().enumerate() {
            writeln!(s, "{} {} {} {}", t + 1, f.x, f.y, f.z)?;
        }
        writeln!(s, "$EndElementData")?;
    }
    Ok(())
}
