//! The tool's static contact stiffness: how the force the tissue exerts on the tool changes
//! when the tool moves and the tissue is given time to settle (the K of the haptic local
//! model, DESIGN §7). The `tool_force` stage reports the *frozen* stiffness (tissue held);
//! the hand feels the tissue's compliance in series with the penalty springs, which is
//! this module's answer.
//!
//! Contact point c (a surface vertex, or a dynamic particle embedded in a host tet) has a
//! penalty spring k_c = k·A_c (N/m) along its normal n_c, and its displacement is
//! interpolated from mesh vertices, u_c = Σₐ w_ca uₐ. With K₀ the small-strain (rest
//! configuration) stiffness of the tet mesh on its free vertices, the tissue's normal
//! compliance between contact points is C_cd = l_dᵀ K₀⁻¹ l_c with l_c = Σₐ w_ca (n_c at
//! vertex a), and eliminating the tissue from the static equations gives
//!
//!   K = −Gᵀ (diag(1/k_c) + C)⁻¹ G + Σ_c k_c (R/r_c − 1)(I − n_c n_cᵀ)
//!
//! G the m×3 matrix of rows n_cᵀ, R the tool radius, r_c the point's distance from the tool
//! centre. With a rigid tissue (C = 0) it is the frozen stiffness of [`crate::contact`]; the
//! second (tangential, geometric) term is taken frozen. K₀⁻¹ comes from a profile (skyline)
//! Cholesky factor of K₀ in reverse Cuthill–McKee order, built once; each vertex's three
//! columns of K₀⁻¹ are solved when it first comes into contact and cached.
//!
//! Approximations: linear elasticity about the rest shape (a pre-stressed or strongly
//! deformed body is stiffer or softer than this), the material's small-strain Lamé
//! parameters for every tet (all tets, particle zone included, at full weight), contact
//! damping ignored (a static quantity). A body with no fixed vertex has a singular K₀:
//! then there is no static stiffness and [`ContactCompliance::new`] says why.

use crate::model::Model;
use glam::{DMat3, DVec3};
use std::collections::HashMap;

/// Marks a vertex without degrees of freedom (fixed, or in no tet).
const NO_DOF: u32 = u32::MAX;

/// Largest profile (stored entries of the Cholesky factor) built: 2·10⁷ doubles, 160 MB.
pub const MAX_PROFILE_ENTRIES: usize = 20_000_000;

/// Bytes of cached K₀⁻¹ columns kept before the cache is cleared.
const COLUMN_CACHE_BYTES: usize = 64 << 20;

/// A point where the tool presses the tissue.
#[derive(Clone, Debug, PartialEq)]
pub struct ContactPoint {
    /// k_c = k·A_c, N/m: the point's penalty stiffness.
    pub stiffness: f64,
    /// Unit normal from the tool centre to the point.
    pub normal: DVec3,
    /// r_c, m: the point's distance from the tool centre.
    pub distance: f64,
    /// (vertex, weight): u_c = Σ w·u_vertex (one vertex with weight 1 for a surface vertex,
    /// the host tet's barycentric weights for a particle).
    pub support: Vec<(u32, f64)>,
}

/// Why a static stiffness cannot be had for a model.
#[derive(Clone, Debug, PartialEq)]
pub enum Unavailable {
    /// K₀ is singular: the body has a rigid-body motion (no fixed vertex, or a free part).
    Singular {
        /// The degree of freedom (in factor order) where the pivot vanished.
        dof: usize,
    },
    /// The factor would hold more than [`MAX_PROFILE_ENTRIES`] entries.
    TooLarge {
        /// Entries it would hold.
        entries: usize,
    },
    /// No free vertex.
    NoFreeVertex,
}

impl std::fmt::Display for Unavailable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Unavailable::Singular { dof } => write!(
                f,
                "the stiffness matrix is singular at degree of freedom {dof} (a part of the body is not held)"
            ),
            Unavailable::TooLarge { entries } => write!(
                f,
                "its factor would hold {entries} entries (limit {MAX_PROFILE_ENTRIES})"
            ),
            Unavailable::NoFreeVertex => write!(f, "no vertex is free"),
        }
    }
}

