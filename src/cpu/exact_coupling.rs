//! Design 8 of `docs/hybrid_coupling.md`: the particle–tet coupling whose affine patch test is
//! exact, as a CPU reference (energy and forces of one state). The stepper does not use it
//! yet; it is the twin the coupling stages will be checked against.
//!
//! Every tet keeps its full energy, and every particle p of the stress set S adds the Bregman
//! remainder of its own motion relative to its host tet:
//!
//! ```text
//! E = Σ_t V_t Ψ(F_t) + Σ_{p∈S} V [Ψ(F̄_p + D_p) − Ψ(F̄_p) − P(F̄_p):D_p],
//! δ_q = u_q − Σ_a w_aq u_a        (how far particle q is from its embedded place; 0 unless dynamic),
//! D_p = Σ_{q∈N(p)} (δ_q − δ_p) ⊗ G_pᵀ V ∇W(X_q − X_p),
//! ```
//!
//! F̄_p = I + H̄_p the host tet's gradient, G_p the kernel-gradient correction. Under any affine
//! motion every δ is zero, so D = 0 and the particles add neither energy nor force: the
//! residual is the FEM's at every vertex and zero at every particle, to rounding, across the
//! interface and near the free surface alike. The remainder is ≥ 0 wherever Ψ is convex and
//! its Hessian at D = 0 is V Dᵀ C(F̄) D, so it adds stiffness to the particles' own motion
//! without softening the tets (design 1's flaw was to take energy away from them).
//!
//! Forces (−∂E/∂u), with A_p = [P(F̄_p + D_p) − P(F̄_p)] G_pᵀ:
//!
//! * on a dynamic particle q: f_q = V² Σ_{b∈N(q)} (A_q + A_b) ∇W(X_b − X_q), the tlsph pair
//!   force with the stress difference;
//! * on the hosts of q, through δ_q: −w_aq f_q (so Σ f = 0 exactly, and the layer cannot slide
//!   on its tets: moving a tet's vertices under still particles changes δ);
//! * on the hosts of every p in S, through F̄_p: −V T_p ∇N_a, the tangent term
//!   T_p = P(F̄_p + D_p) − P(F̄_p) − ∂P(F̄_p)\[D_p\] ([`crate::material::elastic_stress_differential`]);
//! * on every vertex, the tets' full FEM forces −V_t P(F_t) ∇N_a.
//!
//! Followers (particles that are not dynamic) have δ ≡ 0 whatever the vertices do, so they
//! take no pair force. The hourglass penalty is the shipped one (a central pair force on every
//! pair with a dynamic particle, zero under affine motion), with F = I + H̄ + D. [`Slaving`]
//! holds the vertices that carry no core mass to their dynamic particles. Not here: the
//! `paper` model (no Ψ; it keeps the partition of unity), contact and gravity (they act on
//! particles and vertices as they do now).

use super::fem_forces::{displacement_gradient, load_dm_inv};
use super::neighbours::NeighbourLists;
use super::sph::kernel_gradient;
use super::{load3, store3};
use crate::material::{ddot, elastic_stress_differential, elastic_stress_energy, MaterialModel};
use crate::model::Model;
use crate::particles::params::ParticleParams;
use crate::particles::Particles;
use glam::{Mat3, Vec3};

/// The static data of the coupling: particle constants, neighbour lists and corrections.
pub struct ExactCoupling {
    /// Particle constants (volume V, kernel).
    pub pp: ParticleParams,
    /// Reference neighbour lists (CSR).
    pub lists: NeighbourLists,
    /// G_p per particle, 9 floats column-major.
    pub correction: Vec<f32>,
    /// The particles (rest places, hosts, weights).
    pub particles: Particles,
    material: MaterialModel,
    lambda: f32,
    mu: f32,
}

/// Energy and forces of one state.
pub struct CoupledForces {
    /// E of the module docs, J.
    pub energy: f64,
    /// Force on each vertex, packed xyz, N.
    pub vertex_forces: Vec<f32>,
    /// Force on each particle, packed xyz, N (zero on those that are not dynamic).
    pub particle_forces: Vec<f32>,
}

