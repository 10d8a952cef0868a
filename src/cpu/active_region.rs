//! Where an activation can change anything, so the CPU stepper runs the activation's twins
//! there alone (the kernel runs them over every particle, tet and vertex).
//!
//! A particle is *live* when it has any mode bit besides `PINNED` (dynamic, blending, in the
//! stress or force set). An activation changes only live particles and those the tool can
//! reach; a tet's weight differs from 1 only while it hosts stress-set particles; a vertex's
//! relump differs from its all-embedded value only while it hosts force-set or released
//! particles (the relump leaves v exactly when no released particle is hosted). So after one
//! full pass, each activation visits: the live particles and those of tets near the tool; the
//! tets that host stress-set particles now or did at the last activation; the vertices that
//! host force-set or released particles now or did, plus the fixed and massless ones. The
//! results are bit-equal to the full pass (`tests/hybrid.rs` compares them along hm1's
//! press and release, and checks the tet bound against the particles' own distances). Scenes
//! without a tool, or with `activation = "all"`, take the full pass at every activation.

use super::activate::{update_particle, ModeArrays, ModeInputs, ModeState};
use crate::particles::params::mode;
use crate::particles::Particles;
use glam::DVec3;

/// A tet's particles at rest: the centre and radius of a sphere holding them, and their
/// largest Σ|wᵢ| (1 for a particle inside its host; kept general rather than assumed).
#[derive(Clone, Copy, Debug)]
struct TetBound {
    centre: DVec3,
    radius: f64,
    reach: f64,
}

/// The sets one activation leaves for the next (see the module comment).
#[derive(Clone, Debug, Default)]
pub struct ActiveRegion {
    /// Per tet (None: it hosts no particle).
    bounds: Vec<Option<TetBound>>,
    /// Per block of [`TETS_PER_BLOCK`] consecutive tets, a bound holding every particle of
    /// its tets (None: no tet of it hosts a particle): the candidate search skips a block the
    /// tool cannot reach without looking at its tets.
    blocks: Vec<Option<TetBound>>,
    /// Vertices relumped at every activation: fixed, or massless with every particle embedded.
    always: Vec<u32>,
    /// Live particles after the last activation, ascending.
    live: Vec<u32>,
    /// Tets that hosted stress-set particles at the last activation.
    weighted_tets: Vec<u32>,
    /// Vertices that hosted force-set or released particles at the last activation.
    coupled_vertices: Vec<u32>,
    /// The sets describe the current state; false: the next activation is a full pass.
    primed: bool,
    /// Per vertex, false except while `vertices_to_relump` collects corners.
    vertex_seen: Vec<bool>,
}

/// Tets per block of [`ActiveRegion`]'s block bounds.
const TETS_PER_BLOCK: usize = 32;

/// A bound of the bounds `tets` (None when all are None): the centre of their centres' box,
/// the largest distance from it to a tet's centre plus that tet's radius, the largest reach.
fn block_bound(tets: &[Option<TetBound>]) -> Option<TetBound> {
    let present = || tets.iter().flatten();
    let (lo, hi) = present().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(a, b), t| (a.min(t.centre), b.max(t.centre)),
    );
    let centre = 0.5 * (lo + hi);
    let radius = present()
        .map(|t| (t.centre - centre).length() + t.radius)
        .fold(None, |r: Option<f64>, x| Some(r.map_or(x, |r| r.max(x))))?;
    let reach = present().map(|t| t.reach).fold(0.0, f64::max);
    Some(TetBound {
        centre,
        radius,
        reach,
    })
}

/// Sort and remove repeats.
fn sorted(mut v: Vec<u32>) -> Vec<u32> {
    v.sort_unstable();
    v.dedup();
    v
}

/// The union of two ascending lists without repeats, ascending.
fn merged(a: &[u32], b: &[u32]) -> Vec<u32> {
    let mut out = Vec::with_capacity(a.len() + b.len());
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        let (x, y) = (a[i], b[j]);
        out.push(x.min(y));
        i += (x <= y) as usize;
        j += (y <= x) as usize;
    }
    out.extend_from_slice(&a[i..]);
    out.extend_from_slice(&b[j..]);
    out
}