/// Small-strain stiffness of a model, factored, with cached columns of its inverse.
pub struct ContactCompliance {
    /// Per vertex: its position in the factor order, or [`NO_DOF`].
    order: Vec<u32>,
    factor: ProfileCholesky,
    /// Per vertex: K₀⁻¹ applied to unit loads along x, y, z at it (3 × 3n values).
    columns: HashMap<u32, Vec<f64>>,
    /// Tool radius R, m (for the geometric term).
    radius: f64,
}

impl ContactCompliance {
    /// Assemble and factor K₀ of `model` (its tool radius, if any, for the geometric term).
    pub fn new(model: &Model) -> Result<ContactCompliance, Unavailable> {
        let n = model.n_vertices();
        let free: Vec<bool> = (0..n)
            .map(|v| !(model.inv_mass[v] == 0.0 && model.mass[v] > 0.0))
            .collect();
        let mut in_tet = vec![false; n];
        for t in &model.tets {
            for &v in t {
                in_tet[v as usize] = true;
            }
        }
        let active: Vec<bool> = (0..n).map(|v| free[v] && in_tet[v]).collect();
        let order = reverse_cuthill_mckee(n, &model.tets, &active);
        let n_free = order.iter().filter(|&&p| p != NO_DOF).count();
        if n_free == 0 {
            return Err(Unavailable::NoFreeVertex);
        }
        // Row starts of the profile: the lowest DOF that shares a tet with the row's vertex.
        let mut first_vertex: Vec<u32> = (0..n_free as u32).collect();
        for t in &model.tets {
            let lowest = t
                .iter()
                .map(|&v| order[v as usize])
                .filter(|&p| p != NO_DOF)
                .min();
            if let Some(lowest) = lowest {
                for &v in t {
                    let p = order[v as usize];
                    if p != NO_DOF {
                        let f = &mut first_vertex[p as usize];
                        *f = (*f).min(lowest);
                    }
                }
            }
        }
        let first: Vec<usize> = (0..3 * n_free)
            .map(|row| 3 * first_vertex[row / 3] as usize)
            .collect();
        let entries: usize = first.iter().enumerate().map(|(r, &f)| r - f + 1).sum();
        if entries > MAX_PROFILE_ENTRIES {
            return Err(Unavailable::TooLarge { entries });
        }
        let mut k0 = ProfileCholesky::zeros(first);
        let (lambda, mu) = (model.material.lambda, model.material.mu);
        let rest = |v: u32| {
            let i = 3 * v as usize;
            DVec3::new(
                model.rest[i] as f64,
                model.rest[i + 1] as f64,
                model.rest[i + 2] as f64,
            )
        };
        for t in &model.tets {
            let x = t.map(rest);
            let dm = DMat3::from_cols(x[1] - x[0], x[2] - x[0], x[3] - x[0]);
            let volume = dm.determinant() / 6.0;
            if volume <= 0.0 {
                continue;
            }
            let inv = dm.inverse();
            // ∇N_k for k = 1..3 is row k−1 of Dm⁻¹; ∇N_0 = −Σ.
            let (g1, g2, g3) = (inv.row(0), inv.row(1), inv.row(2));
            let g = [-(g1 + g2 + g3), g1, g2, g3];
            for a in 0..4 {
                let pa = order[t[a] as usize];
                if pa == NO_DOF {
                    continue;
                }
                for b in 0..4 {
                    let pb = order[t[b] as usize];
                    if pb == NO_DOF || pb > pa {
                        continue;
                    }
                    let dot = g[a].dot(g[b]);
                    for i in 0..3 {
                        for j in 0..3 {
                            let row = 3 * pa as usize + i;
                            let col = 3 * pb as usize + j;
                            if col > row {
                                continue;
                            }
                            let delta = if i == j { dot } else { 0.0 };
                            let kij = volume
                                * (lambda * g[a][i] * g[b][j] + mu * (g[a][j] * g[b][i] + delta));
                            k0.add(row, col, kij);
                        }
                    }
                }
            }
        }
        k0.factor().map_err(|dof| Unavailable::Singular { dof })?;
        Ok(ContactCompliance {
            order,
            factor: k0,
            columns: HashMap::new(),
            radius: model.tool.as_ref().map_or(0.0, |t| t.tool.radius),
        })
    }