/// Why a model cannot take the exact coupling.
#[derive(Debug, PartialEq, Eq)]
pub enum CouplingError {
    /// The model has no particles.
    NoParticles,
    /// The particle model is `paper` (no strain energy to take the remainder of).
    PaperModel,
    /// The material law has no stress differential here (the split laws).
    Material(&'static str),
}

impl std::fmt::Display for CouplingError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CouplingError::NoParticles => write!(f, "the model has no [particles]"),
            CouplingError::PaperModel => {
                write!(
                    f,
                    "particles.model = \"paper\" has no strain energy to couple exactly"
                )
            }
            CouplingError::Material(m) => {
                write!(f, "material.model = \"{m}\" has no stress differential")
            }
        }
    }
}

impl ExactCoupling {
    /// The coupling of `model`'s particles (neighbour lists and corrections as the stepper
    /// builds them). `forces` and `embedded_offsets` take the same model's tets.
    pub fn new(model: &Model) -> Result<ExactCoupling, CouplingError> {
        let p = model.particles.as_ref().ok_or(CouplingError::NoParticles)?;
        let params = model.step_params(model.bounds.dt_bound, 0.0);
        let pp = model
            .particle_params(&params)
            .ok_or(CouplingError::NoParticles)?;
        if pp.model != 0 {
            return Err(CouplingError::PaperModel);
        }
        let material = model.material.model;
        if elastic_stress_differential(material, Mat3::ZERO, Mat3::ZERO, 1.0, 1.0).is_none() {
            return Err(CouplingError::Material(material.name()));
        }
        let (lists, correction) = super::sph_setup::lists_and_corrections(&pp, &p.rest, p.support);
        Ok(ExactCoupling {
            pp,
            lists,
            correction,
            particles: p.clone(),
            material,
            lambda: params.lambda,
            mu: params.mu,
        })
    }

    /// δ_q = u_q − Σ_a w_aq u_a for the dynamic particles, zero for the others (packed xyz).
    pub fn embedded_offsets(
        &self,
        model: &Model,
        dynamic: &[bool],
        vertex_u: &[f32],
        particle_u: &[f32],
    ) -> Vec<f32> {
        let p = &self.particles;
        let mut delta = vec![0.0; particle_u.len()];
        for (q, _) in dynamic.iter().enumerate().filter(|(_, &d)| d) {
            let d = load3(particle_u, q) - p.embed(&model.tets, vertex_u, q);
            store3(&mut delta, q, d);
        }
        delta
    }

    /// S: the dynamic particles and every particle with a dynamic neighbour (D_p ≠ 0 is
    /// possible only there).
    pub fn stress_set(&self, dynamic: &[bool]) -> Vec<bool> {
        let o = &self.lists.neighbour_offsets;
        (0..dynamic.len())
            .map(|p| {
                dynamic[p]
                    || (o[p]..o[p + 1]).any(|k| dynamic[self.lists.neighbours[k as usize] as usize])
            })
            .collect()
    }

    /// D_p = Σ_q (δ_q − δ_p) ⊗ G_pᵀ V ∇W(X_q − X_p).
    fn remainder_gradient(&self, rest: &[f32], delta: &[f32], p: usize) -> Mat3 {
        let pp = &self.pp;
        let (x, dp) = (load3(rest, p), load3(delta, p));
        let mut s = Mat3::ZERO;
        let o = &self.lists.neighbour_offsets;
        for k in o[p]..o[p + 1] {
            let q = self.lists.neighbours[k as usize] as usize;
            let w = kernel_gradient(pp.model, load3(rest, q) - x, pp.spacing, pp.support);
            let d = load3(delta, q) - dp;
            s += Mat3::from_cols(d * w.x, d * w.y, d * w.z) * pp.volume;
        }
        s * load_dm_inv(&self.correction, p)
    }

    /// P(H) and Ψ(H) of the material.
    fn stress(&self, h: Mat3) -> (Mat3, f32) {
        elastic_stress_energy(self.material, h, self.lambda, self.mu)
    }

