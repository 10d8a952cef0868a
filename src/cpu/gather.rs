//! CPU twin of `kernels/gather.wgsl`: per vertex, f = m·g + f_ext + Σ incident corner forces
//! (no atomics, deterministic); `gather_coupled` adds the tool's contact force and the
//! embedded particles' forces. The kernel gives each vertex [`LANES`] threads; the twin sums
//! in the same order: lane j takes the list entries j, j + LANES, … (for the particle slots,
//! the j-th, (j + LANES)-th, … slot that passes the filter, which is the kernel's order over
//! its short list), and the lanes are added in lane order.

use super::{load3, store3};
use crate::params::StepParams;
use glam::{Vec3, Vec3A};

/// Threads per vertex in `gather.wgsl` (its `LANES`).
pub const LANES: usize = 4;
// `corner_lanes` spells the four lanes out.
const _: () = assert!(LANES == 4);

/// Σ over `lanes` in lane order: ((s₀ + s₁) + s₂) + s₃, as the kernel's `add_lanes`.
fn add_lanes(lanes: &[Vec3A; LANES]) -> Vec3 {
    Vec3::from(lanes[1..].iter().fold(lanes[0], |f, &s| f + s))
}

/// Each lane's share of vertex i's incident corner forces.
fn corner_lanes(
    corner_forces: &[f32],
    incidence_offsets: &[u32],
    incidence: &[u32],
    i: usize,
) -> [Vec3A; LANES] {
    let mut lanes = [Vec3A::ZERO; LANES];
    let (first, last) = (
        incidence_offsets[i] as usize,
        incidence_offsets[i + 1] as usize,
    );
    let corner = |c: u32| Vec3A::from(load3(corner_forces, c as usize));
    // Constant lane indices in the full chunks keep the four sums in registers.
    let mut chunks = incidence[first..last].chunks_exact(LANES);
    for ch in &mut chunks {
        lanes[0] += corner(ch[0]);
        lanes[1] += corner(ch[1]);
        lanes[2] += corner(ch[2]);
        lanes[3] += corner(ch[3]);
    }
    for (lane, &c) in lanes.iter_mut().zip(chunks.remainder()) {
        *lane += corner(c);
    }
    lanes
}

/// Per vertex i: `forces[i] = (mass[i]·g + external_forces[i]) + Σ_{k ∈ offsets[i]..offsets[i+1]} corner_forces[incidence[k]]`,
/// the sum taken in the kernel's lane order (twin of entry `gather`).
pub fn gather(
    params: &StepParams,
    corner_forces: &[f32],
    incidence_offsets: &[u32],
    incidence: &[u32],
    mass: &[f32],
    external_forces: &[f32],
    forces: &mut [f32],
) {
    let g = Vec3::from_array(params.gravity);
    super::par::for_each_chunk::<3>(forces, params.n_vertices as usize, |i, out| {
        let lanes = corner_lanes(corner_forces, incidence_offsets, incidence, i);
        let f = g * mass[i] + load3(external_forces, i) + add_lanes(&lanes);
        store3(out, 0, f);
    });
}

/// What `gather_coupled` adds to a vertex: the tool's contact force (when there is a tool)
/// and the particle coupling (when there are particles).
pub struct Coupling<'a> {
    /// Per vertex, its surface index (tool scenes; empty otherwise).
    pub surface_index: &'a [u32],
    /// Contact force per surface vertex.
    pub contact_forces: &'a [f32],
    /// The scene has a tool (`CONTACT`).
    pub contact: bool,
    /// Per vertex flags (`NODE_COUPLED`).
    pub node_flags: &'a [u32],
    /// CSR vertex → particle slots.
    pub slot_offsets: &'a [u32],
    /// Particle slots p·4 + corner.
    pub slots: &'a [u32],
    /// Barycentric weights, 4 per particle.
    pub weights: &'a [f32],
    /// Particle modes.
    pub mode: &'a [u32],
    /// Particle force sums over the sub-steps.
    pub force_sum: &'a [f32],
    /// The scene has particles (`PARTICLES`).
    pub particles: bool,
}

