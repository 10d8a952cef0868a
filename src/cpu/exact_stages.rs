//! The CPU stages of design 8 (`particles.coupling = "exact"`; the energy and its forces are
//! in [`super::exact_coupling`], which is these stages' reference): what the stepper runs in
//! place of the energy blend's `sph_stress`, `sph_forces`, `gather_coupled` and
//! `integrate_particles` (the plan's `ExactStress`, `ExactForces`, `ExactGather`,
//! `ExactIntegrate`); an activation under it is `cpu/exact_activation.rs`. Their kernels:
//! `exact_stress.wgsl`, `exact_forces.wgsl`, `gather.wgsl::gather_exact`,
//! `exact_slaving.wgsl` (under the tool the GPU backend runs each activation on a CPU twin
//! of the stepper and takes back what changed).
//!
//! One step: δ_q = u_q − Σ wₐ_q uₐ per dynamic particle; per particle p of S, A_p =
//! [P(F̄_p + D_p) − P(F̄_p)] G_pᵀ, F_p = I + H̄_p + D_p, the remainder energy and the tangent
//! term's corner forces on p's host tet; per particle of the force set, the pair force (dynamic
//! only) and the hourglass penalty, with −f_pair (dynamic) or the hourglass share (follower)
//! passed to the hosts through the weights; per vertex, the tets' full forces plus the slots'
//! host forces and tangent forces; then each slaved vertex's force goes to its particles
//! (f_q += s_q f_V), vertices and dynamic particles step, and slaved vertices take their
//! particles' fitted displacement and velocity.

use super::exact_activation::{ReslaveCounts, SlaveOffsets};
use super::exact_coupling::Slaving;
use super::fem_forces::{corner_forces_of_stress, displacement_gradient, load_dm_inv};
use super::sph_forces::{add_external, pair_terms, ForceInputs, Side};
use super::{load3, store3};
use crate::material::{ddot, elastic_stress_differential, elastic_stress_energy, MaterialModel};
use crate::model::Model;
use crate::particles::params::{mode, ParticleParams};
use crate::particles::Particles;
use glam::{Mat3, Vec3, Vec3A};
use rayon::prelude::*;

/// Design 8's per-run arrays.
#[derive(Clone)]
pub(crate) struct ExactArrays {
    /// The slaved vertices, their fits and the vertex masses: the model's at the start, then
    /// the last activation's (`cpu/exact_activation.rs`).
    pub slaving: Slaving,
    /// The slaved vertices' fading offsets.
    pub offsets: SlaveOffsets,
    /// The particles whose δ the stress stage computes: the dynamic ones, then those of the
    /// stress set still blending back onto their host (set by each activation).
    pub delta_list: Vec<u32>,
    /// What the activations so far changed.
    pub counts: ReslaveCounts,
    /// The dynamic set the mode machine asked for at the last activation (before the
    /// closure; empty before the first): the slaving's source.
    pub asked: Vec<bool>,
    /// Per particle, its DYNAMIC and BLENDING bits after the last activation (empty before
    /// the first): when they and the slaving are unchanged, so are the sets and lists.
    pub moving: Vec<u8>,
    /// Why an activation could not slave its dynamic set (the run stops with it).
    pub failure: Option<String>,
    /// δ per particle (zero unless dynamic), packed xyz, m.
    pub delta: Vec<f32>,
    /// Per particle, the force its hosts take through its barycentric weights, N: minus its
    /// pair force when dynamic, its hourglass force when a follower (zero outside the force
    /// set).
    pub host_force: Vec<f32>,
    /// Per vertex, the slots of the force set's particles ([`force_set_slots`]): CSR offsets
    /// and slots, rebuilt at each activation (empty before the first: nothing is in F).
    pub gather_slots: (Vec<u32>, Vec<u32>),
    /// Per slot p·4 + corner, the tangent term's force on that corner of p's host tet, packed
    /// xyz, N (zero outside S).
    pub tangent: Vec<f32>,
    /// The particles the last activation that changed the sets took out of S, whose tangent
    /// forces it zeroed (what a GPU stepper's CPU twin has it zero too).
    pub left_stress: Vec<u32>,
}

