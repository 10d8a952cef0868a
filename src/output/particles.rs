//! The particles as a `.vtu` point cloud: points at rest positions, point data
//! `displacement` and `velocity` (vec3) and `active` (1 for dynamic particles). Embedded
//! particles are placed where their host puts them (Σ wᵢ uᵢ plus a releasing particle's
//! fading offset), so the file is exact whatever the last step computed for them.

use super::vtu;
use crate::cpu::activate::ParticleStatic;
use crate::model::Model;
use crate::particles::params::mode;
use crate::stepper::{ParticleSnapshot, State};

/// The particles' displacements: their own when dynamic, else embedded in their host.
pub fn particle_displacements(model: &Model, nodes: &State, snap: &ParticleSnapshot) -> Vec<f32> {
    let Some(p) = &model.particles else {
        return Vec::new();
    };
    let Some(st) = ParticleStatic::of(model) else {
        return Vec::new();
    };
    (0..p.len())
        .flat_map(|k| {
            let m = snap.modes[k];
            let u = if m & mode::DYNAMIC != 0 {
                crate::cpu::load3(&snap.displacements, k)
            } else {
                let mut u = st.embed(&nodes.displacements, k);
                if m & mode::BLENDING != 0 {
                    let b = (1.0 - snap.timers[k] / p.settings.blend.max(1e-30) as f32).max(0.0);
                    u += crate::cpu::load3(&snap.offsets, k) * b;
                }
                u
            };
            u.to_array()
        })
        .collect()
}

/// The `particles_final.vtu` text.
pub fn particles_vtu(model: &Model, nodes: &State, snap: &ParticleSnapshot) -> String {
    let Some(p) = &model.particles else {
        return String::new();
    };
    let u = particle_displacements(model, nodes, snap);
    let active: Vec<i32> = snap
        .modes
        .iter()
        .map(|m| (m & mode::DYNAMIC != 0) as i32)
        .collect();
    vtu::vtu_points(
        &p.rest,
        &[
            vtu::DataArray::F32("displacement", 3, &u),
            vtu::DataArray::F32("velocity", 3, &snap.velocities),
            vtu::DataArray::I32("active", &active),
        ],
    )
}
