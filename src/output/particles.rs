//! The particles as a `.vtu` point cloud: points at rest positions, point data
//! `displacement` and `velocity` (vec3) and `active` (1 for dynamic particles). Embedded
//! particles are placed where their host puts them (Σ wᵢ uᵢ plus a releasing particle's
//! fading offset) and move with it (Σ wᵢ vᵢ, less offset/blend while the offset fades), so
//! the file is exact whatever the last step computed for them (`follow` writes velocities
//! only for a viscous material, and only for the particles near the tool).

use super::vtu;
use crate::cpu::activate::ParticleStatic;
use crate::model::Model;
use crate::particles::params::mode;
use crate::stepper::{ParticleSnapshot, State};
use glam::Vec3;

/// Per particle, packed xyz (empty without particles): its own value from `own` when
/// dynamic, else `embedded(k, mode, Σ wᵢ aᵢ)` with a the vertices' `field`.
fn own_or_embedded(
    model: &Model,
    field: &[f32],
    own: &[f32],
    snap: &ParticleSnapshot,
    embedded: impl Fn(usize, u32, Vec3) -> Vec3,
) -> Vec<f32> {
    let Some(st) = ParticleStatic::of(model) else {
        return Vec::new();
    };
    (0..st.host.len())
        .flat_map(|k| {
            let m = snap.modes[k];
            let x = if m & mode::DYNAMIC != 0 {
                crate::cpu::load3(own, k)
            } else {
                embedded(k, m, st.embed(field, k))
            };
            x.to_array()
        })
        .collect()
}

/// The particles' blend time, s (never 0: it divides).
fn blend_seconds(model: &Model) -> f32 {
    model
        .particles
        .as_ref()
        .map_or(1e-30, |p| p.settings.blend.max(1e-30) as f32)
}

/// The particles' displacements: their own when dynamic, else embedded in their host.
pub fn particle_displacements(model: &Model, nodes: &State, snap: &ParticleSnapshot) -> Vec<f32> {
    let blend = blend_seconds(model);
    own_or_embedded(
        model,
        &nodes.displacements,
        &snap.displacements,
        snap,
        |k, m, u| {
            if m & mode::BLENDING != 0 {
                let b = (1.0 - snap.timers[k] / blend).max(0.0);
                u + crate::cpu::load3(&snap.offsets, k) * b
            } else {
                u
            }
        },
    )
}

/// The particles' velocities: their own when dynamic, else their host's, v = Σ wᵢ vᵢ, less
/// offset/blend while a releasing particle's offset fades (as `follow` gives them).
pub fn particle_velocities(model: &Model, nodes: &State, snap: &ParticleSnapshot) -> Vec<f32> {
    let blend = blend_seconds(model);
    own_or_embedded(
        model,
        &nodes.velocities,
        &snap.velocities,
        snap,
        |k, m, v| {
            if m & mode::BLENDING != 0 && 1.0 - snap.timers[k] / blend > 0.0 {
                v - crate::cpu::load3(&snap.offsets, k) / blend
            } else {
                v
            }
        },
    )
}

/// The `particles_final.vtu` text.
pub fn particles_vtu(model: &Model, nodes: &State, snap: &ParticleSnapshot) -> String {
    let Some(p) = &model.particles else {
        return String::new();
    };
    let u = particle_displacements(model, nodes, snap);
    let v = particle_velocities(model, nodes, snap);
    let active: Vec<i32> = snap
        .modes
        .iter()
        .map(|m| (m & mode::DYNAMIC != 0) as i32)
        .collect();
    vtu::vtu_points(
        &p.rest,
        &[
            vtu::DataArray::F32("displacement", 3, &u),
            vtu::DataArray::F32("velocity", 3, &v),
            vtu::DataArray::I32("active", &active),
        ],
    )
}

#[cfg(test)]
mod tests {
    use super::particle_velocities;
    use crate::model::Model;
    use crate::particles::params::mode;
    use crate::scene::Scene;
    use crate::stepper::{ParticleSnapshot, State};
    use glam::Vec3;

    #[test]
    fn embedded_particles_move_with_their_host_in_the_file() {
        let text = Scene::builtin_text("lv_touch").unwrap();
        let scene = Scene::from_toml(text, "lv_touch", "lv_touch", None).unwrap();
        let model = Model::from_scene(&scene);
        let rest = &model.particles.as_ref().unwrap().rest;
        let n = rest.len() / 3;
        let rest_of = |k: usize| Vec3::from_slice(&rest[3 * k..3 * k + 3]);
        // The vertices move in an affine field v = A·X + c, which the host's weights
        // reproduce at each embedded particle's rest position.
        let field = |x: Vec3| Vec3::new(0.5 * x.y + 0.01, -0.2 * x.z, 0.3 * x.x - 0.02);
        let nodes = State {
            displacements: vec![0.0; scene.mesh.positions.len() * 3],
            velocities: scene
                .mesh
                .positions
                .iter()
                .flat_map(|x| field(x.as_vec3()).to_array())
                .collect(),
        };
        // Particle 0 dynamic with its own velocity, 1 releasing (its offset fading over the
        // scene's blend time), the rest embedded; the stored velocities stale (zero).
        let mut modes = vec![0; n];
        modes[0] = mode::DYNAMIC;
        modes[1] = mode::BLENDING;
        let mut velocities = vec![0.0; 3 * n];
        velocities[..3].copy_from_slice(&[1.0, 2.0, 3.0]);
        let mut offsets = vec![0.0; 3 * n];
        offsets[3..6].copy_from_slice(&[1e-4, 0.0, 0.0]);
        let snap = ParticleSnapshot {
            displacements: vec![0.0; 3 * n],
            velocities,
            modes,
            offsets,
            timers: vec![0.0; n],
        };
        let v = particle_velocities(&model, &nodes, &snap);
        let at = |k: usize| Vec3::from_slice(&v[3 * k..3 * k + 3]);
        assert_eq!(at(0), Vec3::new(1.0, 2.0, 3.0));
        let blend = scene.particles.as_ref().unwrap().blend as f32;
        let fading = field(rest_of(1)) - Vec3::new(1e-4, 0.0, 0.0) / blend;
        assert!((at(1) - fading).length() < 1e-5, "{} {}", at(1), fading);
        let worst = (2..n)
            .map(|k| (at(k) - field(rest_of(k))).length())
            .fold(0.0f32, f32::max);
        assert!(
            worst < 1e-5,
            "embedded particle off its host's velocity by {worst} m/s"
        );
    }
}