    /// Degrees of freedom of the factored system.
    pub fn dofs(&self) -> usize {
        self.factor.n()
    }

    /// Entries the factor holds.
    pub fn profile_entries(&self) -> usize {
        self.factor.values.len()
    }

    /// u = K₀⁻¹ f for a load `f` per vertex (packed xyz, N); fixed vertices get u = 0.
    pub fn solve(&self, f: &[f64]) -> Vec<f64> {
        let mut b = vec![0.0; self.factor.n()];
        for (v, &p) in self.order.iter().enumerate() {
            if p != NO_DOF {
                b[3 * p as usize..3 * p as usize + 3].copy_from_slice(&f[3 * v..3 * v + 3]);
            }
        }
        self.factor.solve_in_place(&mut b);
        let mut u = vec![0.0; f.len()];
        for (v, &p) in self.order.iter().enumerate() {
            if p != NO_DOF {
                u[3 * v..3 * v + 3].copy_from_slice(&b[3 * p as usize..3 * p as usize + 3]);
            }
        }
        u
    }

    /// Make sure vertex `v`'s three columns of K₀⁻¹ are cached (false: `v` has no DOF).
    fn ensure_columns(&mut self, v: u32) -> bool {
        let p = self.order[v as usize];
        if p == NO_DOF {
            return false;
        }
        if !self.columns.contains_key(&v) {
            let n = self.factor.n();
            if (self.columns.len() + 1) * 3 * n * 8 > COLUMN_CACHE_BYTES {
                self.columns.clear();
            }
            let mut cols = vec![0.0; 3 * n];
            for k in 0..3 {
                let col = &mut cols[k * n..(k + 1) * n];
                col[3 * p as usize + k] = 1.0;
                self.factor.solve_in_place(col);
            }
            self.columns.insert(v, cols);
        }
        true
    }

    /// The vertices of `points`' supports (with degrees of freedom) whose columns of K₀⁻¹
    /// are not cached yet, each once, in order of first appearance.
    pub fn missing_columns(&self, points: &[ContactPoint]) -> Vec<u32> {
        let mut missing = Vec::new();
        for pt in points {
            for &(v, w) in &pt.support {
                if w != 0.0
                    && self.order[v as usize] != NO_DOF
                    && !self.columns.contains_key(&v)
                    && !missing.contains(&v)
                {
                    missing.push(v);
                }
            }
        }
        missing
    }

    /// True when `more` vertices' columns fit in the cache beside those held (else adding
    /// them clears it, and a caller warming them a few at a time would never finish).
    pub fn fits_in_cache(&self, more: usize) -> bool {
        (self.columns.len() + more) * 3 * self.factor.n() * 8 <= COLUMN_CACHE_BYTES
    }

    /// Solve and cache the columns of `vertices` in order, at least one and then while less
    /// than `budget` has passed; returns how many are cached now. Spreads over several
    /// calls the solves that [`ContactCompliance::stiffness`] would make at once (three
    /// triangular solves of the profile factor per new vertex: tens of ms at a first
    /// contact on lv_touch).
    pub fn warm_columns(&mut self, vertices: &[u32], budget: std::time::Duration) -> usize {
        let start = std::time::Instant::now();
        let mut done = 0;
        for &v in vertices {
            if done > 0 && start.elapsed() >= budget {
                break;
            }
            self.ensure_columns(v);
            done += 1;
        }
        done
    }

