//! Design 8 with a dynamic set that follows the tool (`particles.coupling = "exact"`,
//! `activation = "tool"`): what an activation does after the mode machine has run.
//!
//! 1. **Closure and slaving.** The dynamic set is closed and the vertices it covers are slaved
//!    ([`Slaving::new`]). A particle the closure adds becomes dynamic where it stands; one the
//!    mode machine has just released but the closure keeps stays dynamic, untouched, with its
//!    dwell clock left expired, so that it is released again at the next update. (Restarting
//!    its clock let two groups of particles that enclose each other be released at different
//!    updates, each kept by the other, forever: on hm1, 186 particles were still dynamic 3 s
//!    after the tool had gone.)
//! 2. **Lumped masses, linear momentum kept.** Each particle that is not dynamic lumps its mass
//!    m onto its host corners that are not slaved, with shares ŵₐ = wₐ / Σ_free w. Where a
//!    particle's shares change (it became dynamic, was released, or a corner of its host was
//!    slaved or freed), its old shares leave their vertices at those vertices' velocities and
//!    its new shares join at the particle's velocity V̂ (a released particle's own; a follower's
//!    old lumped velocity V_q = Σ ŵₐ vₐ). So a vertex's velocity changes only by what joins,
//!    vₐ ← vₐ + Σ m ŵₐ (V̂ − vₐ) / mₐ′, and a particle that becomes dynamic takes V_q:
//!    Σ m v over vertices and dynamic particles is unchanged (to rounding). A vertex that is
//!    newly slaved had no core mass, so nothing of its momentum is left behind.
//! 3. **No pop for a newly slaved vertex.** Its fit Σ s_q x_q lies near, not on, where it is
//!    (the fit is exact only for an affine field): the difference c_V is kept as an offset
//!    that fades linearly over `particles.blend`, x_V = Σ s_q x_q + (1 − t/blend) c_V, and the
//!    same is done when a slaved vertex's fit changes. While it fades, the vertex's force still
//!    goes to its particles as s_q f_V, so Σ f holds and Σ x × f is off by c_V(t) × f_V.
//! 4. **Release by δ → 0.** A particle the mode machine releases becomes a follower whose
//!    offset from its embedded place, δ = u − Σ wₐ uₐ at release, fades over
//!    `particles.blend` (`follow` places it); until then it stays in the stress set with that
//!    δ, so its neighbours' D sees it move back continuously rather than jump.

use super::exact_coupling::{Slaving, SlavingError};
use super::{load3, store3};
use crate::model::Model;
use crate::particles::params::{mode, ParticleParams};
use crate::particles::Particles;
use glam::{DMat3, DVec3, Vec3};

/// The fading offsets of the slaved vertices (item 3 of the module's doc).
#[derive(Clone, Debug, Default)]
pub struct SlaveOffsets {
    /// Per vertex, c_V (packed xyz, m); zero unless slaved and still fading.
    pub offset: Vec<f32>,
    /// Per vertex, time since its offset was set, s.
    pub timer: Vec<f32>,
}

impl SlaveOffsets {
    /// No offset on `n_vertices` vertices.
    pub fn new(n_vertices: usize) -> SlaveOffsets {
        SlaveOffsets {
            offset: vec![0.0; 3 * n_vertices],
            timer: vec![0.0; n_vertices],
        }
    }

    /// What is left of vertex v's offset after fading over `blend` seconds: (1 − t/blend)·c_V,
    /// zero once t ≥ blend.
    pub fn left(&self, v: usize, blend: f32) -> Vec3 {
        let b = if blend > 0.0 {
            (1.0 - self.timer[v] / blend).max(0.0)
        } else {
            0.0
        };
        load3(&self.offset, v) * b
    }

    /// Advance every offset's clock by `dt` seconds.
    pub fn advance(&mut self, dt: f32) {
        self.timer.iter_mut().for_each(|t| *t += dt);
    }

    /// The offset's rate of change, −c_V / blend while it fades, zero after.
    pub fn rate(&self, v: usize, blend: f32) -> Vec3 {
        if blend > 0.0 && self.timer[v] < blend {
            -load3(&self.offset, v) / blend
        } else {
            Vec3::ZERO
        }
    }
}