    /// ∂P(H)[dH] (`new` refused the laws without one).
    fn differential(&self, h: Mat3, dh: Mat3) -> Mat3 {
        elastic_stress_differential(self.material, h, dh, self.lambda, self.mu)
            .unwrap_or(Mat3::ZERO)
    }

    /// The hourglass penalty of `cpu::sph_forces` on every pair with a dynamic particle: on
    /// side c, x_cb h W(r₀)/r₀² [(Σ_sides F_s X_cb)·x_cb / |x_cb|² − sides], h = ½ α E V², the
    /// sum over the pair's particles in S (`f`, their F). A central pair force, zero under any
    /// affine motion; a follower's share goes to its hosts. It is not the gradient of an
    /// energy (as in the shipped model).
    #[allow(clippy::too_many_arguments)]
    fn add_hourglass(
        &self,
        model: &Model,
        dynamic: &[bool],
        vertex_u: &[f32],
        particle_u: &[f32],
        f: &[Option<Mat3>],
        vertex_forces: &mut [f32],
        particle_forces: &mut [f32],
    ) {
        let (parts, pp) = (&self.particles, &self.pp);
        let place = |p: usize| {
            parts.rest_position(p)
                + if dynamic[p] {
                    load3(particle_u, p)
                } else {
                    parts.embed(&model.tets, vertex_u, p)
                }
        };
        let hg = 0.5 * pp.hourglass * pp.youngs * pp.volume * pp.volume;
        let o = &self.lists.neighbour_offsets;
        for c in 0..parts.len() {
            let (x0c, xc) = (parts.rest_position(c), place(c));
            let mut force = Vec3::ZERO;
            for k in o[c]..o[c + 1] {
                let b = self.lists.neighbours[k as usize] as usize;
                if !(dynamic[c] || dynamic[b]) {
                    continue;
                }
                let x0cb = x0c - parts.rest_position(b);
                let xcb = xc - place(b);
                let (r0, r2) = (x0cb.length(), xcb.length_squared());
                if r0 <= 0.0 || r2 <= 0.0 {
                    continue;
                }
                let (mut g, mut sides) = (Vec3::ZERO, 0.0);
                for fs in [f[c], f[b]].into_iter().flatten() {
                    g += fs * x0cb;
                    sides += 1.0;
                }
                let weight = hg * super::sph::wendland(r0, pp.support) / (r0 * r0);
                force += xcb * (weight * (g.dot(xcb) / r2 - sides));
            }
            if dynamic[c] {
                store3(particle_forces, c, load3(particle_forces, c) + force);
            } else {
                let host = model.tets[parts.host[c] as usize];
                for (i, &v) in host.iter().enumerate() {
                    let w = parts.weights[4 * c + i];
                    store3(
                        vertex_forces,
                        v as usize,
                        load3(vertex_forces, v as usize) + force * w,
                    );
                }
            }
        }
    }

