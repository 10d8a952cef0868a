//! CPU twin of `kernels/activate.wgsl`: the particle mode machine, the stress and force sets,
//! the tets' energy weights and the vertices' lumped masses (see the kernel for the rules).

use super::load3;
use crate::contact::{ToolParams, ToolState};
use crate::params::StepParams;
use crate::particles::params::{mode, ParticleParams, NODE_COUPLED, NODE_MASSLESS};
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

/// What the mode machine reads besides the particle's own state.
pub struct ModeInputs<'a> {
    /// Particle constants.
    pub pp: &'a ParticleParams,
    /// Tool constants.
    pub tool_params: &'a ToolParams,
    /// Tool centre.
    pub centre: Vec3,
    /// The scene has a tool.
    pub tool: bool,
    /// The tool decides (a tool, and not `activation = "all"`).
    pub tool_active: bool,
    /// The largest vertex displacement |u| (0 when the tool does not decide).
    pub u_max: f32,
    /// Particle statics.
    pub s: &'a ParticleStatic<'a>,
    /// Vertex displacements.
    pub displacements: &'a [f32],
    /// Vertex velocities.
    pub velocities: &'a [f32],
}

impl<'a> ModeInputs<'a> {
    /// The inputs for one activation.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        pp: &'a ParticleParams,
        tool_params: &'a ToolParams,
        tool_state: &ToolState,
        tool: bool,
        s: &'a ParticleStatic<'a>,
        displacements: &'a [f32],
        velocities: &'a [f32],
    ) -> ModeInputs<'a> {
        let tool_active = tool && pp.all_active == 0;
        let u_max = if tool_active {
            displacements
                .chunks_exact(3)
                .map(|u| Vec3::from_slice(u).length())
                .fold(0.0f32, f32::max)
        } else {
            0.0
        };
        ModeInputs {
            pp,
            tool_params,
            centre: Vec3::from_array(tool_state.position),
            tool,
            tool_active,
            u_max,
            s,
            displacements,
            velocities,
        }
    }
}

/// One particle's state for the mode machine.
pub struct ModeState<'a> {
    /// Displacement (xyz).
    pub u: &'a mut [f32],
    /// Velocity (xyz).
    pub v: &'a mut [f32],
    /// Mode bits.
    pub mode: &'a mut u32,
    /// Dwell or blend timer, s.
    pub timer: &'a mut f32,
    /// Release offset (xyz).
    pub offset: &'a mut [f32],
}