/// Place each slaved vertex: u_V = Σ s_q u_q + left(c_V), v_V = Σ s_q v_q + rate(c_V).
pub fn place_slaved(
    slaving: &Slaving,
    offsets: &SlaveOffsets,
    blend: f32,
    vertex: (&mut [f32], &mut [f32]),
    particle: (&[f32], &[f32]),
) {
    slaving.place(vertex.0, particle.0);
    slaving.place(vertex.1, particle.1);
    for v in (0..slaving.slaved.len()).filter(|&v| slaving.slaved[v]) {
        let c = offsets.left(v, blend);
        if c != Vec3::ZERO {
            store3(vertex.0, v, load3(vertex.0, v) + c);
            store3(vertex.1, v, load3(vertex.1, v) + offsets.rate(v, blend));
        }
    }
}

/// Particle q's lumped-mass shares under `slaving`: (corner vertex, ŵ) for the corners of its
/// host that are not slaved, ŵ = w / Σ_free w; empty when q is dynamic.
fn shares(model: &Model, pd: &Particles, slaving: &Slaving, q: usize) -> Vec<(u32, f32)> {
    if slaving.dynamic[q] {
        return Vec::new();
    }
    let t = model.tets[pd.host[q] as usize];
    let w = &pd.weights[4 * q..4 * q + 4];
    let free: f32 = (0..4)
        .filter(|&c| !slaving.slaved[t[c] as usize])
        .map(|c| w[c])
        .sum();
    (0..4)
        .filter(|&c| !slaving.slaved[t[c] as usize])
        .map(|c| (t[c], w[c] / free))
        .collect()
}

/// The particle arrays an exact activation reads and writes.
pub struct ExactParticleState<'a> {
    /// Mode bits (the mode machine has run).
    pub mode: &'a mut [u32],
    /// Displacements, packed xyz, m.
    pub displacements: &'a mut [f32],
    /// Velocities, packed xyz, m/s.
    pub velocities: &'a mut [f32],
    /// Dwell or blend timers, s.
    pub timer: &'a mut [f32],
    /// Release offsets, packed xyz, m.
    pub offset: &'a mut [f32],
}

/// What changed in one exact activation (for reports and tests).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ReslaveCounts {
    /// Particles the closure made dynamic (or kept dynamic against a release).
    pub closed: u32,
    /// Vertices slaved now that were not.
    pub newly_slaved: u32,
    /// Vertices freed now that were slaved.
    pub freed: u32,
}

impl ReslaveCounts {
    /// Add another activation's counts.
    pub fn add(&mut self, other: ReslaveCounts) {
        self.closed += other.closed;
        self.newly_slaved += other.newly_slaved;
        self.freed += other.freed;
    }
}