    /// Energy and forces of the state with vertex displacements `vertex_u` and particle
    /// displacements `particle_u` (read only for the dynamic particles).
    pub fn forces(
        &self,
        model: &Model,
        dynamic: &[bool],
        vertex_u: &[f32],
        particle_u: &[f32],
    ) -> CoupledForces {
        let parts = &self.particles;
        let n = parts.len();
        let mut vertex_forces = vec![0.0f32; vertex_u.len()];
        let mut particle_forces = vec![0.0f32; 3 * n];
        let mut energy = 0.0f64;
        let add = |f: &mut [f32], i: usize, v: Vec3| store3(f, i, load3(f, i) + v);
        // The tets' full energy.
        let corner_u = |e: usize| model.tets[e].map(|v| load3(vertex_u, v as usize));
        for e in 0..model.n_tets() {
            let dmi = load_dm_inv(&model.dm_inv, e);
            let (p, psi) = self.stress(displacement_gradient(corner_u(e), dmi));
            energy += (model.rest_volume[e] * psi) as f64;
            let fc = super::fem_forces::corner_forces_of_stress(p, dmi, model.rest_volume[e]);
            for (c, &v) in model.tets[e].iter().enumerate() {
                add(&mut vertex_forces, v as usize, fc[c]);
            }
        }
        // The particles' remainders: A_p for the pair forces, T_p to the host tet.
        let delta = self.embedded_offsets(model, dynamic, vertex_u, particle_u);
        let in_s = self.stress_set(dynamic);
        let mut a = vec![Mat3::ZERO; n];
        let v = self.pp.volume;
        for p in (0..n).filter(|&p| in_s[p]) {
            let e = parts.host[p] as usize;
            let dmi = load_dm_inv(&model.dm_inv, e);
            let h_bar = displacement_gradient(corner_u(e), dmi);
            let d = self.remainder_gradient(&parts.rest, &delta, p);
            let (p1, psi1) = self.stress(h_bar + d);
            let (p0, psi0) = self.stress(h_bar);
            let dp = self.differential(h_bar, d);
            energy += (v * (psi1 - psi0 - ddot(p0, d))) as f64;
            a[p] = (p1 - p0) * load_dm_inv(&self.correction, p).transpose();
            let fc = super::fem_forces::corner_forces_of_stress(p1 - p0 - dp, dmi, v);
            for (c, &vx) in model.tets[e].iter().enumerate() {
                add(&mut vertex_forces, vx as usize, fc[c]);
            }
        }
        // The hourglass penalty (the shipped tlsph's, with F = I + H̄ + D on the sides in S).
        if self.pp.hourglass > 0.0 {
            let f_of = |p: usize| {
                let e = parts.host[p] as usize;
                let h_bar = displacement_gradient(corner_u(e), load_dm_inv(&model.dm_inv, e));
                Mat3::IDENTITY + h_bar + self.remainder_gradient(&parts.rest, &delta, p)
            };
            let f: Vec<Option<Mat3>> = (0..n).map(|p| in_s[p].then(|| f_of(p))).collect();
            self.add_hourglass(
                model,
                dynamic,
                vertex_u,
                particle_u,
                &f,
                &mut vertex_forces,
                &mut particle_forces,
            );
        }
        // Pair forces on the dynamic particles and, negated, on their embedded places.
        let o = &self.lists.neighbour_offsets;
        for q in (0..n).filter(|&q| dynamic[q]) {
            let x = load3(&parts.rest, q);
            let mut f = Vec3::ZERO;
            for k in o[q]..o[q + 1] {
                let b = self.lists.neighbours[k as usize] as usize;
                let w = kernel_gradient(
                    self.pp.model,
                    load3(&parts.rest, b) - x,
                    self.pp.spacing,
                    self.pp.support,
                );
                f += (a[q] + a[b]) * w * (v * v);
            }
            add(&mut particle_forces, q, f);
            let host = model.tets[parts.host[q] as usize];
            for (c, &vx) in host.iter().enumerate() {
                add(
                    &mut vertex_forces,
                    vx as usize,
                    -f * parts.weights[4 * q + c],
                );
            }
        }
        CoupledForces {
            energy,
            vertex_forces,
            particle_forces,
        }
    }
}

/// The affine fit's weights s_q of a slaved vertex over its dynamic particles: with weights
/// β_q (wᵢ m_p) and rest offsets d_q = X_q − X_V, s_q = (β_q/B)(1 − (d_q − d̄)·Cov⁻¹ d̄),
/// B = Σ β, d̄ the β-mean and Cov the β-covariance of the offsets. Then Σ s = 1 and
/// Σ s_q X_q = X_V, so x_V = Σ s_q x_q reproduces any affine motion, and the vertex's force
/// goes to the particles as s_q f_V. This is [`super::activate::KinematicFit`]'s velocity as
/// weights (v_V = Σ s_q v_q). None where the offsets do not span three dimensions.
pub fn slave_weights(beta: &[f32], offsets: &[Vec3]) -> Option<Vec<f32>> {
    let b: f64 = beta.iter().map(|&x| x as f64).sum();
    if b <= 0.0 {
        return None;
    }
    let to64 = |v: Vec3| glam::DVec3::new(v.x as f64, v.y as f64, v.z as f64);
    let mean = beta
        .iter()
        .zip(offsets)
        .fold(glam::DVec3::ZERO, |s, (&w, &d)| s + to64(d) * w as f64)
        / b;
    let mut cov = glam::DMat3::ZERO;
    for (&w, &d) in beta.iter().zip(offsets) {
        let c = to64(d) - mean;
        cov += glam::DMat3::from_cols(c * c.x, c * c.y, c * c.z) * (w as f64 / b);
    }
    let scale = (cov.x_axis.x + cov.y_axis.y + cov.z_axis.z) / 3.0;
    // NaN sums fail the first test too.
    let spans = scale > 0.0 && cov.determinant() > 1e-6 * scale * scale * scale;
    if !spans {
        return None;
    }
    let k = cov.inverse() * mean;
    Some(
        beta.iter()
            .zip(offsets)
            .map(|(&w, &d)| ((w as f64 / b) * (1.0 - (to64(d) - mean).dot(k))) as f32)
            .collect(),
    )
}

