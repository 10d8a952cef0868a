//! Mesh generators: a cantilever beam, a closed ellipsoidal shell (the paper's ED0) and an
//! idealised left ventricle (truncated ellipsoidal shell, Land et al. 2015).
//!
//! All three share one machine, [`extrude`]: a triangulated parameter surface is swept
//! through layers and every prism (triangle × layer) is cut into three tets. The cut of each
//! quadrilateral side of a prism uses the diagonal through its lowest global vertex id, so
//! the two prisms that share a side cut it the same way and the mesh is conforming whatever
//! the surface's topology (periodic, closed, a disk). How each surface quad is cut into two
//! triangles is free (the diagonal is inside the quad); generators pick it for quality.

use super::{signed_volume, tags, TetMesh};
use glam::DVec3;
use std::collections::HashMap;
use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

/// A triangulated parameter surface: `n_nodes` nodes and triangles over them.
#[derive(Clone, Debug, Default)]
pub struct SurfaceGrid {
    /// Number of surface nodes.
    pub n_nodes: usize,
    /// Triangles as node ids.
    pub triangles: Vec<[u32; 3]>,
}

impl SurfaceGrid {
    /// Add the quad (a, b, c, d) (in cyclic order) as two triangles split along the
    /// diagonal through its lowest node id.
    pub fn push_quad(&mut self, q: [u32; 4]) {
        let lowest = (0..4).min_by_key(|&i| q[i]).unwrap_or(0);
        self.push_quad_split(q, lowest % 2 == 0);
    }

    /// Add the quad (a, b, c, d) as two triangles, split along a–c when `diagonal_ac`, else b–d.
    pub fn push_quad_split(&mut self, q: [u32; 4], diagonal_ac: bool) {
        if diagonal_ac {
            self.triangles.push([q[0], q[1], q[2]]);
            self.triangles.push([q[0], q[2], q[3]]);
        } else {
            self.triangles.push([q[1], q[2], q[3]]);
            self.triangles.push([q[1], q[3], q[0]]);
        }
    }
}

/// Sweep `surface` through `layers` layers (layers + 1 node sheets) into tets.
///
/// Vertex `sheet·n + s` is placed at `position(sheet, s)`. Each prism (a, b, c) with
/// a < b < c becomes {a,b,c,c′}, {a,b,b′,c′}, {a,a′,b′,c′} (′ = next sheet); tets are
/// oriented positively. Returns positions, tets and the layer index of each tet.
pub fn extrude(
    surface: &SurfaceGrid,
    layers: usize,
    position: impl Fn(usize, usize) -> DVec3,
) -> (Vec<DVec3>, Vec<[u32; 4]>, Vec<u32>) {
    let n = surface.n_nodes;
    let mut positions = Vec::with_capacity(n * (layers + 1));
    for sheet in 0..=layers {
        for s in 0..n {
            positions.push(position(sheet, s));
        }
    }
    let mut tets = Vec::with_capacity(surface.triangles.len() * layers * 3);
    let mut layer_of = Vec::with_capacity(tets.capacity());
    for layer in 0..layers {
        let off = (layer * n) as u32;
        let up = n as u32;
        for tri in &surface.triangles {
            let mut t = *tri;
            t.sort_unstable();
            let [a, b, c] = t.map(|i| i + off);
            for mut tet in [
                [a, b, c, c + up],
                [a, b, b + up, c + up],
                [a, a + up, b + up, c + up],
            ] {
                let p = tet.map(|i| positions[i as usize]);
                if signed_volume(p[0], p[1], p[2], p[3]) < 0.0 {
                    tet.swap(2, 3);
                }
                tets.push(tet);
                layer_of.push(layer as u32);
            }
        }
    }
    (positions, tets, layer_of)
}

/// A box `size` (m) from the origin, `cells` hexahedral cells each cut into 6 tets.
pub fn beam(size: [f64; 3], cells: [usize; 3]) -> TetMesh {
    let axis = |k: usize| -> Vec<f64> {
        (0..=cells[k])
            .map(|i| i as f64 * (size[k] / cells[k] as f64))
            .collect()
    };
    graded_box(&axis(0), &axis(1), &axis(2))
}