/// The mode machine for particle p (one thread of the kernel). A particle that is neither
/// pinned, dynamic nor blending and lies so far from the tool that it cannot qualify keeps
/// its state (only the per-update bits are cleared), so it is skipped without embedding it:
/// its displacement is Σ wᵢuᵢ, at most Σ|wᵢ|·max|uᵢ| long, so
/// |X_p − c| − Σ|wᵢ|·max|uᵢ| − R ≥ activation radius (with a margin for rounding) rules it out.
pub fn update_particle(inp: &ModeInputs, p: usize, st: ModeState) {
    let (pp, s, c) = (inp.pp, inp.s, inp.centre);
    // In F since the last update: `follow` advanced its blend clock every sub-step.
    let followed = *st.mode & mode::IN_F != 0;
    let mut m = *st.mode & !PER_UPDATE;
    if m & mode::PINNED != 0 {
        *st.mode = m;
        return;
    }
    let x0 = load3(s.rest, p);
    if inp.tool_active && m & (mode::DYNAMIC | mode::BLENDING) == 0 {
        let reach: f32 = s.weights[4 * p..4 * p + 4].iter().map(|w| w.abs()).sum();
        let centre = (x0 - c).length();
        // The kernel forms X + u − c in f32: its rounding grows with |X| and |c|.
        let scale = x0.abs().max_element() + c.abs().max_element();
        let margin = 1e-4 * (centre + scale + inp.tool_params.radius + 1.0);
        if centre - reach * inp.u_max - inp.tool_params.radius >= pp.activation_radius + margin {
            *st.mode = m;
            return;
        }
    }
    let mut timer = *st.timer;
    let mut offset = Vec3::from_slice(st.offset);
    let ue = s.embed(inp.displacements, p);
    let blend = if m & mode::BLENDING != 0 {
        0.0f32.max(1.0 - timer / pp.blend.max(1e-30))
    } else {
        0.0
    };
    let u = if m & mode::DYNAMIC != 0 {
        Vec3::from_slice(st.u)
    } else {
        ue + offset * blend
    };
    let mut qualifies = pp.all_active != 0;
    let mut keep = qualifies;
    if inp.tool && !qualifies {
        let d = (x0 + u - c).length() - inp.tool_params.radius;
        qualifies = d < pp.activation_radius;
        keep = d < pp.release_radius;
    }
    if m & mode::DYNAMIC != 0 {
        if keep {
            timer = -1.0;
        } else {
            // The dwell clock starts at the first check that finds it far (it may have left
            // just before) and counts the intervals after it.
            timer = if timer < 0.0 {
                0.0
            } else {
                timer + pp.interval
            };
            if timer >= pp.dwell {
                offset = u - ue;
                m = (m & !mode::DYNAMIC) | mode::BLENDING | mode::RELEASED;
                timer = 0.0;
            }
        }
    } else if qualifies {
        st.u.copy_from_slice(&u.to_array());
        st.v.copy_from_slice(&s.embed(inp.velocities, p).to_array());
        m = (m & !mode::BLENDING) | mode::DYNAMIC | mode::ACTIVATED;
        timer = -1.0;
        offset = Vec3::ZERO;
    } else if m & mode::BLENDING != 0 {
        if !followed {
            timer += pp.interval;
        }
        if timer >= pp.blend {
            m &= !mode::BLENDING;
            offset = Vec3::ZERO;
        }
    }
    *st.timer = timer;
    st.offset.copy_from_slice(&offset.to_array());
    *st.mode = m;
}

/// The particle arrays the mode machine writes.
pub struct ModeArrays<'a> {
    /// Displacements, xyz.
    pub displacements: &'a mut [f32],
    /// Velocities, xyz.
    pub velocities: &'a mut [f32],
    /// Mode bits.
    pub mode: &'a mut [u32],
    /// Timers, s.
    pub timer: &'a mut [f32],
    /// Release offsets, xyz.
    pub offset: &'a mut [f32],
}