    /// The static stiffness ∂F/∂x (N/m) of the tool force with respect to the tool position
    /// over `points` (see the module formula); zero without points.
    pub fn stiffness(&mut self, points: &[ContactPoint]) -> DMat3 {
        let m = points.len();
        if m == 0 {
            return DMat3::ZERO;
        }
        let n = self.factor.n();
        // z_c = K₀⁻¹ l_c in factor order.
        let mut z = vec![0.0; m * n];
        for (c, pt) in points.iter().enumerate() {
            for &(v, w) in &pt.support {
                if w == 0.0 || !self.ensure_columns(v) {
                    continue;
                }
                let cols = &self.columns[&v];
                let zc = &mut z[c * n..(c + 1) * n];
                for k in 0..3 {
                    let s = w * pt.normal[k];
                    if s != 0.0 {
                        for (o, &x) in zc.iter_mut().zip(&cols[k * n..(k + 1) * n]) {
                            *o += s * x;
                        }
                    }
                }
            }
        }
        // M = diag(1/k) + C, C_cd = l_dᵀ z_c.
        let mut mat = vec![0.0; m * m];
        for (d, pd) in points.iter().enumerate() {
            for c in 0..m {
                let zc = &z[c * n..(c + 1) * n];
                let mut s = 0.0;
                for &(v, w) in &pd.support {
                    let p = self.order[v as usize];
                    if p != NO_DOF {
                        let b = 3 * p as usize;
                        s += w * DVec3::new(zc[b], zc[b + 1], zc[b + 2]).dot(pd.normal);
                    }
                }
                mat[d * m + c] = s;
            }
        }
        for (c, pt) in points.iter().enumerate() {
            mat[c * m + c] += 1.0 / pt.stiffness.max(f64::MIN_POSITIVE);
        }
        // Symmetrise (C is symmetric up to round-off) and solve M X = G.
        for d in 0..m {
            for c in 0..d {
                let s = 0.5 * (mat[d * m + c] + mat[c * m + d]);
                mat[d * m + c] = s;
                mat[c * m + d] = s;
            }
        }
        let mut rhs: Vec<[f64; 3]> = points.iter().map(|p| p.normal.to_array()).collect();
        if !dense_cholesky_solve(&mut mat, m, &mut rhs) {
            // Not positive definite (cannot happen for k > 0 and SPD K₀): no stiffness.
            return DMat3::ZERO;
        }
        let mut k = DMat3::ZERO;
        for (pt, x) in points.iter().zip(&rhs) {
            let x = DVec3::from_array(*x);
            // −n xᵀ summed: column j gets −n·x_j.
            k -= DMat3::from_cols(pt.normal * x.x, pt.normal * x.y, pt.normal * x.z);
            let t = (self.radius / pt.distance.max(f64::MIN_POSITIVE) - 1.0).max(0.0);
            let nn = DMat3::from_cols(
                pt.normal * pt.normal.x,
                pt.normal * pt.normal.y,
                pt.normal * pt.normal.z,
            );
            k += (DMat3::IDENTITY - nn) * (pt.stiffness * t);
        }
        k
    }
}

/// The contact points of `model`'s tool centred at `centre` (m) in the state
/// `displacements` (packed xyz per vertex, m), with the particles' state where the model
/// has them. With particles in contact, the dynamic particles carry the contact (the tets
/// under them have handed theirs over) and only they are returned; otherwise the surface
/// vertices inside the sphere.
pub fn contact_points(
    model: &Model,
    displacements: &[f32],
    particles: Option<&crate::stepper::ParticleSnapshot>,
    centre: DVec3,
) -> Vec<ContactPoint> {
    let Some(tool) = &model.tool else {
        return Vec::new();
    };
    let (radius, k) = (tool.tool.radius, tool.tool.stiffness);
    let at = |x: DVec3| {
        let y = x - centre;
        let r = y.length();
        (r < radius && r > 0.0).then(|| (y / r, r))
    };
    let mut points = Vec::new();
    if let (Some(pd), Some(snap)) = (&model.particles, particles) {
        for p in 0..pd.len() {
            if snap.modes[p] & crate::particles::params::mode::DYNAMIC == 0
                || pd.contact_area[p] <= 0.0
            {
                continue;
            }
            let x = DVec3::from_array(std::array::from_fn(|c| {
                (pd.rest[3 * p + c] + snap.displacements[3 * p + c] + pd.contact_offset[3 * p + c])
                    as f64
            }));
            if let Some((normal, distance)) = at(x) {
                let t = model.tets[pd.host[p] as usize];
                points.push(ContactPoint {
                    stiffness: k * pd.contact_area[p] as f64,
                    normal,
                    distance,
                    support: (0..4)
                        .map(|c| (t[c], pd.weights[4 * p + c] as f64))
                        .collect(),
                });
            }
        }
        if !points.is_empty() {
            return points;
        }
    }
    for (s, &v) in tool.surface_vertices.iter().enumerate() {
        let i = 3 * v as usize;
        let x = DVec3::from_array(std::array::from_fn(|c| {
            (model.rest[i + c] + displacements[i + c]) as f64
        }));
        if let Some((normal, distance)) = at(x) {
            points.push(ContactPoint {
                stiffness: k * tool.surface_area[s] as f64,
                normal,
                distance,
                support: vec![(v, 1.0)],
            });
        }
    }
    points
}

