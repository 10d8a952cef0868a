//! Sampling the particle zone: lattice points inside the zone's tets, each hosted by the tet
//! that contains it, in a fixed order (tets ascending, then lattice points in x-fastest
//! order) so the particle numbering is deterministic.

use super::Particles;
use crate::error::{PalpateError, Result};
use crate::mesh::TetMesh;
use crate::scene::ParticleSettings;
use glam::{DMat3, DVec3};
use std::collections::{HashMap, HashSet};

/// Lattice points closer than this (in barycentric terms) outside a tet still count as
/// inside it; ties between tets go to the first (the lattice index is taken once).
const INSIDE_TOLERANCE: f64 = 1e-10;

/// Sample `mesh`'s particle zone (region `settings.region`) at spacing Δx: the cell-centred
/// lattice X = X_min + (i + ½, j + ½, k + ½)·Δx over the zone's bounding box, nudged by a few
/// millionths of Δx so no point lies exactly on a face. Errors name the settings key when
/// the zone is empty or holds no lattice point.
pub fn sample(
    mesh: &TetMesh,
    settings: &ParticleSettings,
    density: f64,
    origin: &str,
) -> Result<Particles> {
    let bad = |item: &str, message: String| PalpateError::SceneValue {
        origin: origin.to_string(),
        item: item.to_string(),
        message,
    };
    let dx = settings.spacing;
    let zone: Vec<usize> = (0..mesh.n_tets())
        .filter(|&e| mesh.regions[e] == settings.region)
        .collect();
    if zone.is_empty() {
        return Err(bad(
            "particles.region",
            format!("no tet has region {}", settings.region),
        ));
    }
    let mut lo = DVec3::splat(f64::INFINITY);
    for &e in &zone {
        for p in mesh.corners(e) {
            lo = lo.min(p);
        }
    }
    let nudge = DVec3::new(1.3e-6, 2.9e-6, 4.7e-6) * dx;
    let lattice = |i: i64, j: i64, k: i64| {
        lo + DVec3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5) * dx + nudge
    };
    let mut taken: HashSet<(i64, i64, i64)> = HashSet::new();
    let mut index: Vec<(i64, i64, i64)> = Vec::new();
    let mut rest = Vec::new();
    let mut host = Vec::new();
    let mut weights = Vec::new();
    let mut hosting = vec![false; mesh.n_tets()];
    for &e in &zone {
        let x = mesh.corners(e);
        let dm = DMat3::from_cols(x[1] - x[0], x[2] - x[0], x[3] - x[0]);
        let inv = dm.inverse();
        let (bmin, bmax) = x.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(a, b), p| (a.min(*p), b.max(*p)),
        );
        let first = ((bmin - lo) / dx - 0.5).floor();
        let last = ((bmax - lo) / dx - 0.5).ceil();
        for k in first.z as i64..=last.z as i64 {
            for j in first.y as i64..=last.y as i64 {
                for i in first.x as i64..=last.x as i64 {
                    let p = lattice(i, j, k);
                    let b = inv * (p - x[0]);
                    let w = [1.0 - b.x - b.y - b.z, b.x, b.y, b.z];
                    // Not `c < -tol`: a lattice point so far out that its weights overflow to
                    // NaN (a spacing near f64's range) is outside too.
                    let inside = w.iter().all(|&c| c >= -INSIDE_TOLERANCE);
                    if !inside || !taken.insert((i, j, k)) {
                        continue;
                    }
                    index.push((i, j, k));
                    rest.extend(p.to_array().map(|c| c as f32));
                    host.push(e as u32);
                    weights.extend(w.map(|c| c as f32));
                    hosting[e] = true;
                }
            }
        }
    }
    let n = host.len();
    if n == 0 {
        return Err(bad(
            "particles.spacing",
            format!(
                "{} m is too coarse: no lattice point falls inside the {} tets of region {}",
                crate::scene::Num(dx),
                zone.len(),
                settings.region
            ),
        ));
    }
    let holding_volume: f64 = zone
        .iter()
        .filter(|&&e| hosting[e])
        .map(|&e| mesh.tet_volume(e))
        .sum();
    let volume = holding_volume / n as f64;
    // Surface particles: a lattice neighbour along an axis is missing.
    let present: HashMap<(i64, i64, i64), usize> =
        index.iter().enumerate().map(|(p, &ijk)| (ijk, p)).collect();
    let contact_area: Vec<f32> = index
        .iter()
        .map(|&(i, j, k)| {
            let missing = [
                (i - 1, j, k),
                (i + 1, j, k),
                (i, j - 1, k),
                (i, j + 1, k),
                (i, j, k - 1),
                (i, j, k + 1),
            ]
            .iter()
            .any(|ijk| !present.contains_key(ijk));
            if missing {
                (dx * dx) as f32
            } else {
                0.0
            }
        })
        .collect();
    let contact_offset = surface_offsets(mesh, &rest, &host, &contact_area, dx);
    // CSR over tets (particles are already grouped by host, in tet order).
    let mut tet_offsets = vec![0u32; mesh.n_tets() + 1];
    for &e in &host {
        tet_offsets[e as usize + 1] += 1;
    }
    for e in 0..mesh.n_tets() {
        tet_offsets[e + 1] += tet_offsets[e];
    }
    // CSR over vertices of particle slots p·4 + corner.
    let nv = mesh.n_vertices();
    let mut slot_offsets = vec![0u32; nv + 1];
    for &e in &host {
        for v in mesh.tets[e as usize] {
            slot_offsets[v as usize + 1] += 1;
        }
    }
    for i in 0..nv {
        slot_offsets[i + 1] += slot_offsets[i];
    }
    let mut fill = slot_offsets.clone();
    let mut slots = vec![0u32; 4 * n];
    for (p, &e) in host.iter().enumerate() {
        for (c, v) in mesh.tets[e as usize].iter().enumerate() {
            slots[fill[*v as usize] as usize] = (4 * p + c) as u32;
            fill[*v as usize] += 1;
        }
    }
    // Core mass: every tet except the particle-holding zone tets, ρV/4 per corner.
    let mut core_mass = vec![0.0f64; nv];
    for (e, tet) in mesh.tets.iter().enumerate() {
        if hosting[e] {
            continue;
        }
        let m = density * mesh.tet_volume(e) / 4.0;
        for &v in tet {
            core_mass[v as usize] += m;
        }
    }
    let support = (settings.kernel_radius * dx) as f32;
    let (_, n_cells) = super::params::GridParams::layout(&rest, support);
    if n_cells > super::params::MAX_GRID_CELLS {
        return Err(bad(
            "particles.spacing",
            format!(
                "the neighbour grid over region {}'s particles would have {n_cells} cells (kernel-support cells over the zone's bounding box), more than {}: the zone is too spread out for a spacing of {dx} m",
                settings.region,
                super::params::MAX_GRID_CELLS
            ),
        ));
    }
    Ok(Particles {
        settings: settings.clone(),
        rest,
        volume: volume as f32,
        mass: (density * volume) as f32,
        host,
        weights,
        tet_offsets,
        slot_offsets,
        slots,
        contact_area,
        contact_offset,
        support,
        pinned: vec![false; n],
        core_mass: core_mass.into_iter().map(|m| m as f32).collect(),
        follower_lumping: std::sync::OnceLock::new(),
    })
}