/// Per particle: the mode machine (twin of entry `activate`, see [`update_particle`]), in
/// parallel over blocks of particles, so the result is the same for any thread count.
pub fn activate(inp: &ModeInputs, state: ModeArrays) {
    use rayon::prelude::*;
    let n = inp.pp.n_particles as usize;
    const BLOCK: usize = 256;
    state.displacements[..3 * n]
        .par_chunks_mut(3 * BLOCK)
        .zip(state.velocities[..3 * n].par_chunks_mut(3 * BLOCK))
        .zip(state.mode[..n].par_chunks_mut(BLOCK))
        .zip(state.timer[..n].par_chunks_mut(BLOCK))
        .zip(state.offset[..3 * n].par_chunks_mut(3 * BLOCK))
        .enumerate()
        .for_each(|(block, ((((pd, pv), pm), pt), po))| {
            for j in 0..pm.len() {
                let st = ModeState {
                    u: &mut pd[3 * j..3 * j + 3],
                    v: &mut pv[3 * j..3 * j + 3],
                    mode: &mut pm[j],
                    timer: &mut pt[j],
                    offset: &mut po[3 * j..3 * j + 3],
                };
                update_particle(inp, block * BLOCK + j, st);
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

/// Tet e's energy weight: 1 − (its particles in S)/(its particles), 1 without particles.
pub fn tet_weight_of(e: usize, tet_offsets: &[u32], particle_mode: &[u32]) -> f32 {
    let (first, last) = (tet_offsets[e], tet_offsets[e + 1]);
    let in_s = (first..last)
        .filter(|&p| particle_mode[p as usize] & mode::IN_S != 0)
        .count() as u32;
    if last > first {
        1.0 - in_s as f32 / (last - first) as f32
    } else {
        1.0
    }
}

/// Per tet: [`tet_weight_of`] (twin of `activate_tet_weights`).
pub fn tet_weights(
    params: &StepParams,
    tet_offsets: &[u32],
    particle_mode: &[u32],
    tet_weight: &mut [f32],
) {
    super::par::for_each_chunk::<1>(tet_weight, params.n_tets as usize, |e, out| {
        out[0] = tet_weight_of(e, tet_offsets, particle_mode);
    });
}

/// What the relump reads (see [`relump_vertex`]).
pub struct RelumpInputs<'a> {
    /// Particle constants (the particle mass).
    pub pp: &'a ParticleParams,
    /// CSR vertex → particle slots.
    pub slot_offsets: &'a [u32],
    /// Particle slots p·4 + corner.
    pub slots: &'a [u32],
    /// Barycentric weights, 4 per particle.
    pub weights: &'a [f32],
    /// Particle modes.
    pub particle_mode: &'a [u32],
    /// Particle velocities.
    pub particle_velocities: &'a [f32],
    /// Particle rest positions X_p, packed xyz.
    pub particle_rest: &'a [f32],
    /// Vertex rest positions X_i, packed xyz.
    pub rest: &'a [f32],
    /// Per vertex, the mass of the tets that are not particle zone.
    pub core_mass: &'a [f32],
    /// Per vertex, 1 when fixed.
    pub node_fixed: &'a [u32],
    /// CSR vertex → tet corners.
    pub incidence_offsets: &'a [u32],
    /// Tet corners t·4 + corner.
    pub incidence: &'a [u32],
    /// Per tet energy weight.
    pub tet_weight: &'a [f32],
}

/// One vertex's relumped values.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VertexLump {
    /// m = core mass + Σ wᵢ m_p over the non-dynamic hosted particles.
    pub mass: f32,
    /// 1/m; 0 fixed; −1 kinematic (no mass left).
    pub inv_mass: f32,
    /// The velocity that keeps the momentum of released particles; for a vertex with no mass
    /// left, its dynamic particles' velocity field at its rest place ([`KinematicFit`]).
    pub velocity: Vec3,
    /// `NODE_COUPLED` when it hosts a force-set particle, `NODE_MASSLESS` when it has no mass.
    pub flags: u32,
    /// The smallest energy weight of its tets.
    pub contact_weight: f32,
}

/// A vertex with no mass left moves with its dynamic particles: it takes the weighted linear
/// least-squares fit v(d) ≈ a + G d of their velocities over their rest offsets
/// d = (X_p − X_i)/Δx, weights β = wᵢ m_p, evaluated at d = 0:
/// G = Cov(v, d) Cov(d, d)⁻¹ and a = v̄ − G d̄ (v̄, d̄ the β-weighted means). It is exact for
/// any rigid or affine velocity field, so the vertex stays on a rotating body. (The mean v̄
/// alone is the velocity of the particles' weighted centroid, which lies up to a third of a
/// tet from the vertex: in a spin at 3.7 rad/s such vertices drifted 1.3 mm in 0.18 s.)
/// Where the offsets do not span three dimensions (tr Cov(d, d) ≤ 10⁻⁴ tr E[d dᵀ] or
/// det Cov(d, d) ≤ 10⁻³ (tr/3)³) it is v̄.
/// One pass of sums, in the order of the vertex's slots (twin of `activate_relump`'s).
#[derive(Clone, Copy, Debug)]
pub struct KinematicFit {
    /// Σ β.
    pub weight: f32,
    /// Σ β d.
    pub d: Vec3,
    /// Σ β v.
    pub v: Vec3,
    /// Σ β d dᵀ (columns).
    pub dd: glam::Mat3,
    /// Σ β v dᵀ (columns: Σ β v d_k).
    pub vd: glam::Mat3,
}

impl Default for KinematicFit {
    /// No particle (all sums zero; glam's `Mat3::default()` is the identity).
    fn default() -> Self {
        KinematicFit {
            weight: 0.0,
            d: Vec3::ZERO,
            v: Vec3::ZERO,
            dd: glam::Mat3::ZERO,
            vd: glam::Mat3::ZERO,
        }
    }
}

impl KinematicFit {
    /// Add particle with weight β, offset d and velocity v.
    pub fn add(&mut self, beta: f32, d: Vec3, v: Vec3) {
        self.weight += beta;
        self.d += d * beta;
        self.v += v * beta;
        let bd = d * beta;
        self.dd += glam::Mat3::from_cols(d * bd.x, d * bd.y, d * bd.z);
        self.vd += glam::Mat3::from_cols(v * bd.x, v * bd.y, v * bd.z);
    }

    /// The fit's velocity at d = 0 (zero with no particle).
    pub fn velocity_at_vertex(&self) -> Vec3 {
        if self.weight <= 0.0 {
            return Vec3::ZERO;
        }
        let inv_b = 1.0 / self.weight;
        let d_mean = self.d * inv_b;
        let v_mean = self.v * inv_b;
        let cov_dd = self.dd * inv_b - outer(d_mean, d_mean);
        let cov_vd = self.vd * inv_b - outer(v_mean, d_mean);
        // Inverse by cross products, as the kernel forms it.
        let (c0, c1, c2) = (cov_dd.x_axis, cov_dd.y_axis, cov_dd.z_axis);
        let (t0, t1, t2) = (c1.cross(c2), c2.cross(c0), c0.cross(c1));
        let det = c2.dot(t2);
        let trace = (c0.x + c1.y + c2.z) / 3.0;
        // The spread must also stand above the rounding of E[d dᵀ] − d̄ d̄ᵀ (one particle, or
        // several at one offset, leave noise of either sign there); NaN sums fall back too.
        let second_moment = (self.dd.x_axis.x + self.dd.y_axis.y + self.dd.z_axis.z) * inv_b / 3.0;
        let spans = trace > 1e-4 * second_moment && det > 1e-3 * trace * trace * trace;
        if !spans {
            return v_mean;
        }
        let inv = glam::Mat3::from_cols(t0, t1, t2).transpose() * (1.0 / det);
        v_mean - cov_vd * (inv * d_mean)
    }
}

/// a bᵀ (columns a b_k).
fn outer(a: Vec3, b: Vec3) -> glam::Mat3 {
    glam::Mat3::from_cols(a * b.x, a * b.y, a * b.z)
}

/// Vertex i's relump (one thread of `activate_relump`) from its velocity `v`. A vertex
/// hosting no released particle keeps v exactly: v·(m − 0)/m is skipped, not rounded.
pub fn relump_vertex(inp: &RelumpInputs, i: usize, v: Vec3) -> VertexLump {
    let mp = inp.pp.mass;
    let mut m = inp.core_mass[i];
    let (mut m_released, mut p_released) = (0.0f32, Vec3::ZERO);
    let mut dynamic = KinematicFit::default();
    let (mut coupled, mut released) = (false, false);
    let x_i = load3(inp.rest, i);
    for k in inp.slot_offsets[i]..inp.slot_offsets[i + 1] {
        let slot = inp.slots[k as usize] as usize;
        let p = slot / 4;
        let w = inp.weights[slot];
        let md = inp.particle_mode[p];
        if md & mode::DYNAMIC == 0 {
            m += w * mp;
            if md & mode::RELEASED != 0 {
                released = true;
                m_released += w * mp;
                p_released += load3(inp.particle_velocities, p) * (w * mp);
            }
            if md & mode::IN_F != 0 {
                coupled = true;
            }
        } else {
            let d = (load3(inp.particle_rest, p) - x_i) / inp.pp.spacing;
            dynamic.add(w * mp, d, load3(inp.particle_velocities, p));
        }
    }
    let mut v = v;
    let w_inv;
    if inp.node_fixed[i] != 0 {
        v = Vec3::ZERO;
        w_inv = 0.0;
    } else if m > 0.0 {
        w_inv = 1.0 / m;
        if released {
            v = (v * (m - m_released) + p_released) / m;
        }
    } else {
        w_inv = -1.0;
        v = dynamic.velocity_at_vertex();
    }
    let mut cw = 1.0f32;
    for k in inp.incidence_offsets[i]..inp.incidence_offsets[i + 1] {
        cw = cw.min(inp.tet_weight[inp.incidence[k as usize] as usize / 4]);
    }
    VertexLump {
        mass: m,
        inv_mass: w_inv,
        velocity: v,
        flags: if coupled { NODE_COUPLED } else { 0 } | if w_inv < 0.0 { NODE_MASSLESS } else { 0 },
        contact_weight: cw,
    }
}

/// Per vertex, in parallel: [`relump_vertex`] (twin of `activate_relump`).
pub fn relump(
    params: &StepParams,
    inp: &RelumpInputs,
    mass: &mut [f32],
    inv_mass: &mut [f32],
    velocities: &mut [f32],
    node_flags: &mut [u32],
    contact_weight: &mut [f32],
) {
    use rayon::prelude::*;
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
            let lump = relump_vertex(inp, i, Vec3::from_slice(vel));
            *mass_i = lump.mass;
            *inv_mass_i = lump.inv_mass;
            vel.copy_from_slice(&lump.velocity.to_array());
            *flags = lump.flags;
            *contact_w = lump.contact_weight;
        });
}