impl ExactArrays {
    /// Save into `into` what a checkpoint keeps: everything but the per-step arrays (δ, the
    /// hosts' forces, the tangent forces), which `into` holds empty. Reuses `into`'s buffers.
    pub fn save_into(&self, into: &mut ExactArrays) {
        let (s, d) = (&self.slaving, &mut into.slaving);
        d.dynamic.clone_from(&s.dynamic);
        d.slaved.clone_from(&s.slaved);
        d.fit.clone_from(&s.fit);
        d.vertex_mass.clone_from(&s.vertex_mass);
        into.offsets.offset.clone_from(&self.offsets.offset);
        into.offsets.timer.clone_from(&self.offsets.timer);
        into.delta_list.clone_from(&self.delta_list);
        into.counts = self.counts;
        into.failure.clone_from(&self.failure);
        into.asked.clone_from(&self.asked);
        into.moving.clone_from(&self.moving);
        into.gather_slots.0.clone_from(&self.gather_slots.0);
        into.gather_slots.1.clone_from(&self.gather_slots.1);
        for a in [&mut into.delta, &mut into.host_force, &mut into.tangent] {
            a.clear();
        }
        into.left_stress.clear();
    }

    /// Take back what [`Self::save_into`] kept; the per-step arrays become zero, which is
    /// what they hold where they are read before a step writes them: δ outside the δ list,
    /// and the tangent forces outside S (an activation zeroes those of the particles leaving
    /// S). The next step writes the rest before reading it.
    pub fn restore_from(&mut self, saved: &ExactArrays) {
        let (n_delta, n_tangent) = (self.delta.len(), self.tangent.len());
        let (mut delta, mut host, mut tangent) = (
            std::mem::take(&mut self.delta),
            std::mem::take(&mut self.host_force),
            std::mem::take(&mut self.tangent),
        );
        saved.save_into(self);
        for (a, len) in [
            (&mut delta, n_delta),
            (&mut host, n_delta),
            (&mut tangent, n_tangent),
        ] {
            a.clear();
            a.resize(len, 0.0);
        }
        (self.delta, self.host_force, self.tangent) = (delta, host, tangent);
    }

    /// The arrays of `model` (None unless it has the exact coupling).
    pub fn new(model: &Model) -> Option<ExactArrays> {
        let slaving = Slaving::clone(model.slaving.as_ref()?);
        let n = model.particles.as_ref()?.len();
        Some(ExactArrays {
            offsets: SlaveOffsets::new(model.n_vertices()),
            delta_list: Vec::new(),
            counts: ReslaveCounts::default(),
            asked: Vec::new(),
            moving: Vec::new(),
            failure: None,
            slaving,
            delta: vec![0.0; 3 * n],
            host_force: vec![0.0; 3 * n],
            gather_slots: (vec![0; model.n_vertices() + 1], Vec::new()),
            tangent: vec![0.0; 12 * n],
            left_stress: Vec::new(),
        })
    }
}

/// δ_q = u_q − Σ wₐ_q uₐ for each particle q of `dynamic_list` (the dynamic particles, then
/// those of the stress set still blending back onto their host, which `follow` has placed);
/// the others keep theirs (0: an activation clears them).
pub(crate) fn embedded_offsets(
    model: &Model,
    pd: &Particles,
    dynamic_list: &[u32],
    vertex_u: &[f32],
    particle_u: &[f32],
    delta: &mut [f32],
) {
    let d: Vec<Vec3> = dynamic_list
        .par_iter()
        .with_min_len(256)
        .map(|&q| load3(particle_u, q as usize) - pd.embed(&model.tets, vertex_u, q as usize))
        .collect();
    for (&q, d) in dynamic_list.iter().zip(d) {
        store3(delta, q as usize, d);
    }
}

/// What [`exact_stress`] reads.
pub(crate) struct StressInputs<'a> {
    /// The model (tets, their inverse rest edge matrices).
    pub model: &'a Model,
    /// The particles (rest places, hosts).
    pub pd: &'a Particles,
    /// Particle constants.
    pub pp: &'a ParticleParams,
    /// The material law and its Lamé constants, Pa.
    pub material: (MaterialModel, f32, f32),
    /// Neighbour CSR offsets and lists.
    pub lists: (&'a [u32], &'a [u32]),
    /// Rest-state kernel gradients per slot.
    pub pairs: &'a super::sph::PairTable,
    /// G_p per particle (9 floats).
    pub correction: &'a [f32],
    /// δ per particle.
    pub delta: &'a [f32],
    /// Vertex displacements, m.
    pub vertex_u: &'a [f32],
}

