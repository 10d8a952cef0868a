//! CPU twin of `kernels/sph_stress.wgsl`: per particle of the stress set, H_p, the material's
//! P (tlsph) or the paper's eq. (1)–(2) stress (paper), plus for a viscous material the
//! strain-rate stress F·S_v of eq. (3)–(4) from the particles' velocities (as the element
//! forces add it), A_p = P G_pᵀ and V Ψ (elastic).

use super::fem_forces::{load_dm_inv, viscous_stress};
use super::sph_setup::{gradient_sum, gradient_sums};
use crate::material::{ddot, elastic_stress_energy, stvk_second_piola, trace, MaterialModel};
use crate::params::StepParams;
use crate::particles::params::ParticleParams;
use glam::Mat3;

/// A_p, H_p and V Ψ of particle p; with `velocities` (a viscous material) P includes
/// F·S_v, S_v = φ tr(Ė) I + 2ψ Ė, Ė = ½(ḞᵀF + FᵀḞ), Ḟ = [Σ_b V (v_b − v_p) ⊗ ∇W] G_p
/// (tlsph; the paper model adds φ tr(ν) I + 2ψ ν on its own strain's rate ν = 2Ė, no F).
#[allow(clippy::too_many_arguments)]
pub fn stress_of(
    params: &StepParams,
    pp: &ParticleParams,
    material: MaterialModel,
    rest: &[f32],
    displacements: &[f32],
    velocities: Option<&[f32]>,
    neighbour_offsets: &[u32],
    neighbours: &[u32],
    correction: &[f32],
    pairs: Option<&super::sph::PairTable>,
    p: usize,
) -> (Mat3, Mat3, f32) {
    let lists = (neighbour_offsets, neighbours);
    let (s, s_rate) = match velocities {
        Some(v) => {
            let [s, r] = gradient_sums(pp, rest, [displacements, v], lists.0, lists.1, pairs, p);
            (s, Some(r))
        }
        None => (
            gradient_sum(pp, rest, displacements, lists.0, lists.1, pairs, p),
            None,
        ),
    };
    let g = load_dm_inv(correction, p);
    let h = s * g;
    let (stress, psi) = if pp.model == 1 {
        let f = Mat3::IDENTITY + h;
        let eps = f.transpose() * f - Mat3::IDENTITY;
        let tr = trace(eps);
        (
            Mat3::from_diagonal(glam::Vec3::splat(params.lambda * tr)) + eps * (2.0 * params.mu),
            0.25 * params.mu * ddot(eps, eps) + 0.125 * params.lambda * tr * tr,
        )
    } else {
        elastic_stress_energy(material, h, params.lambda, params.mu)
    };
    let stress = match s_rate {
        Some(s_rate) if pp.model == 1 => {
            // The paper's eq. (3)–(4) on its own strain ε = FᵀF − I, as its elastic stress:
            // ν = ε̇ = ḞᵀF + FᵀḞ, no F.
            let (f, f_dot) = (Mat3::IDENTITY + h, s_rate * g);
            let nu = f_dot.transpose() * f + f.transpose() * f_dot;
            stress + stvk_second_piola(Mat3::ZERO, nu, 0.0, 0.0, params.phi, params.psi)
        }
        Some(s_rate) => stress + viscous_stress(params, Mat3::IDENTITY + h, s_rate * g),
        None => stress,
    };
    (stress * g.transpose(), h, pp.volume * psi)
}

/// Per particle of `stress_list`: `particle_stress` (A), `particle_gradient` (H),
/// `particle_energy` (kernel gradients from `pairs` when given; `velocities`: the viscous
/// stress too, see [`stress_of`]).
#[allow(clippy::too_many_arguments)]
pub fn sph_stress(
    params: &StepParams,
    pp: &ParticleParams,
    material: MaterialModel,
    stress_list: &[u32],
    rest: &[f32],
    displacements: &[f32],
    velocities: Option<&[f32]>,
    neighbour_offsets: &[u32],
    neighbours: &[u32],
    correction: &[f32],
    pairs: Option<&super::sph::PairTable>,
    particle_stress: &mut [f32],
    particle_gradient: &mut [f32],
    particle_energy: &mut [f32],
) {
    use rayon::prelude::*;
    let results: Vec<(Mat3, Mat3, f32)> = stress_list
        .par_iter()
        .map(|&p| {
            stress_of(
                params,
                pp,
                material,
                rest,
                displacements,
                velocities,
                neighbour_offsets,
                neighbours,
                correction,
                pairs,
                p as usize,
            )
        })
        .collect();
    for (&p, (a, h, e)) in stress_list.iter().zip(results) {
        let p = p as usize;
        particle_stress[9 * p..9 * p + 9].copy_from_slice(&a.to_cols_array());
        particle_gradient[9 * p..9 * p + 9].copy_from_slice(&h.to_cols_array());
        particle_energy[p] = e;
    }
}
