//! CPU twin of `kernels/integrate_particles.wgsl`: symplectic Euler for dynamic particles with
//! the particle sub-step; divergence flags particle p as n_vertices + p.

use super::{load3, store3};
use crate::params::StepParams;
use crate::particles::params::ParticleParams;

/// Per particle of `dynamic_list`: v ← (v + dt_s f/m)/(1 + α dt_s), u ← u + dt_s v.
pub fn integrate_particles(
    params: &StepParams,
    pp: &ParticleParams,
    dynamic_list: &[u32],
    particle_forces: &[f32],
    particle_displacements: &mut [f32],
    particle_velocities: &mut [f32],
    status: &mut [u32],
) {
    let dt = pp.sub_dt;
    for &p in dynamic_list {
        let p = p as usize;
        let f = load3(particle_forces, p);
        let mut v = load3(particle_velocities, p);
        let mut u = load3(particle_displacements, p);
        v = (v + f * (dt / pp.mass)) / (1.0 + params.damping * dt);
        u += v * dt;
        store3(particle_velocities, p, v);
        store3(particle_displacements, p, u);
        if !(u.is_finite() && v.is_finite()) || v.dot(v) > params.speed_limit * params.speed_limit {
            status[0] = status[0].min(params.n_vertices + p as u32);
        }
    }
}