/// Per particle p of `stress_list`: `stress` ← A_p = [P(F̄ + D) − P(F̄)] G_pᵀ, `gradient` ←
/// H̄_p + D_p, `energy` ← V [Ψ(F̄ + D) − Ψ(F̄) − P(F̄):D], and its host tet's four corner
/// forces of the tangent term T = P(F̄ + D) − P(F̄) − ∂P(F̄)[D] into `tangent` (slots 4p..4p+4):
/// −V T ∇Nₐ, F̄ = I + H̄ the host tet's gradient, D_p = Σ_q (δ_q − δ_p) ⊗ G_pᵀ V ∇W.
pub(crate) fn exact_stress(
    inp: &StressInputs,
    stress_list: &[u32],
    stress: &mut [f32],
    gradient: &mut [f32],
    energy: &mut [f32],
    tangent: &mut [f32],
) {
    let (m, pp) = (inp.model, inp.pp);
    let (law, lambda, mu) = inp.material;
    let v = pp.volume;
    let results: Vec<(Mat3, Mat3, f32, [Vec3; 4])> = stress_list
        .par_iter()
        .with_min_len(64)
        .map(|&p| {
            let p = p as usize;
            let e = inp.pd.host[p] as usize;
            let dmi = load_dm_inv(&m.dm_inv, e);
            let corner_u = m.tets[e].map(|a| load3(inp.vertex_u, a as usize));
            let h_bar = displacement_gradient(corner_u, dmi);
            let g = load_dm_inv(inp.correction, p);
            let d = super::sph_setup::gradient_sum(
                pp,
                &inp.pd.rest,
                inp.delta,
                inp.lists.0,
                inp.lists.1,
                Some(inp.pairs),
                p,
            ) * g;
            let (p1, psi1) = elastic_stress_energy(law, h_bar + d, lambda, mu);
            let (p0, psi0) = elastic_stress_energy(law, h_bar, lambda, mu);
            let dp = elastic_stress_differential(law, h_bar, d, lambda, mu).unwrap_or(Mat3::ZERO);
            let corners = corner_forces_of_stress(p1 - p0 - dp, dmi, v);
            (
                (p1 - p0) * g.transpose(),
                h_bar + d,
                v * (psi1 - psi0 - ddot(p0, d)),
                corners,
            )
        })
        .collect();
    for (&p, (a, h, psi, corners)) in stress_list.iter().zip(results) {
        let p = p as usize;
        stress[9 * p..9 * p + 9].copy_from_slice(&a.to_cols_array());
        gradient[9 * p..9 * p + 9].copy_from_slice(&h.to_cols_array());
        energy[p] = psi;
        for (c, f) in corners.into_iter().enumerate() {
            store3(tangent, 4 * p + c, f);
        }
    }
}

/// Per particle c of `force_list`: its pair terms split as design 8 takes them. A dynamic
/// particle gets the pair force V² Σ (A_c + A_b)∇W, the hourglass penalty, gravity and the
/// tool's contact (`forces`, `contact`), and its hosts −(pair force) (`host_force`); a follower
/// gets no pair force (its δ is 0 whatever its hosts do) and passes its hourglass share to its
/// hosts.
pub fn exact_forces(
    inp: &ForceInputs,
    force_list: &[u32],
    forces: &mut [f32],
    contact: &mut [f32],
    host_force: &mut [f32],
) {
    let results: Vec<(Vec3, Vec3, Vec3)> = force_list
        .par_iter()
        .with_min_len(64)
        .map(|&c| {
            let c = c as usize;
            let side = Side::of(inp, c);
            let (mut pair, mut hourglass) = (Vec3A::ZERO, Vec3A::ZERO);
            for k in inp.neighbour_offsets[c]..inp.neighbour_offsets[c + 1] {
                if let Some((s, h)) = pair_terms(inp, k as usize, &side) {
                    pair += s;
                    hourglass += h.unwrap_or(Vec3A::ZERO);
                }
            }
            if inp.mode[c] & mode::DYNAMIC != 0 {
                let mut f = Vec3::from(pair + hourglass);
                let touch = add_external(inp, c, (side.u, side.f), &mut f);
                (f, touch, -Vec3::from(pair))
            } else {
                let h = Vec3::from(hourglass);
                (h, Vec3::ZERO, h)
            }
        })
        .collect();
    for (&c, (f, touch, host)) in force_list.iter().zip(results) {
        let c = c as usize;
        store3(forces, c, f);
        store3(contact, c, touch);
        store3(host_force, c, host);
    }
}