/// The least share of its full lumped mass (what all its hosted particles give it) a free vertex
/// with no core mass may keep. Its tets keep their full stiffness, so a free vertex's step bound
/// scales with √(its mass): at a half it loses at most a factor √2. Below it, the vertex is
/// slaved.
pub const MIN_FREE_MASS_FRACTION: f64 = 0.5;

/// The largest Σ s_q² · Σ_all w a slaved vertex's fit may have (Σ_all w: its weights over all
/// the particles it hosts). Through the fit its tets' stiffness K lands on its particles as
/// K s sᵀ, whose largest frequency is K Σ s² / m_p against K / (m_p Σ_all w) for the vertex
/// free with all its mass, so this bounds how much the slaving raises that vertex's frequency²
/// (a vertex in the middle of its particles, s ≈ w/Σw, gives Σ w²/Σ w ≤ 1). A fit over too thin
/// a set of dynamic particles exceeds it; then every unpinned particle the vertex hosts is made
/// dynamic and it is fitted over all of them. (Thin fits put a vertex's stiffness on a few
/// particles: on hm1 fits with Σ|s| of 25 blew the run up within a step, 2026-11-25.)
pub const MAX_FIT_STIFFENING: f64 = 4.0;

/// The vertices slaved to the dynamic particles under design 8, and the lumped masses that go
/// with them. A vertex that is not fixed and carries no core mass (it touches only
/// particle-holding zone tets) keeps as mass only its followers' shares, while its tets keep
/// their full stiffness. When those shares fall below [`MIN_FREE_MASS_FRACTION`] of what all
/// its particles would give it, the vertex is slaved: its place is the affine fit of its
/// dynamic particles, x_V = Σ s_q x_q ([`slave_weights`], β = w_Vq m_p), and its force goes to
/// them as s_q f_V (Σ s = 1 and x_V = Σ s_q x_q keep Σ f and Σ x × f). Where that fit is too
/// thin ([`MAX_FIT_STIFFENING`], or offsets that do not span three dimensions), every unpinned
/// particle the vertex hosts is made dynamic first; so is a follower whose four corners all
/// ask to be slaved; repeated until none asks for more.
/// Its followers' mass goes to their other corners, in proportion to their weights. A vertex
/// whose particles' offsets do not span three dimensions even then stays free, with its
/// followers' mass.
#[derive(Clone, Debug)]
pub struct Slaving {
    /// The dynamic set, widened: the given one plus the particles of the vertices it slaves.
    pub dynamic: Vec<bool>,
    /// Per vertex, whether it is slaved.
    pub slaved: Vec<bool>,
    /// Per vertex, its (dynamic particle, s) pairs (empty unless slaved).
    pub fit: Vec<Vec<(u32, f32)>>,
    /// Lumped mass of each vertex, kg (zero on slaved ones).
    pub vertex_mass: Vec<f32>,
}

/// Why a dynamic set cannot be slaved.
#[derive(Debug, PartialEq, Eq)]
pub enum SlavingError {
    /// A vertex with no mass left whose dynamic particles' rest offsets do not span three
    /// dimensions, so it can be neither moved nor placed.
    FlatFit(usize),
    /// A follower whose four corners are all slaved: its mass has nowhere to go (the closure
    /// of the dynamic set prevents it).
    AllCornersSlaved(usize),
}

