//! Tetrahedral meshes: storage, validation, orientation, boundary surface, statistics.
//!
//! A [`TetMesh`] holds rest positions in metres (f64, so generators and readers keep full
//! precision), tets as four vertex indices, and a region id per tet. The simulation takes
//! its f32 buffers from here through [`crate::model::Model`].

pub mod generators;
pub mod io;
pub mod quality;

use crate::error::{PalpateError, Result};
use glam::DVec3;
use std::collections::HashMap;

/// A linear tetrahedral mesh at rest.
#[derive(Clone, Debug, Default)]
pub struct TetMesh {
    /// Rest positions of the vertices, m.
    pub positions: Vec<DVec3>,
    /// Vertex indices of each tet; positive orientation: det[x1−x0, x2−x0, x3−x0] > 0.
    pub tets: Vec<[u32; 4]>,
    /// Region (material / zone) id per tet.
    pub regions: Vec<u32>,
    /// Surface tags per vertex, a bit mask of [`tags`] (empty: no tags).
    pub vertex_tags: Vec<u32>,
    /// Unit fibre direction per tet (empty: none).
    pub fibres: Vec<DVec3>,
}

/// Vertex tag bits (see [`TetMesh::vertex_tags`]).
pub mod tags {
    /// Inner surface of a shell; the endocardium of a ventricle.
    pub const ENDOCARDIUM: u32 = 1;
    /// Outer surface of a shell; the epicardium of a ventricle.
    pub const EPICARDIUM: u32 = 2;
    /// The base plane of a truncated ventricle.
    pub const BASE: u32 = 4;
    /// Name → bit, for scene files.
    pub const NAMES: [(&str, u32); 3] = [
        ("endocardium", ENDOCARDIUM),
        ("epicardium", EPICARDIUM),
        ("base", BASE),
    ];
    /// Bit for a tag name, if known.
    pub fn by_name(name: &str) -> Option<u32> {
        NAMES.iter().find(|(n, _)| *n == name).map(|(_, b)| *b)
    }
}

/// What [`TetMesh::validate`] found and fixed.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ValidationReport {
    /// Tets whose orientation was negative and that were reoriented (two nodes swapped).
    pub reoriented: Vec<usize>,
    /// Up to three pairs of distinct vertices at the same position that tets use, and how
    /// many pairs in all ([`TetMesh::coincident_vertices`]).
    pub coincident: (Vec<(u32, u32)>, usize),
    /// Vertices referenced by no tet (they get no mass and are held fixed).
    pub unused_vertices: usize,
    /// Where the mesh came from, as its errors and warnings name it (a scene, or a scene
    /// and its mesh file).
    pub origin: String,
}

/// Size and quality figures of a mesh.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct MeshStats {
    /// Number of vertices.
    pub vertices: usize,
    /// Number of tets.
    pub tets: usize,
    /// Number of boundary triangles.
    pub boundary_faces: usize,
    /// Total volume, m³.
    pub volume: f64,
    /// Smallest tet volume, m³.
    pub min_volume: f64,
    /// Mean tet volume, m³.
    pub mean_volume: f64,
    /// Shortest edge, m (the paper's h in eq. 14).
    pub min_edge: f64,
    /// Smallest altitude (3V / largest face area) over all tets, m: the h of the time-step bound.
    pub min_altitude: f64,
    /// Smallest dihedral angle, degrees.
    pub min_dihedral_deg: f64,
    /// Largest dihedral angle, degrees.
    pub max_dihedral_deg: f64,
    /// Largest aspect ratio (longest edge / smallest altitude).
    pub max_aspect_ratio: f64,
}

/// Signed volume of the tet (a, b, c, d): det[b−a, c−a, d−a] / 6.
pub fn signed_volume(a: DVec3, b: DVec3, c: DVec3, d: DVec3) -> f64 {
    (b - a).dot((c - a).cross(d - a)) / 6.0
}

/// The four faces of a tet, each listed so that its normal (right-hand rule) points out
/// of a positively oriented tet. Face k is opposite corner k.
pub const TET_FACES: [[usize; 3]; 4] = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]];

/// The six edges of a tet as corner pairs.
pub const TET_EDGES: [[usize; 2]; 6] = [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]];

/// The largest coordinate magnitude a mesh may have, m: the engine computes in f32, whose
/// squares overflow past ~1.8e19 (3.4e38 = f32::MAX).
pub const MAX_COORDINATE: f64 = 1e18;