#[cfg(test)]
mod tests {
    use super::KinematicFit;
    use glam::{Mat3, Vec3};

    /// The fit reproduces an affine velocity field at the vertex, even when the particles all
    /// lie on one side of it (the mean would not), and falls back to the mean for coplanar
    /// offsets and for one particle or several at one offset (whose spread is rounding noise
    /// of either sign: without the floor on the trace, such noise passed the determinant test
    /// and gave garbage or NaN).
    #[test]
    fn the_kinematic_fit_is_exact_for_an_affine_field_and_the_mean_when_flat() {
        let a = Mat3::from_cols(
            Vec3::new(0.1, -0.3, 0.2),
            Vec3::new(0.3, 0.05, -0.1),
            Vec3::new(-0.2, 0.1, 0.02),
        );
        let c = Vec3::new(0.01, -0.02, 0.03);
        let mut fit = KinematicFit::default();
        let mut flat = KinematicFit::default();
        let mut k = 0u32;
        for i in 0..3 {
            for j in 0..3 {
                for l in 0..3 {
                    let d = Vec3::new(0.5 + i as f32, 0.5 + j as f32, 0.5 + l as f32);
                    let beta = 1e-6 * (1.0 + (k % 5) as f32);
                    fit.add(beta, d, c + a * d);
                    let d_flat = Vec3::new(d.x, d.y, 0.5);
                    flat.add(beta, d_flat, c + a * d_flat);
                    k += 1;
                }
            }
        }
        let v = fit.velocity_at_vertex();
        assert!((v - c).length() < 1e-5, "fit {v} against {c}");
        let mean = flat.v * (1.0 / flat.weight);
        assert_eq!(flat.velocity_at_vertex(), mean);
        assert!((mean - c).length() > 0.1, "the mean would have been right");
        assert_eq!(KinematicFit::default().velocity_at_vertex(), Vec3::ZERO);
        // One particle, or several at one offset: the mean, never the noise of a zero spread.
        for d in [
            Vec3::new(0.3, 1.7, 2.9),
            Vec3::new(-2.5, 0.1, 3.3),
            Vec3::splat(1.1),
        ] {
            let mut one = KinematicFit::default();
            for _ in 0..3 {
                one.add(1.3e-6, d, c + a * d);
                let v = one.velocity_at_vertex();
                assert_eq!(v, one.v * (1.0 / one.weight), "offset {d}");
            }
        }
    }
}