/// After the mode machine: close the dynamic set, slave the vertices it covers, re-lump the
/// masses keeping Σ m v, and set the fading offsets of the slaved vertices whose fit is new
/// (the module's doc, items 1–3). `old` is the slaving of the last activation, made from the
/// dynamic set `asked_before` (the mode machine's, before the closure; empty when unknown,
/// and replaced by this one's); the vertex velocities are updated in place and the slaved
/// vertices are placed. Returns the new slaving, or None when the mode machine asked for the
/// same set as last time: the slaving, the masses and the fits are then `old`'s (a slaving is
/// a function of the set asked for), and only the closure's particles and the slaved
/// vertices' places are set, as the full path would.
#[allow(clippy::too_many_arguments)]
pub fn reslave(
    model: &Model,
    pd: &Particles,
    pp: &ParticleParams,
    (old, asked_before): (&Slaving, &mut Vec<bool>),
    particles: ExactParticleState,
    vertex_u: &mut [f32],
    vertex_v: &mut [f32],
    offsets: &mut SlaveOffsets,
) -> Result<(Option<Slaving>, ReslaveCounts), SlavingError> {
    let (n, blend) = (pd.len(), pp.blend);
    let asked: Vec<bool> = particles
        .mode
        .iter()
        .map(|&m| m & mode::DYNAMIC != 0)
        .collect();
    let same_set = *asked_before == asked;
    let fresh = if same_set {
        None
    } else {
        Some(Slaving::new(model, pd, &asked)?)
    };
    *asked_before = asked;
    let asked = &asked_before[..];
    let new = fresh.as_ref().unwrap_or(old);
    let mut counts = ReslaveCounts::default();
    // The particles the closure adds.
    for q in (0..n).filter(|&q| new.dynamic[q] && !asked[q]) {
        counts.closed += 1;
        let m = particles.mode[q];
        if m & mode::RELEASED == 0 {
            // A follower (or one still blending back): dynamic where it stands.
            let b = if m & mode::BLENDING != 0 && blend > 0.0 {
                (1.0 - particles.timer[q] / blend).max(0.0)
            } else {
                0.0
            };
            let u = pd.embed(&model.tets, vertex_u, q) + load3(particles.offset, q) * b;
            store3(particles.displacements, q, u);
        }
        // A particle released by this update keeps its displacement, its velocity and an
        // expired dwell clock; one that was not released starts as any activated one.
        particles.timer[q] = if m & mode::RELEASED != 0 {
            pp.dwell
        } else {
            -1.0
        };
        particles.mode[q] = (m & !(mode::BLENDING | mode::RELEASED)) | mode::DYNAMIC;
        store3(particles.offset, q, Vec3::ZERO);
    }
    if same_set {
        // Nothing changed hands: no mass moved, no fit is new.
        place_slaved(
            old,
            offsets,
            blend,
            (vertex_u, vertex_v),
            (particles.displacements, particles.velocities),
        );
        return Ok((None, counts));
    }
    // What the re-lump touches, and its angular momentum before.
    let nv = model.n_vertices();
    let touched: Vec<usize> = (0..nv)
        .filter(|&a| {
            model.inv_mass[a] != 0.0
                && (old.slaved[a] != new.slaved[a] || old.vertex_mass[a] != new.vertex_mass[a])
        })
        .collect();
    let switched: Vec<usize> = (0..n)
        .filter(|&q| old.dynamic[q] != new.dynamic[q])
        .collect();
    let l_before = angular_momentum(&point_masses(
        model,
        pd,
        old,
        (&touched, &switched),
        (vertex_u, vertex_v),
        (particles.displacements, particles.velocities),
    ));
    // Mass shares: old leave at their vertices' velocities, new join at the particle's.
    // Only a particle that switched or whose host has a corner slaved or freed can move
    // mass: those, ascending (the order the vertices' sums take).
    let mut candidates = switched.clone();
    for a in (0..nv).filter(|&a| old.slaved[a] != new.slaved[a]) {
        let slots = &pd.slots[pd.slot_offsets[a] as usize..pd.slot_offsets[a + 1] as usize];
        candidates.extend(slots.iter().map(|&slot| slot as usize / 4));
    }
    candidates.sort_unstable();
    candidates.dedup();
    let mut joined = vec![Vec3::ZERO; nv];
    for q in candidates {
        let was_follower = !old.dynamic[q];
        let is_follower = !new.dynamic[q];
        let corners_changed = model.tets[pd.host[q] as usize]
            .iter()
            .any(|&a| old.slaved[a as usize] != new.slaved[a as usize]);
        if was_follower == is_follower && !(is_follower && corners_changed) {
            continue;
        }
        let before = shares(model, pd, old, q);
        // The velocity its mass carries: a follower's old lumped velocity, a dynamic
        // particle's own.
        let carried = if was_follower {
            before
                .iter()
                .fold(Vec3::ZERO, |s, &(a, w)| s + load3(vertex_v, a as usize) * w)
        } else {
            load3(particles.velocities, q)
        };
        if is_follower {
            for (a, w) in shares(model, pd, new, q) {
                let a = a as usize;
                joined[a] += (carried - load3(vertex_v, a)) * (w * pd.mass);
            }
        } else {
            store3(particles.velocities, q, carried);
        }
    }
    for a in 0..nv {
        if new.slaved[a] || model.inv_mass[a] == 0.0 || joined[a] == Vec3::ZERO {
            continue;
        }
        let v = load3(vertex_v, a) + joined[a] / new.vertex_mass[a];
        store3(vertex_v, a, v);
    }
    // The angular momentum the moved masses carried: mass that changes hands between a
    // vertex and a particle (or another vertex) changes place, so the re-lump alone keeps Σ m v
    // but not Σ x × m v. The difference goes back as a rigid spin of the touched masses about
    // their centre, v += δω × (x − c) with I δω = ΔL, which leaves Σ m v as it is.
    let after = point_masses(
        model,
        pd,
        new,
        (&touched, &switched),
        (vertex_u, vertex_v),
        (particles.displacements, particles.velocities),
    );
    let dl = l_before - angular_momentum(&after);
    // Too few touched masses to spin (one vertex that took a released particle's mass whose
    // other corners are slaved, say): spin every dynamic particle with them.
    let (after, spin) = match spin_back(&after, dl) {
        Some(spin) => (after, Some(spin)),
        None => {
            let dynamic: Vec<usize> = (0..n)
                .filter(|&q| new.dynamic[q] && old.dynamic[q])
                .collect();
            let mut wider = after;
            wider.extend(point_masses(
                model,
                pd,
                new,
                (&[], &dynamic),
                (vertex_u, vertex_v),
                (particles.displacements, particles.velocities),
            ));
            let spin = spin_back(&wider, dl);
            (wider, spin)
        }
    };
    if let Some((centre, dw)) = spin {
        for p in after {
            let v = p.velocity + dw.cross(p.position - centre);
            match p.index {
                Lump::Vertex(a) => store3(vertex_v, a, v.as_vec3()),
                Lump::Particle(q) => store3(particles.velocities, q, v.as_vec3()),
            }
        }
    }
    // Fading offsets of the slaved vertices whose fit is new.
    for v in 0..nv {
        if !new.slaved[v] {
            store3(&mut offsets.offset, v, Vec3::ZERO);
            offsets.timer[v] = 0.0;
            continue;
        }
        if old.slaved[v] && old.fit[v] == new.fit[v] {
            continue;
        }
        if old.slaved[v] {
            // Refit: keep where it is now (its old fit plus what was left of its offset).
        } else {
            counts.newly_slaved += 1;
        }
        let fit = new.fit[v].iter().fold(Vec3::ZERO, |s, &(q, w)| {
            s + load3(particles.displacements, q as usize) * w
        });
        store3(&mut offsets.offset, v, load3(vertex_u, v) - fit);
        offsets.timer[v] = 0.0;
    }
    counts.freed = (0..nv).filter(|&v| old.slaved[v] && !new.slaved[v]).count() as u32;
    place_slaved(
        new,
        offsets,
        blend,
        (vertex_u, vertex_v),
        (particles.displacements, particles.velocities),
    );
    Ok((fresh, counts))
}