impl TetMesh {
    /// Build a mesh and validate it (see [`TetMesh::validate`]).
    pub fn new(
        origin: &str,
        positions: Vec<DVec3>,
        tets: Vec<[u32; 4]>,
        regions: Option<Vec<u32>>,
    ) -> Result<(Self, ValidationReport)> {
        let regions = regions.unwrap_or_else(|| vec![0; tets.len()]);
        let mut mesh = TetMesh {
            positions,
            tets,
            regions,
            ..Default::default()
        };
        let report = mesh.validate(origin)?;
        Ok((mesh, report))
    }

    /// Number of vertices.
    pub fn n_vertices(&self) -> usize {
        self.positions.len()
    }

    /// Number of tets.
    pub fn n_tets(&self) -> usize {
        self.tets.len()
    }

    /// Corner positions of tet `t`.
    pub fn corners(&self, t: usize) -> [DVec3; 4] {
        self.tets[t].map(|i| self.positions[i as usize])
    }

    /// Signed volume of tet `t`.
    pub fn tet_volume(&self, t: usize) -> f64 {
        let [a, b, c, d] = self.corners(t);
        signed_volume(a, b, c, d)
    }

    /// Check indices, refuse degenerate tets, reorient inverted ones.
    ///
    /// A tet is degenerate when |6V| ≤ 1e-9 · ℓ³ (ℓ its longest edge) or when it repeats a
    /// vertex; the error names the tet and its vertices. Non-finite coordinates, and any
    /// beyond ±[`MAX_COORDINATE`], are refused.
    pub fn validate(&mut self, origin: &str) -> Result<ValidationReport> {
        let err = |message: String| PalpateError::Mesh {
            origin: origin.to_string(),
            message,
        };
        if self.tets.is_empty() {
            return Err(err("mesh has no tetrahedra".into()));
        }
        if self.regions.len() != self.tets.len() {
            return Err(err(format!(
                "{} region ids for {} tets",
                self.regions.len(),
                self.tets.len()
            )));
        }
        if !self.vertex_tags.is_empty() && self.vertex_tags.len() != self.positions.len() {
            return Err(err(format!(
                "{} vertex tags for {} vertices",
                self.vertex_tags.len(),
                self.positions.len()
            )));
        }
        if !self.fibres.is_empty() && self.fibres.len() != self.tets.len() {
            return Err(err(format!(
                "{} fibre directions for {} tets",
                self.fibres.len(),
                self.tets.len()
            )));
        }
        if self.positions.len() > u32::MAX as usize / 2 {
            return Err(err(format!(
                "{} vertices is too many",
                self.positions.len()
            )));
        }
        for (i, p) in self.positions.iter().enumerate() {
            if !p.is_finite() {
                return Err(err(format!("vertex {i} has a non-finite coordinate {p:?}")));
            }
            if p.abs().max_element() > MAX_COORDINATE {
                return Err(err(format!(
                    "vertex {i} at [{}, {}, {}] m lies beyond ±{MAX_COORDINATE:e} m, which single precision cannot square (check the mesh's size or scale)",
                    crate::scene::Num(p.x),
                    crate::scene::Num(p.y),
                    crate::scene::Num(p.z)
                )));
            }
        }
        let n = self.positions.len() as u32;
        let mut report = ValidationReport::default();
        let mut used = vec![false; self.positions.len()];
        for t in 0..self.tets.len() {
            let tet = self.tets[t];
            for &v in &tet {
                if v >= n {
                    return Err(err(format!(
                        "tet {t} refers to vertex {v} but the mesh has {n} vertices"
                    )));
                }
                used[v as usize] = true;
            }
            for a in 0..4 {
                for b in a + 1..4 {
                    if tet[a] == tet[b] {
                        return Err(err(format!(
                            "tet {t} {tet:?} is degenerate: it repeats vertex {}",
                            tet[a]
                        )));
                    }
                }
            }
            let c = self.corners(t);
            let longest = TET_EDGES
                .iter()
                .map(|e| c[e[0]].distance(c[e[1]]))
                .fold(0.0, f64::max);
            let v6 = 6.0 * signed_volume(c[0], c[1], c[2], c[3]);
            if v6.abs() <= 1e-9 * longest.powi(3) {
                return Err(err(format!(
                    "tet {t} {tet:?} is degenerate: volume {:.3e} m³ for longest edge {longest:.3e} m",
                    v6 / 6.0
                )));
            }
            if v6 < 0.0 {
                self.tets[t].swap(2, 3);
                report.reoriented.push(t);
            }
        }
        self.check_connectivity().map_err(err)?;
        report.unused_vertices = used.iter().filter(|u| !**u).count();
        report.coincident = self.coincident_vertices(3);
        report.origin = origin.to_string();
        Ok(report)
    }