/// Twin of entry `gather_coupled`: [`gather`] plus Σ wᵢ f_p over the embedded particles of
/// the force set it hosts (in the lanes, after the corners) and the contact force of a surface
/// vertex (last).
#[allow(clippy::too_many_arguments)]
pub fn gather_coupled(
    params: &StepParams,
    corner_forces: &[f32],
    incidence_offsets: &[u32],
    incidence: &[u32],
    mass: &[f32],
    external_forces: &[f32],
    forces: &mut [f32],
    c: &Coupling,
) {
    let g = Vec3::from_array(params.gravity);
    super::par::for_each_chunk::<3>(forces, params.n_vertices as usize, |i, out| {
        let mut lanes = corner_lanes(corner_forces, incidence_offsets, incidence, i);
        if c.particles && c.node_flags[i] & crate::particles::params::NODE_COUPLED != 0 {
            use crate::particles::params::mode;
            let mut passed = 0;
            for k in c.slot_offsets[i]..c.slot_offsets[i + 1] {
                let slot = c.slots[k as usize] as usize;
                let p = slot / 4;
                let m = c.mode[p];
                if m & mode::IN_F != 0 && m & mode::DYNAMIC == 0 {
                    lanes[passed % LANES] += Vec3A::from(load3(c.force_sum, p) * c.weights[slot]);
                    passed += 1;
                }
            }
        }
        let mut f = g * mass[i] + load3(external_forces, i) + add_lanes(&lanes);
        if c.contact {
            let s = c.surface_index[i];
            if s != crate::contact::NOT_ON_SURFACE {
                f += load3(c.contact_forces, s as usize);
            }
        }
        store3(out, 0, f);
    });
}

/// The CPU path's short list of what `gather_coupled` adds per coupled vertex: for each
/// vertex with `NODE_COUPLED`, its slots (in CSR order) whose particle is in the force set
/// and not dynamic, built once per activation. Modes change only at an activation, so until
/// the particle state is replaced the filter in [`gather_coupled`] passes exactly these
/// slots, in the same order: summing over them gives the same bits as walking every slot.
#[derive(Debug, Default, PartialEq)]
pub(crate) struct CoupledSlots {
    /// CSR offsets per vertex (n_vertices + 1).
    pub offsets: Vec<u32>,
    /// Slots p·4 + corner.
    pub slots: Vec<u32>,
    /// Built from the current modes; false after the particle state was replaced.
    pub valid: bool,
}

impl Clone for CoupledSlots {
    fn clone(&self) -> Self {
        let mut c = CoupledSlots::default();
        c.clone_from(self);
        c
    }

    /// Copies into the existing buffers (a checkpoint every batch allocates nothing).
    fn clone_from(&mut self, s: &Self) {
        self.offsets.clone_from(&s.offsets);
        self.slots.clone_from(&s.slots);
        self.valid = s.valid;
    }
}

impl CoupledSlots {
    /// Rebuild from the vertex flags and particle modes an activation left.
    pub fn rebuild(
        &mut self,
        node_flags: &[u32],
        slot_offsets: &[u32],
        slots: &[u32],
        particle_mode: &[u32],
    ) {
        use crate::particles::params::{mode, NODE_COUPLED};
        self.offsets.clear();
        self.slots.clear();
        self.offsets.push(0);
        for (i, &flags) in node_flags.iter().enumerate() {
            if flags & NODE_COUPLED != 0 {
                // Every slot is written and the length advances only for a kept one (the
                // modes make the test's outcome unpredictable; a branch on it costs more).
                let range = slot_offsets[i] as usize..slot_offsets[i + 1] as usize;
                let mut len = self.slots.len();
                self.slots.resize(len + range.len(), 0);
                for &slot in &slots[range] {
                    let m = particle_mode[slot as usize / 4];
                    self.slots[len] = slot;
                    len += (m & mode::IN_F != 0 && m & mode::DYNAMIC == 0) as usize;
                }
                self.slots.truncate(len);
            }
            self.offsets.push(self.slots.len() as u32);
        }
        self.valid = true;
    }
}
