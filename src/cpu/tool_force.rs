//! CPU twin of `kernels/tool_force.wgsl`: the force on the tool and its frozen-tissue
//! stiffness, reduced over surface vertices and the dynamic particles in the GPU's fixed tree
//! order (blocks of 128 surface vertices, then blocks of 128 entries of the dynamic list, then
//! one block over the partials).

use super::contact::{contact_force, tool_velocity};
use super::load3;
use crate::contact::{ToolInput, ToolParams, ToolState, REPORT_LEN};
use crate::params::StepParams;
use glam::Vec3;

/// Threads per tool_force workgroup.
pub const TOOL_WORKGROUP: usize = 128;
/// Floats per lane: force (3), stiffness (9), max penetration, contacts, area.
pub const LANE: usize = 15;
const MAX_SLOT: usize = 12;

/// The most partials `tool_force_partial` and `tool_force_particles` write (the buffer's
/// size: every particle dynamic).
pub fn n_partials(tool_params: &ToolParams) -> usize {
    (tool_params.n_surface as usize).div_ceil(TOOL_WORKGROUP)
        + (tool_params.n_particles as usize).div_ceil(TOOL_WORKGROUP)
}

fn combine(a: &mut [f32; LANE], o: &[f32; LANE]) {
    for k in 0..LANE {
        if k == MAX_SLOT {
            a[k] = a[k].max(o[k]);
        } else {
            a[k] += o[k];
        }
    }
}

fn tree(lanes: &mut [[f32; LANE]; TOOL_WORKGROUP]) -> [f32; LANE] {
    let mut s = TOOL_WORKGROUP / 2;
    while s > 0 {
        for l in 0..s {
            let o = lanes[l + s];
            combine(&mut lanes[l], &o);
        }
        s /= 2;
    }
    lanes[0]
}

/// One surface vertex's lane: −f (force on the tool), k A [(R/r)(I − n nᵀ) − I], d, 1, A.
fn lane(p: &ToolParams, x: Vec3, v: Vec3, c: Vec3, vc: Vec3, area: f32) -> [f32; LANE] {
    let mut lane = [0.0f32; LANE];
    let ct = contact_force(p, x, v, c, vc, area);
    if ct.penetration > 0.0 {
        let n = ct.normal.to_array();
        let a = p.radius / ct.distance;
        let ka = p.stiffness * area;
        lane[0] = -ct.force.x;
        lane[1] = -ct.force.y;
        lane[2] = -ct.force.z;
        for col in 0..3 {
            for row in 0..3 {
                let delta = if row == col { 1.0 } else { 0.0 };
                lane[3 + 3 * col + row] = ka * (a * (delta - n[row] * n[col]) - delta);
            }
        }
        lane[12] = ct.penetration;
        lane[13] = 1.0;
        lane[14] = area;
    }
    lane
}

/// Per block of 128 surface vertices: the block's partial lane (tool where the batch left it,
/// [`super::contact::tool_batch_end`]).
#[allow(clippy::too_many_arguments)]
pub fn tool_force_partial(
    params: &StepParams,
    tool_params: &ToolParams,
    tool_input: &ToolInput,
    tool_state: &ToolState,
    surface_vertices: &[u32],
    surface_area: &[f32],
    rest_positions: &[f32],
    displacements: &[f32],
    velocities: &[f32],
    tool_partials: &mut [f32],
    contact_weight: Option<&[f32]>,
) {
    let vc = tool_velocity(params, tool_input);
    let c = super::contact::tool_batch_end(tool_input, tool_state);
    let n = tool_params.n_surface as usize;
    let blocks = n.div_ceil(TOOL_WORKGROUP);
    super::par::for_each_chunk::<LANE>(tool_partials, blocks, |block, out| {
        let mut lanes = [[0.0f32; LANE]; TOOL_WORKGROUP];
        for (l, slot) in lanes.iter_mut().enumerate() {
            let s = block * TOOL_WORKGROUP + l;
            if s < n {
                let i = surface_vertices[s] as usize;
                let x = load3(rest_positions, i) + load3(displacements, i);
                *slot = lane(
                    tool_params,
                    x,
                    load3(velocities, i),
                    c,
                    vc,
                    surface_area[s] * contact_weight.map_or(1.0, |w| w[i]),
                );
            }
        }
        out.copy_from_slice(&tree(&mut lanes));
    });
}

/// Per block of 128 entries of `dynamic_list` (after the vertices' blocks): the dynamic
/// surface particles' contact lanes (twin of `tool_force_particles`; the list is the last
/// activation's, written and checkpointed with the modes; the mode is checked all the same).
#[allow(clippy::too_many_arguments)]
pub fn tool_force_particles(
    params: &StepParams,
    tool_params: &ToolParams,
    tool_input: &ToolInput,
    tool_state: &ToolState,
    particle_mode: &[u32],
    particle_rest: &[f32],
    particle_displacements: &[f32],
    particle_velocities: &[f32],
    particle_area: &[f32],
    particle_gradient: &[f32],
    particle_contact_offset: &[f32],
    dynamic_list: &[u32],
    tool_partials: &mut [f32],
) {
    let vc = tool_velocity(params, tool_input);
    let c = super::contact::tool_batch_end(tool_input, tool_state);
    let n = dynamic_list.len();
    let first = (tool_params.n_surface as usize).div_ceil(TOOL_WORKGROUP);
    super::par::for_each_chunk::<LANE>(
        &mut tool_partials[LANE * first..],
        n.div_ceil(TOOL_WORKGROUP),
        |block, out| {
            let mut lanes = [[0.0f32; LANE]; TOOL_WORKGROUP];
            for (l, slot) in lanes.iter_mut().enumerate() {
                let d = block * TOOL_WORKGROUP + l;
                let p = dynamic_list.get(d).map_or(0, |&p| p as usize);
                if d < n
                    && particle_mode[p] & crate::particles::params::mode::DYNAMIC != 0
                    && particle_area[p] > 0.0
                {
                    let f =
                        glam::Mat3::IDENTITY + super::fem_forces::load_dm_inv(particle_gradient, p);
                    let x = load3(particle_rest, p)
                        + load3(particle_displacements, p)
                        + f * load3(particle_contact_offset, p);
                    *slot = lane(
                        tool_params,
                        x,
                        load3(particle_velocities, p),
                        c,
                        vc,
                        particle_area[p],
                    );
                }
            }
            out.copy_from_slice(&tree(&mut lanes));
        },
    );
}

/// One block: lane l combines partials l, l+128, … of the vertices' blocks and the
/// ceil(`dynamic`/128) blocks of the dynamic list; then the tree. Writes `tool_report`.
pub fn tool_force_final(
    tool_params: &ToolParams,
    dynamic: usize,
    tool_partials: &[f32],
    tool_report: &mut [f32],
) {
    let n = (tool_params.n_surface as usize).div_ceil(TOOL_WORKGROUP)
        + dynamic.div_ceil(TOOL_WORKGROUP);
    let mut lanes = [[0.0f32; LANE]; TOOL_WORKGROUP];
    for (l, lane) in lanes.iter_mut().enumerate() {
        let mut b = l;
        while b < n {
            let p: [f32; LANE] = tool_partials[LANE * b..LANE * b + LANE]
                .try_into()
                .expect("LANE floats");
            combine(lane, &p);
            b += TOOL_WORKGROUP;
        }
    }
    let r = tree(&mut lanes);
    tool_report[..LANE].copy_from_slice(&r);
    tool_report[REPORT_LEN - 1] = 0.0;
}