/// A box on the tensor grid of node coordinates `xs` × `ys` × `zs` (each strictly
/// increasing, m), every hexahedral cell cut into 6 tets as [`beam`] does.
pub fn graded_box(xs: &[f64], ys: &[f64], zs: &[f64]) -> TetMesh {
    let (nx, ny, nz) = (xs.len() - 1, ys.len() - 1, zs.len() - 1);
    let mut grid = SurfaceGrid {
        n_nodes: (nx + 1) * (ny + 1),
        ..Default::default()
    };
    let id = |i: usize, j: usize| (i + j * (nx + 1)) as u32;
    for j in 0..ny {
        for i in 0..nx {
            grid.push_quad([id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    let (positions, tets, _) = extrude(&grid, nz, |k, s| {
        let (i, j) = (s % (nx + 1), s / (nx + 1));
        DVec3::new(xs[i], ys[j], zs[k])
    });
    let regions = vec![0; tets.len()];
    TetMesh {
        positions,
        tets,
        regions,
        ..Default::default()
    }
}

/// Node coordinates from `start` to `start + length` (m): cells of size `fine` next to
/// `start`, each next cell `growth` times the previous, the last one stretched or shrunk
/// so the coordinates end exactly at `start + length` (a geometric grading that resolves
/// a contact at `start` with few cells).
pub fn graded_axis(start: f64, length: f64, fine: f64, growth: f64) -> Vec<f64> {
    let mut xs = vec![start];
    let mut h = fine;
    let end = start + length;
    while xs[xs.len() - 1] + h < end - 0.5 * h {
        let next = xs[xs.len() - 1] + h;
        xs.push(next);
        h *= growth;
    }
    xs.push(end);
    xs
}

/// Cubed-sphere surface: six `n`×`n` grids on the faces of a cube, seams shared.
/// Returns the grid and each node's unit direction (equiangular gnomonic projection).
pub fn cubed_sphere(n: usize) -> (SurfaceGrid, Vec<DVec3>) {
    let mut ids: HashMap<[i64; 3], u32> = HashMap::new();
    let mut dirs = Vec::new();
    let mut grid = SurfaceGrid::default();
    let n_i = n as i64;
    let mut node = |p: [i64; 3], dirs: &mut Vec<DVec3>| -> u32 {
        *ids.entry(p).or_insert_with(|| {
            let q = p.map(|c| (FRAC_PI_4 * (2.0 * c as f64 / n as f64 - 1.0)).tan());
            dirs.push(DVec3::from_array(q).normalize());
            (dirs.len() - 1) as u32
        })
    };
    for axis in 0..3 {
        for side in [0, n_i] {
            let (ua, va) = ((axis + 1) % 3, (axis + 2) % 3);
            for j in 0..n_i {
                for i in 0..n_i {
                    let at = |di: i64, dj: i64| {
                        let mut p = [0i64; 3];
                        p[axis] = side;
                        p[ua] = i + di;
                        p[va] = j + dj;
                        p
                    };
                    let q = [at(0, 0), at(1, 0), at(1, 1), at(0, 1)].map(|p| node(p, &mut dirs));
                    grid.push_quad(q);
                }
            }
        }
    }
    grid.n_nodes = dirs.len();
    (grid, dirs)
}

/// Region id of a tet in wall layer `layer` of `layers`: the inner half of the wall is
/// [`REGION_INNER_WALL`], the outer half [`REGION_OUTER_WALL`].
pub fn wall_region(layer: u32, layers: usize) -> u32 {
    if (layer as usize) < layers.div_ceil(2) {
        REGION_INNER_WALL
    } else {
        REGION_OUTER_WALL
    }
}

/// Region id of tets in the inner half of a shell wall (the FEM core of the hybrid model).
pub const REGION_INNER_WALL: u32 = 0;
/// Region id of tets in the outer half of a shell wall (the particle zone of the hybrid model).
pub const REGION_OUTER_WALL: u32 = 1;

/// Two concentric ellipsoids (semi-axes `inner` and `outer`, m) with the shell between them
/// filled with tets: `layers` through the wall, `n` cells along each cube-face edge.
/// Vertex tags: inner surface = endocardium, outer = epicardium. Regions: inner/outer wall.
pub fn ellipsoid_shell(inner: [f64; 3], outer: [f64; 3], layers: usize, n: usize) -> TetMesh {
    let (grid, dirs) = cubed_sphere(n);
    let (a, b) = (DVec3::from_array(inner), DVec3::from_array(outer));
    let (positions, tets, layer_of) = extrude(&grid, layers, |k, s| {
        let t = k as f64 / layers as f64;
        (a + (b - a) * t) * dirs[s]
    });
    let mut vertex_tags = vec![0; positions.len()];
    for s in 0..grid.n_nodes {
        vertex_tags[s] |= tags::ENDOCARDIUM;
        vertex_tags[layers * grid.n_nodes + s] |= tags::EPICARDIUM;
    }
    TetMesh {
        positions,
        tets,
        regions: layer_of.iter().map(|&l| wall_region(l, layers)).collect(),
        vertex_tags,
        ..Default::default()
    }
}

/// Concentric (Shirley–Chiu) map of the square [−1,1]² onto the unit disk: squares of
/// "radius" ρ go to circles of radius ρ, so rings keep uniform spacing and the centre has
/// no singular fan. Returns (radius ∈ \[0,1\], angle).
pub fn concentric_disk(a: f64, b: f64) -> (f64, f64) {
    if a == 0.0 && b == 0.0 {
        return (0.0, 0.0);
    }
    let (r, theta) = if a.abs() > b.abs() {
        (a, FRAC_PI_4 * (b / a))
    } else {
        (b, FRAC_PI_2 - FRAC_PI_4 * (a / b))
    };
    let (x, y) = (r * theta.cos(), r * theta.sin());
    ((x * x + y * y).sqrt(), y.atan2(x))
}

/// Geometry of an idealised left ventricle (all lengths in m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LvGeometry {
    /// Short-axis radius at endocardium and epicardium.
    pub short_radius: [f64; 2],
    /// Long-axis radius at endocardium and epicardium.
    pub long_radius: [f64; 2],
    /// Height of the base plane (z).
    pub base_z: f64,
}

impl Default for LvGeometry {
    /// Land et al. 2015 benchmark: r_s 7 → 10 mm, r_l 17 → 20 mm, base at z = 5 mm.
    fn default() -> Self {
        LvGeometry {
            short_radius: [0.007, 0.010],
            long_radius: [0.017, 0.020],
            base_z: 0.005,
        }
    }
}

impl LvGeometry {
    /// Analytic volume of the wall: V(epi) − V(endo), with V the volume of the prolate
    /// spheroid (r_s, r_s, r_l) below z_base: π r_s² [(z_b + r_l) − (z_b³ + r_l³)/(3 r_l²)], m³.
    pub fn wall_volume(&self) -> f64 {
        let v = |rs: f64, rl: f64| {
            let zb = self.base_z;
            PI * rs * rs * ((zb + rl) - (zb.powi(3) + rl.powi(3)) / (3.0 * rl * rl))
        };
        v(self.short_radius[1], self.long_radius[1]) - v(self.short_radius[0], self.long_radius[0])
    }

    /// Point at wall fraction t ∈ \[0,1\] (endo → epi), disk radius ρ ∈ \[0,1\] (apex → base)
    /// and angle v: x = r_s sin u cos v, y = r_s sin u sin v, z = r_l cos u with
    /// u = −π + ρ (π − arccos(z_base / r_l)).
    pub fn point(&self, t: f64, rho: f64, v: f64) -> DVec3 {
        let rs = self.short_radius[0] + t * (self.short_radius[1] - self.short_radius[0]);
        let rl = self.long_radius[0] + t * (self.long_radius[1] - self.long_radius[0]);
        let u_base = -(self.base_z / rl).clamp(-1.0, 1.0).acos();
        let u = -PI + rho * (u_base + PI);
        DVec3::new(rs * u.sin() * v.cos(), rs * u.sin() * v.sin(), rl * u.cos())
    }
}

/// Fibre helix angle at the endocardium, degrees (linear to −60° at the epicardium).
pub const HELIX_ENDO_DEG: f64 = 60.0;

/// Idealised left ventricle: `layers` through the wall, a `disk`×`disk` square grid mapped
/// onto the apex-to-base surface by [`concentric_disk`] (disk/2 rings apex → base, 4·disk
/// cells around, no seam and no polar fan). Tags: endocardium, epicardium, base. Regions:
/// inner/outer wall. Fibres: helix angle α(t) = 60° − 120° t (t = wall fraction, endo → epi)
/// from the circumferential direction towards the apex-to-base direction,
/// f = cos α e_circ + sin α e_long, at each tet's centroid.
pub fn lv(geometry: LvGeometry, layers: usize, disk: usize) -> TetMesh {
    let m = disk + 1;
    let mut grid = SurfaceGrid {
        n_nodes: m * m,
        ..Default::default()
    };
    let id = |i: usize, j: usize| (i + j * m) as u32;
    let polar: Vec<(f64, f64)> = (0..m * m)
        .map(|s| {
            let (i, j) = (s % m, s / m);
            let a = 2.0 * i as f64 / disk as f64 - 1.0;
            let b = 2.0 * j as f64 / disk as f64 - 1.0;
            concentric_disk(a, b)
        })
        .collect();
    let on_rim = |s: u32| {
        let (i, j) = (s as usize % m, s as usize / m);
        i == 0 || j == 0 || i == disk || j == disk
    };
    let mid = |s: u32| geometry.point(0.5, polar[s as usize].0, polar[s as usize].1);
    for j in 0..disk {
        for i in 0..disk {
            let q = [id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)];
            // A triangle with all three nodes on the base rim would extrude into a flat
            // prism in the base plane: at the square's corners take the other diagonal.
            // Elsewhere, the split whose worse triangle is better (on the mid-wall surface).
            let rim_ac = (on_rim(q[0]) && on_rim(q[1]) && on_rim(q[2]))
                || (on_rim(q[0]) && on_rim(q[2]) && on_rim(q[3]));
            let rim_bd = (on_rim(q[1]) && on_rim(q[2]) && on_rim(q[3]))
                || (on_rim(q[1]) && on_rim(q[3]) && on_rim(q[0]));
            let p = q.map(mid);
            let ac = triangle_quality(p[0], p[1], p[2]).min(triangle_quality(p[0], p[2], p[3]));
            let bd = triangle_quality(p[1], p[2], p[3]).min(triangle_quality(p[1], p[3], p[0]));
            grid.push_quad_split(q, if rim_ac != rim_bd { rim_bd } else { ac >= bd });
        }
    }
    let (positions, tets, layer_of) = extrude(&grid, layers, |k, s| {
        let (rho, v) = polar[s];
        geometry.point(k as f64 / layers as f64, rho, v)
    });
    let mut vertex_tags = vec![0; positions.len()];
    for k in 0..=layers {
        for s in 0..m * m {
            let (i, j) = (s % m, s / m);
            let g = k * m * m + s;
            if k == 0 {
                vertex_tags[g] |= tags::ENDOCARDIUM;
            }
            if k == layers {
                vertex_tags[g] |= tags::EPICARDIUM;
            }
            if i == 0 || j == 0 || i == disk || j == disk {
                vertex_tags[g] |= tags::BASE;
            }
        }
    }
    let param: Vec<(f64, f64, f64)> = (0..positions.len())
        .map(|g| {
            let (k, s) = (g / (m * m), g % (m * m));
            (k as f64 / layers as f64, polar[s].0, polar[s].1)
        })
        .collect();
    let fibres = tets
        .iter()
        .map(|t| lv_fibre(&geometry, t.map(|i| param[i as usize])))
        .collect();
    TetMesh {
        positions,
        tets,
        regions: layer_of.iter().map(|&l| wall_region(l, layers)).collect(),
        vertex_tags,
        fibres,
    }
}

/// Triangle shape quality 4√3·area / Σ edge², 1 for equilateral, 0 for degenerate.
pub fn triangle_quality(a: DVec3, b: DVec3, c: DVec3) -> f64 {
    let area = 0.5 * (b - a).cross(c - a).length();
    let s = (b - a).length_squared() + (c - b).length_squared() + (a - c).length_squared();
    4.0 * 3f64.sqrt() * area / s.max(f64::MIN_POSITIVE)
}

/// Fibre direction of a tet from its corners' (t, ρ, v) parameters (see [`lv`]).
fn lv_fibre(geometry: &LvGeometry, corners: [(f64, f64, f64); 4]) -> DVec3 {
    let t = corners.iter().map(|c| c.0).sum::<f64>() / 4.0;
    let mut e_circ = DVec3::ZERO;
    let mut e_long = DVec3::ZERO;
    let h = 1e-6;
    for (ct, rho, v) in corners {
        let p = geometry.point(ct, rho, v);
        let dv = geometry.point(ct, rho, v + h) - p;
        let drho = geometry.point(ct, (rho + h).min(1.0), v)
            - geometry.point(ct, (rho + h).min(1.0) - h, v);
        // The circumferential direction is undefined on the axis (apex): skip it there.
        if dv.length() > 1e-14 {
            e_circ += dv.normalize();
        }
        e_long += drho.normalize_or_zero();
    }
    let e_long = e_long.normalize_or(DVec3::Z);
    let e_circ =
        (e_circ - e_long * e_circ.dot(e_long)).normalize_or(e_long.any_orthonormal_vector());
    let alpha = (HELIX_ENDO_DEG - 2.0 * HELIX_ENDO_DEG * t).to_radians();
    (e_circ * alpha.cos() + e_long * alpha.sin()).normalize()
}