impl std::fmt::Display for SlavingError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SlavingError::FlatFit(v) => write!(
                f,
                "vertex {v} carries no core mass and its dynamic particles do not span three dimensions (refine particles.spacing or the mesh there)"
            ),
            SlavingError::AllCornersSlaved(q) => {
                write!(f, "particle {q} has all four host corners slaved")
            }
        }
    }
}

impl Slaving {
    /// The slaving of `dynamic` in `model` (`particles` = the model's): the dynamic set is
    /// first widened as the type's doc says; the result's `dynamic` is the widened set.
    pub fn new(
        model: &Model,
        particles: &Particles,
        dynamic: &[bool],
    ) -> Result<Slaving, SlavingError> {
        let nv = model.n_vertices();
        let mut dynamic = dynamic.to_vec();
        // Only a vertex that hosts a dynamic particle can want slaving: the vertex loops skip
        // the others at once (an activation under the tool wakes a few hundred of hm1's
        // 27,751 particles; walking every vertex's slots several times cost 2.5 ms).
        let mut hosts_dynamic = vec![false; nv];
        let wake = |q: usize, dynamic: &mut [bool], hosts_dynamic: &mut [bool]| {
            dynamic[q] = true;
            for &v in &model.tets[particles.host[q] as usize] {
                hosts_dynamic[v as usize] = true;
            }
        };
        for q in 0..particles.len() {
            if dynamic[q] {
                wake(q, &mut dynamic, &mut hosts_dynamic);
            }
        }
        // More dynamic particles only lower the followers' shares: the widening grows to the
        // least set that asks for no more, whatever the order of the vertices.
        loop {
            let mut woke = false;
            for v in 0..nv {
                if !hosts_dynamic[v]
                    || !Self::wants_slaving(model, particles, &dynamic, v)
                    || Self::fit_of(model, particles, &dynamic, v).is_some()
                {
                    continue;
                }
                for q in Self::hosted(particles, v).map(|(q, _)| q) {
                    if !dynamic[q] && !particles.pinned[q] {
                        wake(q, &mut dynamic, &mut hosts_dynamic);
                        woke = true;
                    }
                }
            }
            // A follower whose four corners all want slaving would leave its mass nowhere.
            let wants: Vec<bool> = (0..nv)
                .map(|v| hosts_dynamic[v] && Self::wants_slaving(model, particles, &dynamic, v))
                .collect();
            // (Such a follower is hosted by a vertex that wants slaving: only those vertices'
            // particles are candidates. Waking one changes no other's test.)
            for v in (0..nv).filter(|&v| wants[v]) {
                for q in Self::hosted(particles, v).map(|(q, _)| q) {
                    let t = model.tets[particles.host[q] as usize];
                    if !dynamic[q] && !particles.pinned[q] && t.iter().all(|&c| wants[c as usize]) {
                        wake(q, &mut dynamic, &mut hosts_dynamic);
                        woke = true;
                    }
                }
            }
            if !woke {
                break;
            }
        }
        let (slaved, fit) = Self::fits(model, particles, &dynamic, &hosts_dynamic);
        let mass = Self::lump(model, particles, &dynamic, &slaved, &hosts_dynamic)?;
        if let Some(v) = (0..nv).find(|&v| !slaved[v] && model.inv_mass[v] != 0.0 && mass[v] <= 0.0)
        {
            return Err(SlavingError::FlatFit(v));
        }
        Ok(Slaving {
            dynamic,
            slaved,
            fit,
            vertex_mass: mass.into_iter().map(|m| m as f32).collect(),
        })
    }