/// Whose mass a [`PointMass`] is.
#[derive(Clone, Copy, Debug)]
enum Lump {
    Vertex(usize),
    Particle(usize),
}

/// A lumped mass at its current place.
struct PointMass {
    index: Lump,
    position: DVec3,
    mass: f64,
    velocity: DVec3,
}

/// The masses under `slaving` among the given vertices (free ones: their lumped mass) and
/// particles (dynamic ones: the particle mass).
fn point_masses(
    model: &Model,
    pd: &Particles,
    slaving: &Slaving,
    (vertices, particles): (&[usize], &[usize]),
    (vertex_u, vertex_v): (&[f32], &[f32]),
    (particle_u, particle_v): (&[f32], &[f32]),
) -> Vec<PointMass> {
    let vertex = vertices
        .iter()
        .filter(|&&a| !slaving.slaved[a])
        .map(|&a| PointMass {
            index: Lump::Vertex(a),
            position: (load3(&model.rest, a) + load3(vertex_u, a)).as_dvec3(),
            mass: slaving.vertex_mass[a] as f64,
            velocity: load3(vertex_v, a).as_dvec3(),
        });
    let particle = particles
        .iter()
        .filter(|&&q| slaving.dynamic[q])
        .map(|&q| PointMass {
            index: Lump::Particle(q),
            position: (pd.rest_position(q) + load3(particle_u, q)).as_dvec3(),
            mass: pd.mass as f64,
            velocity: load3(particle_v, q).as_dvec3(),
        });
    vertex.chain(particle).collect()
}

/// Σ x × m v.
fn angular_momentum(masses: &[PointMass]) -> DVec3 {
    masses.iter().fold(DVec3::ZERO, |l, p| {
        l + p.position.cross(p.velocity * p.mass)
    })
}

/// The centre c = Σ m x / Σ m of `masses` and the spin δω = I⁻¹ ΔL about it (I = Σ m (|r|² 𝟙
/// − r rᵀ), r = x − c); None for no change or masses too nearly on a line to spin
/// (det I ≤ 10⁻⁹ (tr I / 3)³).
fn spin_back(masses: &[PointMass], dl: DVec3) -> Option<(DVec3, DVec3)> {
    let total: f64 = masses.iter().map(|p| p.mass).sum();
    if dl == DVec3::ZERO || total <= 0.0 {
        return None;
    }
    let centre = masses
        .iter()
        .fold(DVec3::ZERO, |c, p| c + p.position * p.mass)
        / total;
    let mut inertia = DMat3::ZERO;
    for p in masses {
        let r = p.position - centre;
        inertia += (DMat3::IDENTITY * r.length_squared()
            - DMat3::from_cols(r * r.x, r * r.y, r * r.z))
            * p.mass;
    }
    let trace = (inertia.x_axis.x + inertia.y_axis.y + inertia.z_axis.z) / 3.0;
    (trace > 0.0 && inertia.determinant() > 1e-9 * trace * trace * trace)
        .then(|| (centre, inertia.inverse() * dl))
}
