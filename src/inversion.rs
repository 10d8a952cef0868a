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

/// What counting inverted particles needs from the rest state, built once: the reference
/// neighbour lists and each particle's kernel correction (both constant in a total-Lagrangian
/// model), so that a count during a session costs only the stressed particles' gradient sums.
pub struct InversionProbe {
    pp: ParticleParams,
    offsets: Vec<u32>,
    neighbours: Vec<u32>,
    /// Per particle, the correction G_p (zero where it is singular).
    corrections: Vec<Mat3>,
}

impl InversionProbe {
    /// The probe for `model` (None without particles). Builds the neighbour lists on the CPU.
    pub fn new(model: &Model) -> Option<InversionProbe> {
        let p = model.particles.as_ref()?;
        let pp = ParticleParams {
            n_particles: p.len() as u32,
            model: p.settings.model.index(),
            volume: p.volume,
            spacing: p.settings.spacing as f32,
            support: p.support,
            ..Default::default()
        };
        let lists = neighbours::build(&GridParams::over(&p.rest, p.support), &p.rest);
        let corrections = (0..p.len())
            .map(|k| {
                sph_setup::correction(&pp, &p.rest, &lists.neighbour_offsets, &lists.neighbours, k)
            })
            .collect();
        Some(InversionProbe {
            pp,
            offsets: lists.neighbour_offsets,
            neighbours: lists.neighbours,
            corrections,
        })
    }

    /// Particles carrying SPH stress (dynamic or in S) with det(I + H_p) ≤ 0 at (`state`,
    /// `snap`), H_p as in [`Inverted::particles`].
    pub fn inverted_particles(
        &self,
        model: &Model,
        state: &State,
        snap: &ParticleSnapshot,
    ) -> usize {
        let Some(p) = &model.particles else {
            return 0;
        };
        let stressed: Vec<usize> = (0..p.len())
            .filter(|&k| {
                snap.modes
                    .get(k)
                    .is_some_and(|m| m & (mode::DYNAMIC | mode::IN_S) != 0)
                    && self.corrections[k] != Mat3::ZERO
            })
            .collect();
        if stressed.is_empty() {
            return 0;
        }
        let u = crate::output::particles::particle_displacements(model, state, snap);
        stressed
            .into_iter()
            .filter(|&k| {
                let h = sph_setup::gradient_sum(
                    &self.pp,
                    &p.rest,
                    &u,
                    &self.offsets,
                    &self.neighbours,
                    None,
                    k,
                ) * self.corrections[k];
                (Mat3::IDENTITY + h).determinant() <= 0.0
            })
            .count()
    }

    /// Both counts, as [`inverted`] gives them.
    pub fn inverted(
        &self,
        model: &Model,
        state: &State,
        snap: Option<&ParticleSnapshot>,
    ) -> Inverted {
        Inverted {
            tets: weighted_inverted_tets(model, state, snap),
            particles: snap.map_or(0, |s| self.inverted_particles(model, state, s)),
        }
    }
}

/// Particles carrying SPH stress inverted at (`state`, `snap`); 0 without particles. Builds the
/// reference neighbour lists on the CPU (a one-off cost at the end of a run; a session that
/// counts often keeps an [`InversionProbe`]).
pub fn inverted_particles(model: &Model, state: &State, snap: &ParticleSnapshot) -> usize {
    let stressed = |m: &u32| m & (mode::DYNAMIC | mode::IN_S) != 0;
    if !snap.modes.iter().any(stressed) {
        return 0;
    }
    InversionProbe::new(model).map_or(0, |probe| probe.inverted_particles(model, state, snap))
}

/// Tets of [`inverted_tets`] whose energy weight ([`crate::cpu::activate::tet_weight_of`]) is
/// not 0 (every tet without particles).
fn weighted_inverted_tets(model: &Model, state: &State, snap: Option<&ParticleSnapshot>) -> usize {
    let weighted = |e: usize| match (&model.particles, snap) {
        (Some(p), Some(s)) => {
            crate::cpu::activate::tet_weight_of(e, &p.tet_offsets, &s.modes) > 0.0
        }
        _ => true,
    };
    (0..model.n_tets())
        .filter(|&e| weighted(e) && tet_inverted(model, state, e))
        .count()
}

/// Both counts: the tets of [`inverted_tets`] whose energy weight
/// ([`crate::cpu::activate::tet_weight_of`]) is not 0, and [`inverted_particles`].
pub fn inverted(model: &Model, state: &State, snap: Option<&ParticleSnapshot>) -> Inverted {
    Inverted {
        tets: weighted_inverted_tets(model, state, snap),
        particles: snap.map_or(0, |s| inverted_particles(model, state, s)),
    }
}
