//! Inverted elements in a state: tets and particles that carry strain energy and whose
//! deformation gradient F has det F ≤ 0. StVK does not push them back (its energy depends
//! on FᵀF, which a reflection leaves unchanged: an inverted element is pushed towards the
//! mirror image of its rest shape), so a run that ends with some has, in that place, a force
//! the material would not give; `summary.json` reports the counts and the CLI warns.

use crate::cpu::fem_forces::load_dm_inv;
use crate::cpu::{load3, neighbours, sph_setup};
use crate::model::Model;
use crate::particles::params::{mode, GridParams, ParticleParams};
use crate::stepper::{ParticleSnapshot, State};
use glam::Mat3;

/// How many elements of a state are inverted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Inverted {
    /// Tets with det(I + H_t) ≤ 0, H_t = [u₁ − u₀, u₂ − u₀, u₃ − u₀] Dm⁻¹, among those
    /// whose energy weight is not 0 (a zone tet whose particles all carry SPH stress has no
    /// energy of its own, and its vertices may be kinematic).
    pub tets: usize,
    /// Particles that carry SPH stress (dynamic, or in the stress set around them) with
    /// det(I + H_p) ≤ 0, H_p = Σ_b V (u_b − u_p) ⊗ ∇W_pb G_p (the corrected SPH gradient of
    /// `sph_stress`, embedded neighbours where their host puts them); particles whose
    /// correction is singular are not counted.
    pub particles: usize,
}

/// Tets of `model` inverted at `state` (every tet: see [`inverted`] for the weighted ones).
pub fn inverted_tets(model: &Model, state: &State) -> usize {
    (0..model.n_tets())
        .filter(|&e| tet_inverted(model, state, e))
        .count()
}

/// det(I + H_t) ≤ 0 for tet e.
fn tet_inverted(model: &Model, state: &State, e: usize) -> bool {
    let u = model.tets[e].map(|i| load3(&state.displacements, i as usize));
    let h = Mat3::from_cols(u[1] - u[0], u[2] - u[0], u[3] - u[0]) * load_dm_inv(&model.dm_inv, e);
    (Mat3::IDENTITY + h).determinant() <= 0.0
}

/// Particles carrying SPH stress inverted at (`state`, `snap`); 0 without particles. Builds the
/// reference neighbour lists on the CPU (a one-off cost at the end of a run).
pub fn inverted_particles(model: &Model, state: &State, snap: &ParticleSnapshot) -> usize {
    let Some(p) = &model.particles else {
        return 0;
    };
    let stressed: Vec<usize> = (0..p.len())
        .filter(|&k| {
            snap.modes
                .get(k)
                .is_some_and(|m| m & (mode::DYNAMIC | mode::IN_S) != 0)
        })
        .collect();
    if stressed.is_empty() {
        return 0;
    }
    let pp = ParticleParams {
        n_particles: p.len() as u32,
        model: p.settings.model.index(),
        volume: p.volume,
        spacing: p.settings.spacing as f32,
        support: p.support,
        ..Default::default()
    };
    let lists = neighbours::build(&GridParams::over(&p.rest, p.support), &p.rest);
    let u = crate::output::particles::particle_displacements(model, state, snap);
    let (offsets, nb) = (&lists.neighbour_offsets, &lists.neighbours);
    stressed
        .into_iter()
        .filter(|&k| {
            let g = sph_setup::correction(&pp, &p.rest, offsets, nb, k);
            if g == Mat3::ZERO {
                return false;
            }
            let h = sph_setup::gradient_sum(&pp, &p.rest, &u, offsets, nb, None, k) * g;
            (Mat3::IDENTITY + h).determinant() <= 0.0
        })
        .count()
}

/// Both counts: the tets of [`inverted_tets`] whose energy weight
/// ([`crate::cpu::activate::tet_weight_of`]) is not 0, and [`inverted_particles`].
pub fn inverted(model: &Model, state: &State, snap: Option<&ParticleSnapshot>) -> Inverted {
    let weighted = |e: usize| match (&model.particles, snap) {
        (Some(p), Some(s)) => {
            crate::cpu::activate::tet_weight_of(e, &p.tet_offsets, &s.modes) > 0.0
        }
        _ => true,
    };
    Inverted {
        tets: (0..model.n_tets())
            .filter(|&e| weighted(e) && tet_inverted(model, state, e))
            .count(),
        particles: snap.map_or(0, |s| inverted_particles(model, state, s)),
    }
}