/// The distance from `x` to the nearest of `triangles` (+∞ for none).
pub fn distance_to_triangles(triangles: impl IntoIterator<Item = [DVec3; 3]>, x: DVec3) -> f64 {
    triangles
        .into_iter()
        .map(|[a, b, c]| (closest_on_triangle(x, a, b, c) - x).length())
        .fold(f64::INFINITY, f64::min)
}

/// The distance from the segment p–q to the nearest of `triangles` (+∞ for none): 0 where
/// it meets one, else the least of its ends' distances to the triangle and its distances to
/// the triangle's edges (where a segment misses a triangle, the closest pair has an end of
/// the segment or a point of an edge; Ericson, *Real-Time Collision Detection*, §5.1.9).
pub fn segment_distance_to_triangles(
    triangles: impl IntoIterator<Item = [DVec3; 3]>,
    p: DVec3,
    q: DVec3,
) -> f64 {
    let mut best = f64::INFINITY;
    for [a, b, c] in triangles {
        // A lower bound first (the segment's distance to the centroid less the triangle's
        // reach from it): most faces are far from a stride and are passed over on it.
        let centroid = (a + b + c) / 3.0;
        let reach = [a, b, c]
            .iter()
            .map(|v| v.distance(centroid))
            .fold(0.0, f64::max);
        if segment_segment_distance(p, q, centroid, centroid) - reach >= best {
            continue;
        }
        if segment_meets_triangle(p, q, a, b, c) {
            return 0.0;
        }
        let ends = (closest_on_triangle(p, a, b, c) - p)
            .length()
            .min((closest_on_triangle(q, a, b, c) - q).length());
        best = [(a, b), (b, c), (c, a)]
            .iter()
            .map(|&(e0, e1)| segment_segment_distance(p, q, e0, e1))
            .fold(ends.min(best), f64::min);
    }
    best
}

