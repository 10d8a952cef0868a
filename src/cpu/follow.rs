//! CPU twin of `kernels/follow.wgsl`: embedded particles of the force set follow their host
//! (plus the fading offset of a blending particle).

use super::activate::ParticleStatic;
use super::{load3, store3};
use crate::particles::params::{mode, ParticleParams};

/// Per particle of `force_list` that is not dynamic: u_p = Σ wᵢ uᵢ (+ offset·(1 − t/blend)).
#[allow(clippy::too_many_arguments)]
pub fn follow(
    pp: &ParticleParams,
    force_list: &[u32],
    particle_mode: &[u32],
    s: &ParticleStatic,
    displacements: &[f32],
    particle_timer: &[f32],
    particle_offset: &[f32],
    particle_displacements: &mut [f32],
) {
    for &p in force_list {
        let p = p as usize;
        let m = particle_mode[p];
        if m & mode::DYNAMIC != 0 {
            continue;
        }
        let mut u = s.embed(displacements, p);
        if m & mode::BLENDING != 0 {
            let b = 0.0f32.max(1.0 - particle_timer[p] / pp.blend.max(1e-30));
            u += load3(particle_offset, p) * b;
        }
        store3(particle_displacements, p, u);
    }
}