    /// No tet twice (the same four vertices) and no face in more than two tets: either makes
    /// a mesh whose boundary (the contact and load surface) silently loses faces. An error
    /// naming the tets.
    fn check_connectivity(&self) -> std::result::Result<(), String> {
        let sorted = |mut v: [u32; 4]| {
            v.sort_unstable();
            v
        };
        let mut tets: Vec<([u32; 4], u32)> = (0..self.tets.len())
            .map(|t| (sorted(self.tets[t]), t as u32))
            .collect();
        tets.sort_unstable();
        if let Some(w) = tets.windows(2).find(|w| w[0].0 == w[1].0) {
            return Err(format!(
                "tets {} and {} are the same tetrahedron (vertices {:?})",
                w[0].1, w[1].1, w[0].0
            ));
        }
        // Each face once per tet, as (sorted vertices, tet), sorted: a run of three or more
        // is a face in more than two tets.
        let mut faces: Vec<([u32; 3], u32)> = Vec::with_capacity(4 * tets.len());
        for (v, t) in tets {
            faces.extend([
                ([v[0], v[1], v[2]], t),
                ([v[0], v[1], v[3]], t),
                ([v[0], v[2], v[3]], t),
                ([v[1], v[2], v[3]], t),
            ]);
        }
        faces.sort_unstable();
        if let Some(w) = faces.windows(3).find(|w| w[0].0 == w[2].0) {
            let mut sharing: Vec<u32> = faces
                .iter()
                .filter(|f| f.0 == w[0].0)
                .map(|f| f.1)
                .collect();
            sharing.sort_unstable();
            return Err(format!(
                "face {:?} belongs to {} tets {sharing:?}; a face of a tetrahedral mesh belongs to at most two",
                w[0].0,
                sharing.len()
            ));
        }
        // The two tets of a shared face lie on its two sides; on one side they overlap (the
        // mesh then counts that volume, and its mass, twice).
        let side = |face: [u32; 3], t: u32| {
            let tet = self.tets[t as usize];
            let apex = tet
                .into_iter()
                .find(|v| !face.contains(v))
                .unwrap_or(face[0]);
            let [a, b, c] = face.map(|v| self.positions[v as usize]);
            signed_volume(a, b, c, self.positions[apex as usize]).signum()
        };
        if let Some(w) = faces
            .windows(2)
            .find(|w| w[0].0 == w[1].0 && side(w[0].0, w[0].1) == side(w[1].0, w[1].1))
        {
            return Err(format!(
                "tets {} and {} overlap: they share face {:?} and lie on the same side of it",
                w[0].1.min(w[1].1),
                w[0].1.max(w[1].1),
                w[0].0
            ));
        }
        Ok(())
    }

    /// Pairs of distinct vertices at the same position that tets use (the mesh is not joined
    /// there: the tets on either side share no vertex), in order; at most `limit`, and how
    /// many there are in all.
    pub fn coincident_vertices(&self, limit: usize) -> (Vec<(u32, u32)>, usize) {
        let mut used = vec![false; self.positions.len()];
        for tet in &self.tets {
            for &v in tet {
                used[v as usize] = true;
            }
        }
        let mut at: Vec<([u64; 3], u32)> = (0..self.positions.len() as u32)
            .filter(|&v| used[v as usize])
            .map(|v| {
                // +0.0 and -0.0 are one place.
                let p = self.positions[v as usize] + DVec3::ZERO;
                (p.to_array().map(f64::to_bits), v)
            })
            .collect();
        at.sort_unstable();
        let mut pairs = Vec::new();
        let mut count = 0;
        for w in at.windows(2) {
            if w[0].0 == w[1].0 {
                count += 1;
                if pairs.len() < limit {
                    pairs.push((w[0].1, w[1].1));
                }
            }
        }
        (pairs, count)
    }

    /// Boundary triangles: faces that belong to exactly one tet, oriented outward.
    pub fn boundary_faces(&self) -> Vec<[u32; 3]> {
        let mut count: HashMap<[u32; 3], (u32, [u32; 3])> = HashMap::new();
        for tet in &self.tets {
            for f in TET_FACES {
                let face = [tet[f[0]], tet[f[1]], tet[f[2]]];
                let mut key = face;
                key.sort_unstable();
                count.entry(key).or_insert((0, face)).0 += 1;
            }
        }
        let mut faces: Vec<[u32; 3]> = count
            .into_values()
            .filter(|(c, _)| *c == 1)
            .map(|(_, f)| f)
            .collect();
        faces.sort_unstable();
        faces
    }

