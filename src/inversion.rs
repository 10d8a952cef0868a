//! Inverted elements in a state: tets and dynamic particles whose deformation gradient F has
//! det F ≤ 0. StVK has no restoring force for them (its energy depends on FᵀF, which a
//! reflection leaves unchanged), so a run that ends with some has, in that place, a force the
//! material would not give; `summary.json` reports the counts and the CLI warns.

use crate::cpu::fem_forces::load_dm_inv;
use crate::cpu::{load3, neighbours, sph_setup};
use crate::model::Model;
use crate::particles::params::{mode, GridParams, ParticleParams};
use crate::stepper::{ParticleSnapshot, State};
use glam::Mat3;

/// How many elements of a state are inverted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Inverted {
    /// Tets with det(I + H_t) ≤ 0, H_t = [u₁ − u₀, u₂ − u₀, u₃ − u₀] Dm⁻¹.
    pub tets: usize,
    /// Dynamic particles with det(I + H_p) ≤ 0, H_p = Σ_b V (u_b − u_p) ⊗ ∇W_pb G_p (the
    /// corrected SPH gradient of `sph_stress`, embedded neighbours where their host puts
    /// them); particles whose correction is singular are not counted.
    pub particles: usize,
}

/// Tets of `model` inverted at `state`.
pub fn inverted_tets(model: &Model, state: &State) -> usize {
    (0..model.n_tets())
        .filter(|&e| {
            let t = model.tets[e];
            let u = t.map(|i| load3(&state.displacements, i as usize));
            let h = Mat3::from_cols(u[1] - u[0], u[2] - u[0], u[3] - u[0])
                * load_dm_inv(&model.dm_inv, e);
            (Mat3::IDENTITY + h).determinant() <= 0.0
        })
        .count()
}

/// Dynamic particles inverted at (`state`, `snap`); 0 without particles. Builds the
/// reference neighbour lists on the CPU (a one-off cost at the end of a run).
pub fn inverted_particles(model: &Model, state: &State, snap: &ParticleSnapshot) -> usize {
    let Some(p) = &model.particles else {
        return 0;
    };
    let dynamic: Vec<usize> = (0..p.len())
        .filter(|&k| snap.modes.get(k).is_some_and(|m| m & mode::DYNAMIC != 0))
        .collect();
    if dynamic.is_empty() {
        return 0;
    }
    let pp = ParticleParams {
        n_particles: p.len() as u32,
        model: match p.settings.model {
            crate::scene::ParticleModel::Tlsph => 0,
            crate::scene::ParticleModel::Paper => 1,
        },
        volume: p.volume,
        spacing: p.settings.spacing as f32,
        support: p.support,
        ..Default::default()
    };
    let lists = neighbours::build(&GridParams::over(&p.rest, p.support), &p.rest);
    let u = crate::output::particles::particle_displacements(model, state, snap);
    let (offsets, nb) = (&lists.neighbour_offsets, &lists.neighbours);
    dynamic
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

/// Both counts ([`inverted_tets`], [`inverted_particles`]).
pub fn inverted(model: &Model, state: &State, snap: Option<&ParticleSnapshot>) -> Inverted {
    Inverted {
        tets: inverted_tets(model, state),
        particles: snap.map_or(0, |s| inverted_particles(model, state, s)),
    }
}