    /// The lumped vertex masses, f64: each vertex's core mass plus, over the particles that are
    /// not dynamic, in ascending order, its share of their mass, wₐ / Σ_free w · m over the
    /// host corners that are not slaved ([`Self::share`]). Only the vertices a
    /// dynamic particle's or a slaved vertex's particles reach are summed here (over their own
    /// slots, ascending: the same terms in the same order as a sum over every particle); the
    /// others take [`Particles::follower_lumping`], the sum with nothing dynamic or slaved.
    fn lump(
        model: &Model,
        particles: &Particles,
        dynamic: &[bool],
        slaved: &[bool],
        hosts_dynamic: &[bool],
    ) -> Result<Vec<f64>, SlavingError> {
        let base = particles
            .follower_lumping
            .get_or_init(|| Self::lumped_over_every_particle(model, particles, &[], &[]));
        let mut mass = base.clone();
        let mut reached = hosts_dynamic.to_vec();
        for v in (0..slaved.len()).filter(|&v| slaved[v]) {
            for (q, _) in Self::hosted(particles, v) {
                for &a in &model.tets[particles.host[q] as usize] {
                    reached[a as usize] = true;
                }
            }
        }
        let mut cornered = None::<usize>;
        for v in (0..mass.len()).filter(|&v| reached[v]) {
            mass[v] = particles.core_mass[v] as f64;
            for slot in &particles.slots
                [particles.slot_offsets[v] as usize..particles.slot_offsets[v + 1] as usize]
            {
                let (q, c) = (*slot as usize / 4, *slot as usize % 4);
                if dynamic[q] {
                    continue;
                }
                let free = Self::free_weight(model, particles, slaved, q);
                if free <= 0.0 {
                    cornered = Some(cornered.map_or(q, |k| k.min(q)));
                } else if !slaved[v] {
                    mass[v] += Self::share(particles, q, c, free);
                }
            }
        }
        match cornered {
            Some(q) => Err(SlavingError::AllCornersSlaved(q)),
            None => Ok(mass),
        }
    }

    /// The lumped vertex masses as one sum over every particle that is not dynamic, in
    /// ascending order (`dynamic` and `slaved` empty: none; a particle with no free corner
    /// adds nothing): what a slaving's `vertex_mass` must equal (as f32), bit for bit.
    pub fn lumped_over_every_particle(
        model: &Model,
        particles: &Particles,
        dynamic: &[bool],
        slaved: &[bool],
    ) -> Vec<f64> {
        let mut mass: Vec<f64> = particles.core_mass.iter().map(|&m| m as f64).collect();
        for q in (0..particles.len()).filter(|&q| !dynamic.get(q).copied().unwrap_or(false)) {
            let free = Self::free_weight(model, particles, slaved, q);
            if free <= 0.0 {
                continue;
            }
            for (c, &a) in model.tets[particles.host[q] as usize].iter().enumerate() {
                if !slaved.get(a as usize).copied().unwrap_or(false) {
                    mass[a as usize] += Self::share(particles, q, c, free);
                }
            }
        }
        mass
    }

    /// Σ_free w of particle q: its weights on the host corners that are not slaved (`slaved`
    /// empty: none), in corner order.
    fn free_weight(model: &Model, particles: &Particles, slaved: &[bool], q: usize) -> f64 {
        let t = model.tets[particles.host[q] as usize];
        (0..4)
            .filter(|&k| !slaved.get(t[k] as usize).copied().unwrap_or(false))
            .map(|k| particles.weights[4 * q + k] as f64)
            .sum()
    }

    /// Follower q's mass share on its host's corner c: w_c / Σ_free w · m.
    fn share(particles: &Particles, q: usize, c: usize, free: f64) -> f64 {
        particles.weights[4 * q + c] as f64 / free * particles.mass as f64
    }