    /// Vertices on the boundary surface, sorted.
    pub fn boundary_vertices(&self) -> Vec<u32> {
        let mut v: Vec<u32> = self.boundary_faces().into_iter().flatten().collect();
        v.sort_unstable();
        v.dedup();
        v
    }

    /// Total volume, m³.
    pub fn volume(&self) -> f64 {
        (0..self.tets.len()).map(|t| self.tet_volume(t)).sum()
    }

    /// Smallest altitude over all tets: min over tets of 3V / (largest face area), m.
    ///
    /// This is the length `h` used by the time-step bound (see [`crate::timestep`]).
    pub fn min_altitude(&self) -> f64 {
        (0..self.tets.len())
            .map(|t| tet_quality(&self.corners(t)).min_altitude)
            .fold(f64::INFINITY, f64::min)
    }

    /// Shortest edge over all tets, m (the paper's h: "minimum distance between a node and its neighbours").
    pub fn min_edge(&self) -> f64 {
        (0..self.tets.len())
            .map(|t| tet_quality(&self.corners(t)).min_edge)
            .fold(f64::INFINITY, f64::min)
    }

    /// Size and quality statistics.
    pub fn stats(&self) -> MeshStats {
        let mut s = MeshStats {
            vertices: self.positions.len(),
            tets: self.tets.len(),
            boundary_faces: self.boundary_faces().len(),
            min_volume: f64::INFINITY,
            min_edge: f64::INFINITY,
            min_altitude: f64::INFINITY,
            min_dihedral_deg: f64::INFINITY,
            ..Default::default()
        };
        for t in 0..self.tets.len() {
            let q = tet_quality(&self.corners(t));
            s.volume += q.volume;
            s.min_volume = s.min_volume.min(q.volume);
            s.min_edge = s.min_edge.min(q.min_edge);
            s.min_altitude = s.min_altitude.min(q.min_altitude);
            s.min_dihedral_deg = s.min_dihedral_deg.min(q.min_dihedral_deg);
            s.max_dihedral_deg = s.max_dihedral_deg.max(q.max_dihedral_deg);
            s.max_aspect_ratio = s.max_aspect_ratio.max(q.aspect_ratio);
        }
        s.mean_volume = s.volume / self.tets.len().max(1) as f64;
        s
    }
}

/// Quality figures of a single tet.
#[derive(Clone, Copy, Debug)]
pub struct TetQuality {
    /// Signed volume, m³.
    pub volume: f64,
    /// Shortest edge, m.
    pub min_edge: f64,
    /// Longest edge, m.
    pub max_edge: f64,
    /// 3V / largest face area, m.
    pub min_altitude: f64,
    /// Smallest dihedral angle, degrees.
    pub min_dihedral_deg: f64,
    /// Largest dihedral angle, degrees.
    pub max_dihedral_deg: f64,
    /// Longest edge / smallest altitude.
    pub aspect_ratio: f64,
}

/// Quality of the tet with corners `c`.
pub fn tet_quality(c: &[DVec3; 4]) -> TetQuality {
    let volume = signed_volume(c[0], c[1], c[2], c[3]);
    let edges: Vec<f64> = TET_EDGES
        .iter()
        .map(|e| c[e[0]].distance(c[e[1]]))
        .collect();
    let min_edge = edges.iter().cloned().fold(f64::INFINITY, f64::min);
    let max_edge = edges.iter().cloned().fold(0.0, f64::max);
    let normals: Vec<DVec3> = TET_FACES
        .iter()
        .map(|f| (c[f[1]] - c[f[0]]).cross(c[f[2]] - c[f[0]]) * 0.5)
        .collect();
    let max_area = normals.iter().map(|n| n.length()).fold(0.0, f64::max);
    let min_altitude = 3.0 * volume.abs() / max_area.max(f64::MIN_POSITIVE);
    let mut min_d = f64::INFINITY;
    let mut max_d: f64 = 0.0;
    for a in 0..4 {
        for b in a + 1..4 {
            // dihedral angle at the edge shared by faces a and b = π − angle between outward normals
            let cos = normals[a]
                .normalize_or_zero()
                .dot(normals[b].normalize_or_zero());
            let angle = (std::f64::consts::PI - cos.clamp(-1.0, 1.0).acos()).to_degrees();
            min_d = min_d.min(angle);
            max_d = max_d.max(angle);
        }
    }
    TetQuality {
        volume,
        min_edge,
        max_edge,
        min_altitude,
        min_dihedral_deg: min_d,
        max_dihedral_deg: max_d,
        aspect_ratio: max_edge / min_altitude.max(f64::MIN_POSITIVE),
    }
}