/// Solve A X = B in place for a dense SPD `a` (n×n row-major, overwritten by its factor)
/// and 3 right-hand sides; false when A is not positive definite.
fn dense_cholesky_solve(a: &mut [f64], n: usize, b: &mut [[f64; 3]]) -> bool {
    for j in 0..n {
        let mut d = a[j * n + j];
        for k in 0..j {
            d -= a[j * n + k] * a[j * n + k];
        }
        if d.is_nan() || d <= 0.0 {
            return false;
        }
        let d = d.sqrt();
        a[j * n + j] = d;
        for i in j + 1..n {
            let mut s = a[i * n + j];
            for k in 0..j {
                s -= a[i * n + k] * a[j * n + k];
            }
            a[i * n + j] = s / d;
        }
    }
    // Forward (L y = b) and backward (Lᵀ x = y) substitution, three columns at once.
    for i in 0..n {
        let mut s = b[i];
        for k in 0..i {
            for (sr, br) in s.iter_mut().zip(b[k]) {
                *sr -= a[i * n + k] * br;
            }
        }
        b[i] = s.map(|x| x / a[i * n + i]);
    }
    for i in (0..n).rev() {
        let mut s = b[i];
        for k in i + 1..n {
            for (sr, br) in s.iter_mut().zip(b[k]) {
                *sr -= a[k * n + i] * br;
            }
        }
        b[i] = s.map(|x| x / a[i * n + i]);
    }
    true
}

/// Reverse Cuthill–McKee order of the `active` vertices of a tet mesh's vertex graph:
/// per vertex its position, or [`NO_DOF`] when inactive. Each connected part starts from a
/// pseudo-peripheral vertex (the last one reached by a breadth-first search from a
/// lowest-degree vertex), neighbours visited by increasing degree.
fn reverse_cuthill_mckee(n: usize, tets: &[[u32; 4]], active: &[bool]) -> Vec<u32> {
    let mut adjacency: Vec<Vec<u32>> = vec![Vec::new(); n];
    for t in tets {
        for &a in t {
            for &b in t {
                if a != b && active[a as usize] && active[b as usize] {
                    adjacency[a as usize].push(b);
                }
            }
        }
    }
    for list in &mut adjacency {
        list.sort_unstable();
        list.dedup();
    }
    let degree = |v: u32| adjacency[v as usize].len();
    let bfs = |start: u32, visited: &mut Vec<bool>, out: &mut Vec<u32>| {
        let begin = out.len();
        visited[start as usize] = true;
        out.push(start);
        let mut head = begin;
        while head < out.len() {
            let v = out[head];
            head += 1;
            let mut next: Vec<u32> = adjacency[v as usize]
                .iter()
                .copied()
                .filter(|&w| !visited[w as usize])
                .collect();
            next.sort_by_key(|&w| (degree(w), w));
            for w in next {
                visited[w as usize] = true;
                out.push(w);
            }
        }
    };
    let mut visited = vec![false; n];
    let mut sequence: Vec<u32> = Vec::with_capacity(n);
    let mut by_degree: Vec<u32> = (0..n as u32).filter(|&v| active[v as usize]).collect();
    by_degree.sort_by_key(|&v| (degree(v), v));
    for &seed in &by_degree {
        if visited[seed as usize] {
            continue;
        }
        // Find a pseudo-peripheral start within this part.
        let mut probe_visited = visited.clone();
        let mut probe = Vec::new();
        bfs(seed, &mut probe_visited, &mut probe);
        let start = *probe.last().unwrap_or(&seed);
        bfs(start, &mut visited, &mut sequence);
    }
    let mut order = vec![NO_DOF; n];
    let len = sequence.len();
    for (k, &v) in sequence.iter().enumerate() {
        order[v as usize] = (len - 1 - k) as u32;
    }
    order
}

