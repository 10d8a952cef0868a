//! CPU twin of `kernels/follow.wgsl`: embedded particles of the force set follow their host
//! (plus the fading offset of a blending particle, whose blend clock advances here by a
//! particle sub-step, so the offset fades step by step).

use super::activate::ParticleStatic;
use super::{load3, store3};
use crate::particles::params::{mode, ParticleParams};

/// Per particle of `force_list` that is not dynamic: u_p = Σ wᵢ uᵢ, plus, when it is blending,
/// offset·(1 − t/blend) with its timer first advanced by a sub-step, t += Δt_sub (the
/// activation then adds nothing for the interval to a particle that was in the force set).
/// With `velocities` (the vertices' and the particles', for a viscous material's stress) also
/// v_p = Σ wᵢ vᵢ, less offset/blend while the offset fades.
#[allow(clippy::too_many_arguments)]
pub fn follow(
    pp: &ParticleParams,
    force_list: &[u32],
    particle_mode: &[u32],
    s: &ParticleStatic,
    displacements: &[f32],
    particle_timer: &mut [f32],
    particle_offset: &[f32],
    particle_displacements: &mut [f32],
    mut velocities: Option<(&[f32], &mut [f32])>,
) {
    for &p in force_list {
        let p = p as usize;
        let m = particle_mode[p];
        if m & mode::DYNAMIC != 0 {
            continue;
        }
        let mut u = s.embed(displacements, p);
        let mut fading = false;
        if m & mode::BLENDING != 0 {
            let t = particle_timer[p] + pp.sub_dt;
            particle_timer[p] = t;
            let b = 0.0f32.max(1.0 - t / pp.blend.max(1e-30));
            u += load3(particle_offset, p) * b;
            fading = 1.0 - t / pp.blend.max(1e-30) > 0.0;
        }
        store3(particle_displacements, p, u);
        if let Some((vertex_v, particle_v)) = velocities.as_mut() {
            let mut v = s.embed(vertex_v, p);
            if fading {
                v -= load3(particle_offset, p) / pp.blend.max(1e-30);
            }
            store3(particle_v, p, v);
        }
    }
}