/// One particle after the mode machine: displacement, velocity, mode, timer, offset.
type UpdatedParticle = ([f32; 3], [f32; 3], u32, f32, [f32; 3]);

impl ActiveRegion {
    /// Bounds of every tet's particles and the always-relumped vertices (`node_fixed`: 1 per
    /// fixed vertex); not primed.
    pub fn new(s: &Particles, node_fixed: &[u32]) -> ActiveRegion {
        let n_tets = s.tet_offsets.len() - 1;
        let bounds = (0..n_tets)
            .map(|e| {
                let (first, last) = (s.tet_offsets[e] as usize, s.tet_offsets[e + 1] as usize);
                if first == last {
                    return None;
                }
                let x = |p: usize| {
                    DVec3::new(
                        s.rest[3 * p] as f64,
                        s.rest[3 * p + 1] as f64,
                        s.rest[3 * p + 2] as f64,
                    )
                };
                let (lo, hi) = (first..last).fold(
                    (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
                    |(a, b), p| (a.min(x(p)), b.max(x(p))),
                );
                let centre = 0.5 * (lo + hi);
                let radius = (first..last)
                    .map(|p| (x(p) - centre).length())
                    .fold(0.0, f64::max);
                let reach = (first..last)
                    .map(|p| {
                        s.weights[4 * p..4 * p + 4]
                            .iter()
                            .map(|w| w.abs() as f64)
                            .sum::<f64>()
                    })
                    .fold(0.0, f64::max);
                Some(TetBound {
                    centre,
                    radius,
                    reach,
                })
            })
            .collect::<Vec<_>>();
        let blocks = bounds.chunks(TETS_PER_BLOCK).map(block_bound).collect();
        // The all-embedded mass, summed as the relump sums it.
        let always = (0..node_fixed.len())
            .filter(|&i| {
                let mut m = s.core_mass[i];
                for k in s.slot_offsets[i]..s.slot_offsets[i + 1] {
                    m += s.weights[s.slots[k as usize] as usize] * s.mass;
                }
                // (a NaN mass takes the relump's massless branch too)
                node_fixed[i] != 0 || m <= 0.0 || m.is_nan()
            })
            .map(|i| i as u32)
            .collect();
        ActiveRegion {
            bounds,
            blocks,
            always,
            ..ActiveRegion::default()
        }
    }

    /// True when the next activation may visit the region alone.
    pub fn primed(&self) -> bool {
        self.primed
    }

    /// Forget the sets (after the particle state was replaced): the next activation is a
    /// full pass.
    pub fn forget(&mut self) {
        self.primed = false;
    }

    /// Particles the mode machine must visit: the live ones and those of every tet whose
    /// particles the tool may reach (|C − c| − ρ − reach·max|u| − R < activation radius plus a
    /// margin twice the per-particle skip's, so every particle left out would be skipped
    /// there too), ascending. A block of tets is skipped whole when its bound fails the same
    /// test with a margin at least each of its tets' (its tets' |C − c| − ρ are at least the
    /// block's, their reach at most the block's), so the result is that of the test per tet.
    pub fn candidates(&self, inp: &ModeInputs, tet_offsets: &[u32]) -> Vec<u32> {
        let c = inp.centre.as_dvec3();
        let c_scale = c.abs().max_element();
        let radius = inp.tool_params.radius as f64;
        let limit = inp.pp.activation_radius as f64;
        let u_max = inp.u_max as f64;
        // The near tets' particles come out ascending (tets in order, each a run).
        let mut near = Vec::new();
        for (k, block) in self.blocks.iter().enumerate() {
            let Some(b) = block else { continue };
            let to_centre = (b.centre - c).length();
            // Each tet's margin term to_centre + ρ + |C| + ρ is at most the block's
            // to_centre + |C| + 2ρ_B (its centre lies within ρ_B − ρ of the block's); 4ρ_B
            // is a looser bound of it.
            let scale = b.centre.abs().max_element() + 4.0 * b.radius + c_scale;
            let margin = 2e-4 * (to_centre + scale + radius + 1.0);
            if to_centre - b.radius - b.reach * u_max - radius >= limit + margin {
                continue;
            }
            let first = k * TETS_PER_BLOCK;
            for (e, t) in self
                .bounds
                .iter()
                .enumerate()
                .skip(first)
                .take(TETS_PER_BLOCK)
            {
                let Some(b) = t else { continue };
                let to_centre = (b.centre - c).length();
                let scale = b.centre.abs().max_element() + b.radius + c_scale;
                let margin = 2e-4 * (to_centre + b.radius + scale + radius + 1.0);
                if to_centre - b.radius - b.reach * u_max - radius < limit + margin {
                    near.extend(tet_offsets[e]..tet_offsets[e + 1]);
                }
            }
        }
        merged(&self.live, &near)
    }

    /// The mode machine over `candidates` (in parallel; each particle is independent, so the
    /// result is that of the full pass over them). True when a particle became dynamic, was
    /// released or finished blending back (its `DYNAMIC` or `BLENDING` bit changed): only
    /// then can the sets, weights, masses and flags the activation derives differ from the
    /// last ones.
    pub fn update(inp: &ModeInputs, candidates: &[u32], state: ModeArrays) -> bool {
        use rayon::prelude::*;
        let updated: Vec<UpdatedParticle> = candidates
            .par_iter()
            .with_min_len(64)
            .map(|&p| {
                let p = p as usize;
                let xyz = |a: &[f32]| [a[3 * p], a[3 * p + 1], a[3 * p + 2]];
                let (mut u, mut v, mut o) = (
                    xyz(state.displacements),
                    xyz(state.velocities),
                    xyz(state.offset),
                );
                let (mut m, mut t) = (state.mode[p], state.timer[p]);
                update_particle(
                    inp,
                    p,
                    ModeState {
                        u: &mut u,
                        v: &mut v,
                        mode: &mut m,
                        timer: &mut t,
                        offset: &mut o,
                    },
                );
                (u, v, m, t, o)
            })
            .collect();
        let mut changed = false;
        for (&p, (u, v, m, t, o)) in candidates.iter().zip(updated) {
            let p = p as usize;
            changed |= (state.mode[p] ^ m) & (mode::DYNAMIC | mode::BLENDING) != 0;
            state.displacements[3 * p..3 * p + 3].copy_from_slice(&u);
            state.velocities[3 * p..3 * p + 3].copy_from_slice(&v);
            state.mode[p] = m;
            state.timer[p] = t;
            state.offset[3 * p..3 * p + 3].copy_from_slice(&o);
        }
        changed
    }

    /// The vertices an activation that changed no set must still relump (see
    /// [`ActiveRegion::update`]): the coupled vertices with no mass left (`inv_mass` < 0),
    /// whose velocity is their dynamic particles' mean. Every other vertex's relump would give
    /// back its mass, flags and velocity unchanged: a fixed vertex's velocity is already zero
    /// (`integrate` zeroes it), a vertex with mass keeps it when no particle was released,
    /// and a massless one that hosts no dynamic particle stays at rest. Ascending.
    pub fn kinematic_vertices<'a>(&'a self, inv_mass: &'a [f32]) -> impl Iterator<Item = u32> + 'a {
        self.coupled_vertices
            .iter()
            .copied()
            .filter(|&v| inv_mass[v as usize] < 0.0)
    }

    /// Mark `bit` on every particle of `sources` and on its neighbours; the particles that
    /// carry it now, ascending (the same set as [`super::activate::mark_set`] over all).
    pub fn mark(
        sources: &[u32],
        bit: u32,
        neighbour_offsets: &[u32],
        neighbours: &[u32],
        particle_mode: &mut [u32],
    ) -> Vec<u32> {
        // Every candidate is written and the count advances only for a new one (no branch
        // on the mode, whose outcome is unpredictable).
        let bound: usize = sources
            .iter()
            .map(|&p| {
                1 + (neighbour_offsets[p as usize + 1] - neighbour_offsets[p as usize]) as usize
            })
            .sum();
        let mut marked = vec![0u32; bound];
        let mut len = 0;
        let mut set = |p: usize| {
            let fresh = particle_mode[p] & bit == 0;
            particle_mode[p] |= bit;
            marked[len] = p as u32;
            len += fresh as usize;
        };
        for &p in sources {
            set(p as usize);
            for k in neighbour_offsets[p as usize]..neighbour_offsets[p as usize + 1] {
                set(neighbours[k as usize] as usize);
            }
        }
        marked.truncate(len);
        marked.sort_unstable();
        marked
    }

    /// Tets whose weight must be recomputed (hosts of `stress` now, or weighted at the last
    /// activation); remembers the hosts of `stress` for the next one.
    pub fn tets_to_weigh(&mut self, stress: &[u32], host: &[u32]) -> Vec<u32> {
        let now = sorted(stress.iter().map(|&p| host[p as usize]).collect());
        let mut all = std::mem::replace(&mut self.weighted_tets, now.clone());
        all.extend(now);
        sorted(all)
    }

    /// Vertices to relump: corners of the hosts of `coupled` (force-set or released
    /// particles) now or at the last activation, and the always-relumped ones; remembers the
    /// current corners for the next one.
    pub fn vertices_to_relump(
        &mut self,
        coupled: &[u32],
        host: &[u32],
        tets: &[[u32; 4]],
    ) -> Vec<u32> {
        // Each host tet's corners once: a per-vertex mark (cleared again below) instead of
        // sorting every corner of every particle.
        let seen = &mut self.vertex_seen;
        let mut now = Vec::new();
        let mut last_host = u32::MAX;
        for &p in coupled {
            let e = host[p as usize];
            if e == last_host {
                continue;
            }
            last_host = e;
            for v in tets[e as usize] {
                if seen.len() <= v as usize {
                    seen.resize(v as usize + 1, false);
                }
                if !seen[v as usize] {
                    seen[v as usize] = true;
                    now.push(v);
                }
            }
        }
        for &v in &now {
            seen[v as usize] = false;
        }
        now.sort_unstable();
        let all = merged(&merged(&self.coupled_vertices, &now), &self.always);
        self.coupled_vertices = now;
        all
    }

    /// After an activation: remember the live particles (force set ∪ blending) and mark the
    /// sets as describing the state.
    pub fn settle(&mut self, force_list: &[u32], blending: &[u32]) {
        let mut live = force_list.to_vec();
        live.extend_from_slice(blending);
        self.live = sorted(live);
        self.primed = true;
    }

    /// After a full pass: rebuild every set from the modes.
    pub fn prime(
        &mut self,
        particle_mode: &[u32],
        force_list: &[u32],
        stress_list: &[u32],
        host: &[u32],
        tets: &[[u32; 4]],
    ) {
        let blending: Vec<u32> = (0..particle_mode.len())
            .filter(|&p| particle_mode[p] & mode::BLENDING != 0)
            .map(|p| p as u32)
            .collect();
        let released: Vec<u32> = blending
            .iter()
            .copied()
            .filter(|&p| particle_mode[p as usize] & mode::RELEASED != 0)
            .collect();
        self.weighted_tets = sorted(stress_list.iter().map(|&p| host[p as usize]).collect());
        let mut coupled = force_list.to_vec();
        coupled.extend(released);
        self.coupled_vertices = sorted(
            coupled
                .iter()
                .flat_map(|&p| tets[host[p as usize] as usize])
                .collect(),
        );
        self.settle(force_list, &blending);
    }
}