/// A symmetric matrix in profile (skyline) storage, lower triangle by rows, replaced in
/// place by its Cholesky factor L (A = L Lᵀ).
struct ProfileCholesky {
    /// Per row: the first stored column.
    first: Vec<usize>,
    /// Per row: where the row's entries start in `values` (entry (r, c) is at
    /// `start[r] + c − first[r]`).
    start: Vec<usize>,
    values: Vec<f64>,
}

impl ProfileCholesky {
    /// A zero matrix with the given row profile (`first[r] ≤ r`).
    fn zeros(first: Vec<usize>) -> Self {
        let mut start = Vec::with_capacity(first.len() + 1);
        let mut at = 0;
        for (r, &f) in first.iter().enumerate() {
            start.push(at);
            at += r - f + 1;
        }
        start.push(at);
        ProfileCholesky {
            first,
            start,
            values: vec![0.0; at],
        }
    }

    fn n(&self) -> usize {
        self.first.len()
    }

    /// A[row][col] += v for col ≤ row inside the profile.
    fn add(&mut self, row: usize, col: usize, v: f64) {
        debug_assert!(col <= row && col >= self.first[row]);
        self.values[self.start[row] + col - self.first[row]] += v;
    }

    /// Replace A by L (A = L Lᵀ); Err(row) at a non-positive pivot.
    fn factor(&mut self) -> Result<(), usize> {
        let n = self.n();
        for r in 0..n {
            let fr = self.first[r];
            let sr = self.start[r];
            for c in fr..r {
                let fc = self.first[c];
                let sc = self.start[c];
                let k0 = fr.max(fc);
                let mut s = self.values[sr + c - fr];
                let row_r = &self.values[sr + k0 - fr..sr + c - fr];
                let row_c = &self.values[sc + k0 - fc..sc + c - fc];
                for (a, b) in row_r.iter().zip(row_c) {
                    s -= a * b;
                }
                let diag = self.values[sc + c - fc];
                self.values[sr + c - fr] = s / diag;
            }
            let mut d = self.values[sr + r - fr];
            for x in &self.values[sr..sr + r - fr] {
                d -= x * x;
            }
            if !(d > 0.0 && d.is_finite()) {
                return Err(r);
            }
            self.values[sr + r - fr] = d.sqrt();
        }
        Ok(())
    }