/// Per vertex, the slots (p·4 + corner, in CSR order) whose particle p is in the force set F
/// (which holds S): the only slots whose host force or tangent force the exact stages write.
/// Rebuilt at each activation into `offsets` (n_vertices + 1) and `slots`, so the gather walks
/// a few thousand slots instead of every one, and a particle that has left F or S adds nothing
/// (its last host or tangent force stays in the arrays, unread). Only the corners of the
/// force list's host tets can hold such a slot: the others' lists are not walked.
pub(crate) fn force_set_slots(
    model: &Model,
    pd: &Particles,
    (force_list, particle_mode): (&[u32], &[u32]),
    slots: &mut (Vec<u32>, Vec<u32>),
) {
    let nv = pd.slot_offsets.len() - 1;
    let mut hosts = vec![false; nv];
    for &p in force_list {
        for &v in &model.tets[pd.host[p as usize] as usize] {
            hosts[v as usize] = true;
        }
    }
    let (offsets, list) = slots;
    offsets.clear();
    list.clear();
    offsets.push(0);
    for (v, &host) in hosts.iter().enumerate() {
        if host {
            let range = pd.slot_offsets[v] as usize..pd.slot_offsets[v + 1] as usize;
            list.extend(
                pd.slots[range]
                    .iter()
                    .filter(|&&slot| particle_mode[slot as usize / 4] & mode::IN_F != 0),
            );
        }
        offsets.push(list.len() as u32);
    }
}

/// What [`exact_gather`] adds to the core's gather at vertex i.
pub(crate) struct ExactGather<'a> {
    /// Per vertex, its surface index (tool scenes; empty otherwise).
    pub surface_index: &'a [u32],
    /// Contact force per surface vertex (read when `surface_index` is not empty).
    pub contact_forces: &'a [f32],
    /// CSR vertex → the slots p·4 + corner of the force set's particles
    /// ([`force_set_slots`]).
    pub slots: (&'a [u32], &'a [u32]),
    /// Barycentric weights, 4 per particle.
    pub weights: &'a [f32],
    /// Per particle, the force its hosts take through its weights.
    pub host_force: &'a [f32],
    /// Per slot, the tangent term's corner force.
    pub tangent: &'a [f32],
}

/// Per vertex i: f = mᵢ g + f_ext + Σ incident corner forces + the tool's contact (the
/// blend's `gather_coupled` without its particle term), then + Σ over its slots (p, a) of
/// [w_ap host_force_p + tangent_(p,a)].
#[allow(clippy::too_many_arguments)]
pub(crate) fn exact_gather(
    params: &crate::params::StepParams,
    corner_forces: &[f32],
    incidence: (&[u32], &[u32]),
    mass: &[f32],
    external_forces: &[f32],
    c: &ExactGather,
    forces: &mut [f32],
) {
    super::gather::gather_coupled(
        params,
        corner_forces,
        incidence.0,
        incidence.1,
        mass,
        external_forces,
        forces,
        &super::gather::Coupling {
            surface_index: c.surface_index,
            contact_forces: c.contact_forces,
            contact: !c.surface_index.is_empty(),
            node_flags: &[],
            slot_offsets: &[],
            slots: &[],
            weights: &[],
            mode: &[],
            force_sum: &[],
            particles: false,
        },
    );
    super::par::for_each_chunk::<3>(forces, params.n_vertices as usize, |i, out| {
        let mut f = load3(out, 0);
        for k in c.slots.0[i]..c.slots.0[i + 1] {
            let slot = c.slots.1[k as usize] as usize;
            f += load3(c.host_force, slot / 4) * c.weights[slot] + load3(c.tangent, slot);
        }
        store3(out, 0, f);
    });
}