    /// Vertex v's hosted particles and their weights on it.
    fn hosted(particles: &Particles, v: usize) -> impl Iterator<Item = (usize, f32)> + '_ {
        let slots = &particles.slots
            [particles.slot_offsets[v] as usize..particles.slot_offsets[v + 1] as usize];
        slots
            .iter()
            .map(|&slot| (slot as usize / 4, particles.weights[slot as usize]))
    }

    /// Whether vertex v, under `dynamic`, is not fixed, has no core mass, hosts a dynamic
    /// particle and keeps less than [`MIN_FREE_MASS_FRACTION`] of its hosted weight on
    /// followers.
    fn wants_slaving(model: &Model, particles: &Particles, dynamic: &[bool], v: usize) -> bool {
        if model.inv_mass[v] == 0.0 || particles.core_mass[v] != 0.0 {
            return false;
        }
        let (mut all, mut followers) = (0.0f64, 0.0f64);
        for (q, w) in Self::hosted(particles, v) {
            all += w as f64;
            if !dynamic[q] {
                followers += w as f64;
            }
        }
        followers < all && followers < MIN_FREE_MASS_FRACTION * all
    }

    /// Vertex v's affine fit over its dynamic particles, (q, s_q); None when their offsets do
    /// not span three dimensions or the fit exceeds [`MAX_FIT_STIFFENING`].
    fn fit_of(
        model: &Model,
        particles: &Particles,
        dynamic: &[bool],
        v: usize,
    ) -> Option<Vec<(u32, f32)>> {
        let all: f64 = Self::hosted(particles, v).map(|(_, w)| w as f64).sum();
        let f = Self::full_fit(model, particles, dynamic, v)?;
        let stiffening = all * f.iter().map(|&(_, s)| (s as f64).powi(2)).sum::<f64>();
        (stiffening <= MAX_FIT_STIFFENING).then_some(f)
    }

    /// Vertex v's affine fit over its dynamic particles, however thin (None when their
    /// offsets do not span three dimensions).
    fn full_fit(
        model: &Model,
        particles: &Particles,
        dynamic: &[bool],
        v: usize,
    ) -> Option<Vec<(u32, f32)>> {
        let hosted: Vec<(usize, f32)> = Self::hosted(particles, v)
            .filter(|&(q, _)| dynamic[q])
            .collect();
        let x_v = load3(&model.rest, v);
        let beta: Vec<f32> = hosted.iter().map(|&(_, w)| w * particles.mass).collect();
        let offsets: Vec<Vec3> = hosted
            .iter()
            .map(|&(q, _)| (particles.rest_position(q) - x_v) / particles.settings.spacing as f32)
            .collect();
        let s = slave_weights(&beta, &offsets)?;
        Some(
            hosted
                .iter()
                .zip(s)
                .map(|(&(q, _), s)| (q as u32, s))
                .collect(),
        )
    }

    /// Which vertices `dynamic` (already widened) slaves ([`Self::wants_slaving`], offsets that
    /// span three dimensions) and their fits over their dynamic particles; only the vertices
    /// `hosts_dynamic` marks (those hosting a dynamic particle) can be.
    fn fits(
        model: &Model,
        particles: &Particles,
        dynamic: &[bool],
        hosts_dynamic: &[bool],
    ) -> (Vec<bool>, Vec<Vec<(u32, f32)>>) {
        let nv = model.n_vertices();
        let mut slaved = vec![false; nv];
        let mut fit = vec![Vec::new(); nv];
        for v in (0..nv)
            .filter(|&v| hosts_dynamic[v] && Self::wants_slaving(model, particles, dynamic, v))
        {
            // Too few particles to place it even all awake: it keeps its place and its
            // followers' mass.
            if let Some(f) = Self::fit_of(model, particles, dynamic, v)
                .or_else(|| Self::full_fit(model, particles, dynamic, v))
            {
                slaved[v] = true;
                fit[v] = f;
            }
        }
        (slaved, fit)
    }

    /// Pass each slaved vertex's force to its particles (f_q += s_q f_V) and zero it.
    pub fn transfer_forces(&self, vertex_forces: &mut [f32], particle_forces: &mut [f32]) {
        for (v, fit) in self.fit.iter().enumerate().filter(|(v, _)| self.slaved[*v]) {
            let f = load3(vertex_forces, v);
            for &(q, s) in fit {
                let q = q as usize;
                store3(particle_forces, q, load3(particle_forces, q) + f * s);
            }
            store3(vertex_forces, v, Vec3::ZERO);
        }
    }

    /// Set each slaved vertex's value (displacement or velocity) from its particles':
    /// a_V = Σ s_q a_q.
    pub fn place(&self, vertex_values: &mut [f32], particle_values: &[f32]) {
        for (v, fit) in self.fit.iter().enumerate().filter(|(v, _)| self.slaved[*v]) {
            let a = fit.iter().fold(Vec3::ZERO, |a, &(q, s)| {
                a + load3(particle_values, q as usize) * s
            });
            store3(vertex_values, v, a);
        }
    }
}