    /// b ← A⁻¹ b with the factor.
    fn solve_in_place(&self, b: &mut [f64]) {
        let n = self.n();
        for r in 0..n {
            let (fr, sr) = (self.first[r], self.start[r]);
            let mut s = b[r];
            for (k, x) in self.values[sr..sr + r - fr].iter().enumerate() {
                s -= x * b[fr + k];
            }
            b[r] = s / self.values[sr + r - fr];
        }
        for r in (0..n).rev() {
            let (fr, sr) = (self.first[r], self.start[r]);
            b[r] /= self.values[sr + r - fr];
            let br = b[r];
            for (k, x) in self.values[sr..sr + r - fr].iter().enumerate() {
                b[fr + k] -= x * br;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn profile_cholesky_solves_a_banded_spd_system() {
        // Tridiagonal plus a long-range entry: A = 4 on the diagonal, −1 off it, A[5][1] = 0.5.
        let n = 7;
        let mut first: Vec<usize> = (0..n).map(|r: usize| r.saturating_sub(1)).collect();
        first[5] = 1;
        let mut a = ProfileCholesky::zeros(first);
        let mut dense = vec![0.0; n * n];
        for r in 0..n {
            a.add(r, r, 4.0);
            dense[r * n + r] = 4.0;
            if r > 0 {
                a.add(r, r - 1, -1.0);
                dense[r * n + r - 1] = -1.0;
                dense[(r - 1) * n + r] = -1.0;
            }
        }
        a.add(5, 1, 0.5);
        dense[5 * n + 1] = 0.5;
        dense[n + 5] = 0.5;
        a.factor().unwrap();
        let b: Vec<f64> = (0..n).map(|i| (i as f64 * 0.7).sin() + 1.0).collect();
        let mut x = b.clone();
        a.solve_in_place(&mut x);
        for r in 0..n {
            let ax: f64 = (0..n).map(|c| dense[r * n + c] * x[c]).sum();
            assert!((ax - b[r]).abs() < 1e-12, "row {r}: {ax} vs {}", b[r]);
        }
    }

    #[test]
    fn a_negative_pivot_is_reported() {
        let mut a = ProfileCholesky::zeros(vec![0, 0]);
        a.add(0, 0, 1.0);
        a.add(1, 0, 2.0);
        a.add(1, 1, 1.0);
        assert_eq!(a.factor(), Err(1));
    }

    #[test]
    fn dense_solve_matches() {
        let mut a = vec![4.0, 1.0, 1.0, 3.0];
        let mut b = vec![[1.0, 0.0, 2.0], [0.0, 1.0, 1.0]];
        assert!(dense_cholesky_solve(&mut a, 2, &mut b));
        // A⁻¹ = [3 −1; −1 4]/11
        assert!((b[0][0] - 3.0 / 11.0).abs() < 1e-14);
        assert!((b[1][1] - 4.0 / 11.0).abs() < 1e-14);
        assert!((b[0][2] - 5.0 / 11.0).abs() < 1e-14);
    }

    /// Columns warmed a vertex at a time (a zero budget does one a call) give the same
    /// stiffness as a refresh that solves them all at once, and warming is then done.
    #[test]
    fn columns_warmed_a_few_at_a_time_give_the_same_stiffness() {
        let scene = crate::Scene::load("lv_touch").unwrap();
        let model = Model::from_scene(&scene);
        let tool = scene.tool.as_ref().unwrap();
        // The tool 2 mm into the unloaded epicardium at x = 9.68 mm.
        let centre = DVec3::new(0.00968 + tool.radius - 0.002, 0.0, -0.005);
        let rest = vec![0.0f32; 3 * model.n_vertices()];
        let points = contact_points(&model, &rest, None, centre);
        assert!(points.len() >= 3, "{} contact points", points.len());
        let mut at_once = ContactCompliance::new(&model).unwrap();
        let k_at_once = at_once.stiffness(&points);
        let mut warmed = ContactCompliance::new(&model).unwrap();
        let missing = warmed.missing_columns(&points);
        assert!(missing.len() > 1 && warmed.fits_in_cache(missing.len()));
        for done in 0..missing.len() {
            let left = warmed.missing_columns(&points);
            assert_eq!(left.len(), missing.len() - done);
            assert_eq!(warmed.warm_columns(&left, std::time::Duration::ZERO), 1);
        }
        assert!(warmed.missing_columns(&points).is_empty());
        assert!(at_once.missing_columns(&points).is_empty());
        let k_warmed = warmed.stiffness(&points);
        assert_eq!(k_warmed, k_at_once);
        assert_ne!(k_at_once, DMat3::ZERO);
    }

    #[test]
    fn rcm_orders_every_active_vertex_once() {
        let tets = [[0, 1, 2, 3], [1, 2, 3, 4], [2, 3, 4, 5]];
        let active = [true, true, false, true, true, true];
        let order = reverse_cuthill_mckee(6, &tets, &active);
        assert_eq!(order[2], NO_DOF);
        let mut seen: Vec<u32> = order.iter().copied().filter(|&p| p != NO_DOF).collect();
        seen.sort_unstable();
        assert_eq!(seen, vec![0, 1, 2, 3, 4]);
    }
}
