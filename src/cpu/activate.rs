//! CPU twin of `kernels/activate.wgsl`: the particle mode machine, the stress and force sets,
//! the tets' energy weights and the vertices' lumped masses (see the kernel for the rules).

use super::load3;
use crate::contact::{ToolParams, ToolState};
use crate::params::StepParams;
use crate::particles::params::{mode, ParticleParams, NODE_COUPLED};
use glam::Vec3;

const PER_UPDATE: u32 = mode::NEAR | mode::IN_S | mode::IN_F | mode::ACTIVATED | mode::RELEASED;

/// Read-only particle data the activation stage needs.
pub struct ParticleStatic<'a> {
    /// Rest positions, xyz.
    pub rest: &'a [f32],
    /// Host tet per particle.
    pub host: &'a [u32],
    /// Barycentric weights, 4 per particle.
    pub weights: &'a [f32],
    /// Tets of the mesh.
    pub tets: &'a [[u32; 4]],
}

impl<'a> ParticleStatic<'a> {
    /// The particle data of `model` (None without particles).
    pub fn of(model: &'a crate::model::Model) -> Option<ParticleStatic<'a>> {
        let p = model.particles.as_ref()?;
        Some(ParticleStatic {
            rest: &p.rest,
            host: &p.host,
            weights: &p.weights,
            tets: &model.tets,
        })
    }

    /// Σ wᵢ aᵢ over particle p's host corners (a: packed xyz per vertex).
    pub fn embed(&self, a: &[f32], p: usize) -> Vec3 {
        let t = self.tets[self.host[p] as usize];
        (0..4).fold(Vec3::ZERO, |acc, c| {
            acc + load3(a, t[c] as usize) * self.weights[4 * p + c]
        })
    }
}

/// Per particle: the mode machine (twin of entry `activate`), in parallel over particles.
///
/// A particle that is neither pinned, dynamic nor blending and lies so far from the tool
/// that it cannot qualify keeps its state (only the per-update bits are cleared), so it is
/// skipped without embedding it: its displacement is Σ wᵢuᵢ, at most Σ|wᵢ|·max|uᵢ| long,
/// so |X_p − c| − Σ|wᵢ|·max|uᵢ| − R ≥ activation radius (with a margin for rounding) rules it
/// out. Results are those of the kernel, which evaluates every particle.
#[allow(clippy::too_many_arguments)]
pub fn activate(
    pp: &ParticleParams,
    tool_params: &ToolParams,
    tool_state: &ToolState,
    tool: bool,
    s: &ParticleStatic,
    displacements: &[f32],
    velocities: &[f32],
    particle_displacements: &mut [f32],
    particle_velocities: &mut [f32],
    particle_mode: &mut [u32],
    particle_timer: &mut [f32],
    particle_offset: &mut [f32],
) {
    use rayon::prelude::*;
    let c = Vec3::from_array(tool_state.position);
    let n = pp.n_particles as usize;
    let tool_active = tool && pp.all_active == 0;
    let u_max = if tool_active {
        displacements
            .chunks_exact(3)
            .map(|u| Vec3::from_slice(u).length())
            .fold(0.0f32, f32::max)
    } else {
        0.0
    };
    let update_particle =
        |p: usize, pd: &mut [f32], pv: &mut [f32], pm: &mut u32, pt: &mut f32, po: &mut [f32]| {
            let mut m = *pm & !PER_UPDATE;
            if m & mode::PINNED != 0 {
                *pm = m;
                return;
            }
            let x0 = load3(s.rest, p);
            if tool_active && m & (mode::DYNAMIC | mode::BLENDING) == 0 {
                let reach: f32 = s.weights[4 * p..4 * p + 4].iter().map(|w| w.abs()).sum();
                let centre = (x0 - c).length();
                // The kernel forms X + u − c in f32: its rounding grows with |X| and |c|.
                let scale = x0.abs().max_element() + c.abs().max_element();
                let margin = 1e-4 * (centre + scale + tool_params.radius + 1.0);
                if centre - reach * u_max - tool_params.radius >= pp.activation_radius + margin {
                    *pm = m;
                    return;
                }
            }
            let mut timer = *pt;
            let mut offset = Vec3::from_slice(po);
            let ue = s.embed(displacements, p);
            let blend = if m & mode::BLENDING != 0 {
                0.0f32.max(1.0 - timer / pp.blend.max(1e-30))
            } else {
                0.0
            };
            let u = if m & mode::DYNAMIC != 0 {
                Vec3::from_slice(pd)
            } else {
                ue + offset * blend
            };
            let mut qualifies = pp.all_active != 0;
            let mut keep = qualifies;
            if tool && !qualifies {
                let d = (x0 + u - c).length() - tool_params.radius;
                qualifies = d < pp.activation_radius;
                keep = d < pp.release_radius;
            }
            if m & mode::DYNAMIC != 0 {
                if keep {
                    timer = 0.0;
                } else {
                    timer += pp.interval;
                    if timer >= pp.dwell {
                        offset = u - ue;
                        m = (m & !mode::DYNAMIC) | mode::BLENDING | mode::RELEASED;
                        timer = 0.0;
                    }
                }
            } else if qualifies {
                pd.copy_from_slice(&u.to_array());
                pv.copy_from_slice(&s.embed(velocities, p).to_array());
                m = (m & !mode::BLENDING) | mode::DYNAMIC | mode::ACTIVATED;
                timer = 0.0;
                offset = Vec3::ZERO;
            } else if m & mode::BLENDING != 0 {
                timer += pp.interval;
                if timer >= pp.blend {
                    m &= !mode::BLENDING;
                    offset = Vec3::ZERO;
                }
            }
            *pt = timer;
            po.copy_from_slice(&offset.to_array());
            *pm = m;
        };
    const BLOCK: usize = 256;
    particle_displacements[..3 * n]
        .par_chunks_mut(3 * BLOCK)
        .zip(particle_velocities[..3 * n].par_chunks_mut(3 * BLOCK))
        .zip(particle_mode[..n].par_chunks_mut(BLOCK))
        .zip(particle_timer[..n].par_chunks_mut(BLOCK))
        .zip(particle_offset[..3 * n].par_chunks_mut(3 * BLOCK))
        .enumerate()
        .for_each(|(block, ((((pd, pv), pm), pt), po))| {
            for j in 0..pm.len() {
                let (pd, pv) = (&mut pd[3 * j..3 * j + 3], &mut pv[3 * j..3 * j + 3]);
                let (pm, pt, po) = (&mut pm[j], &mut pt[j], &mut po[3 * j..3 * j + 3]);
                update_particle(block * BLOCK + j, pd, pv, pm, pt, po);
            }
        });
}

/// Mark `bit` on every particle with `source` set and on its neighbours (twin of
/// `activate_stress_set` with source DYNAMIC / bit IN_S and `activate_force_set` with
/// source IN_S / bit IN_F; an OR, so the order does not matter).
pub fn mark_set(
    n: usize,
    source: u32,
    bit: u32,
    neighbour_offsets: &[u32],
    neighbours: &[u32],
    particle_mode: &mut [u32],
) {
    for p in 0..n {
        if particle_mode[p] & source == 0 {
            continue;
        }
        particle_mode[p] |= bit;
        for k in neighbour_offsets[p]..neighbour_offsets[p + 1] {
            particle_mode[neighbours[k as usize] as usize] |= bit;
        }
    }
}

/// Per tet: 1 − (its particles in S)/(its particles), 1 without particles (twin of
/// `activate_tet_weights`).
pub fn tet_weights(
    params: &StepParams,
    tet_offsets: &[u32],
    particle_mode: &[u32],
    tet_weight: &mut [f32],
) {
    super::par::for_each_chunk::<1>(tet_weight, params.n_tets as usize, |e, out| {
        let (first, last) = (tet_offsets[e], tet_offsets[e + 1]);
        let in_s = (first..last)
            .filter(|&p| particle_mode[p as usize] & mode::IN_S != 0)
            .count() as u32;
        out[0] = if last > first {
            1.0 - in_s as f32 / (last - first) as f32
        } else {
            1.0
        };
    });
}

/// Per vertex, in parallel: lumped mass, momentum-preserving velocity, kinematic vertices,
/// coupling flag and contact weight (twin of `activate_relump`).
#[allow(clippy::too_many_arguments)]
pub fn relump(
    params: &StepParams,
    pp: &ParticleParams,
    slot_offsets: &[u32],
    slots: &[u32],
    weights: &[f32],
    particle_mode: &[u32],
    particle_velocities: &[f32],
    core_mass: &[f32],
    node_fixed: &[u32],
    incidence_offsets: &[u32],
    incidence: &[u32],
    tet_weight: &[f32],
    mass: &mut [f32],
    inv_mass: &mut [f32],
    velocities: &mut [f32],
    node_flags: &mut [u32],
    contact_weight: &mut [f32],
) {
    use rayon::prelude::*;
    let mp = pp.mass;
    let nv = params.n_vertices as usize;
    mass[..nv]
        .par_iter_mut()
        .zip(inv_mass[..nv].par_iter_mut())
        .zip(velocities[..3 * nv].par_chunks_mut(3))
        .zip(node_flags[..nv].par_iter_mut())
        .zip(contact_weight[..nv].par_iter_mut())
        .with_min_len(super::par::MIN_INDICES_PER_TASK)
        .enumerate()
        .for_each(|(i, ((((mass_i, inv_mass_i), vel), flags), contact_w))| {
            let mut m = core_mass[i];
            let (mut m_released, mut p_released) = (0.0f32, Vec3::ZERO);
            let (mut m_dynamic, mut p_dynamic) = (0.0f32, Vec3::ZERO);
            let mut coupled = false;
            for k in slot_offsets[i]..slot_offsets[i + 1] {
                let slot = slots[k as usize] as usize;
                let p = slot / 4;
                let w = weights[slot];
                let md = particle_mode[p];
                if md & mode::DYNAMIC == 0 {
                    m += w * mp;
                    if md & mode::RELEASED != 0 {
                        m_released += w * mp;
                        p_released += load3(particle_velocities, p) * (w * mp);
                    }
                    if md & mode::IN_F != 0 {
                        coupled = true;
                    }
                } else {
                    m_dynamic += w * mp;
                    p_dynamic += load3(particle_velocities, p) * (w * mp);
                }
            }
            *mass_i = m;
            let mut v = Vec3::from_slice(vel);
            let w_inv;
            if node_fixed[i] != 0 {
                v = Vec3::ZERO;
                w_inv = 0.0;
            } else if m > 0.0 {
                w_inv = 1.0 / m;
                v = (v * (m - m_released) + p_released) / m;
            } else {
                w_inv = -1.0;
                v = if m_dynamic > 0.0 {
                    p_dynamic / m_dynamic
                } else {
                    Vec3::ZERO
                };
            }
            *inv_mass_i = w_inv;
            vel.copy_from_slice(&v.to_array());
            *flags = if coupled { NODE_COUPLED } else { 0 };
            let mut cw = 1.0f32;
            for k in incidence_offsets[i]..incidence_offsets[i + 1] {
                cw = cw.min(tet_weight[incidence[k as usize] as usize / 4]);
            }
            *contact_w = cw;
        });
}