/// Whether the segment p → q meets triangle (a, b, c) (Möller–Trumbore: p + t(q − p) =
/// a + u(b − a) + v(c − a) with t, u, v, u + v in [0, 1], each bound given 1e-9 of slack so
/// that a segment through an edge shared by two faces, rounded differently in each, still
/// meets one). A segment in the triangle's plane counts as missing it: its distance to the
/// triangle's edges, taken beside this, covers it.
fn segment_meets_triangle(p: DVec3, q: DVec3, a: DVec3, b: DVec3, c: DVec3) -> bool {
    const SLACK: f64 = 1e-9;
    let (d, e1, e2) = (q - p, b - a, c - a);
    let h = d.cross(e2);
    let det = e1.dot(h);
    if det.abs() <= 1e-12 * d.length() * e1.length() * e2.length() {
        return false;
    }
    let s = p - a;
    let u = s.dot(h) / det;
    let k = s.cross(e1);
    let v = d.dot(k) / det;
    let t = e2.dot(k) / det;
    u >= -SLACK && v >= -SLACK && u + v <= 1.0 + SLACK && (-SLACK..=1.0 + SLACK).contains(&t)
}

/// The distance between segments p1–q1 and p2–q2 (Ericson §5.1.9: the closest points at
/// parameters s, t in [0, 1], clamped in turn; a segment of zero length is a point).
fn segment_segment_distance(p1: DVec3, q1: DVec3, p2: DVec3, q2: DVec3) -> f64 {
    let (d1, d2, r) = (q1 - p1, q2 - p2, p1 - p2);
    let (a, e, f) = (d1.length_squared(), d2.length_squared(), d2.dot(r));
    let tiny = f64::MIN_POSITIVE;
    let (s, t) = if a <= tiny && e <= tiny {
        (0.0, 0.0)
    } else if a <= tiny {
        (0.0, (f / e).clamp(0.0, 1.0))
    } else {
        let c = d1.dot(r);
        if e <= tiny {
            ((-c / a).clamp(0.0, 1.0), 0.0)
        } else {
            let b = d1.dot(d2);
            let denom = a * e - b * b;
            // Parallel segments (denom 0): any s; take 0.
            let s = if denom > 0.0 {
                ((b * f - c * e) / denom).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let t = (b * s + f) / e;
            if t < 0.0 {
                ((-c / a).clamp(0.0, 1.0), 0.0)
            } else if t > 1.0 {
                (((b - c) / a).clamp(0.0, 1.0), 1.0)
            } else {
                (s, t)
            }
        }
    };
    ((p1 + d1 * s) - (p2 + d2 * t)).length()
}

/// The closest point of triangle (a, b, c) to p (Ericson, *Real-Time Collision Detection*,
/// §5.1.5).
fn closest_on_triangle(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> DVec3 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

/// For each surface particle (contact area > 0), the offset to the nearest point of a
/// boundary face that shares a vertex with its host tet (zero when none is within 1.5 Δx:
/// a lattice hole next to the core, not the body's surface).
fn surface_offsets(mesh: &TetMesh, rest: &[f32], host: &[u32], area: &[f32], dx: f64) -> Vec<f32> {
    let faces = mesh.boundary_faces();
    let mut faces_of_vertex: Vec<Vec<u32>> = vec![Vec::new(); mesh.n_vertices()];
    for (k, f) in faces.iter().enumerate() {
        for &v in f {
            faces_of_vertex[v as usize].push(k as u32);
        }
    }
    let mut out = vec![0.0f32; rest.len()];
    for p in 0..host.len() {
        if area[p] <= 0.0 {
            continue;
        }
        let x = DVec3::new(
            rest[3 * p] as f64,
            rest[3 * p + 1] as f64,
            rest[3 * p + 2] as f64,
        );
        let mut best: Option<(f64, DVec3)> = None;
        for &v in &mesh.tets[host[p] as usize] {
            for &k in &faces_of_vertex[v as usize] {
                let [a, b, c] = faces[k as usize].map(|i| mesh.positions[i as usize]);
                let q = closest_on_triangle(x, a, b, c);
                let d = (q - x).length();
                if best.is_none_or(|(bd, _)| d < bd) {
                    best = Some((d, q - x));
                }
            }
        }
        if let Some((d, o)) = best {
            if d <= 1.5 * dx {
                out[3 * p..3 * p + 3].copy_from_slice(&o.as_vec3().to_array());
            }
        }
    }
    out
}
