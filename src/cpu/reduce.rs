//! CPU twin of `kernels/reduce.wgsl`: a two-level tree reduction (blocks of 256, then one
//! block over the partials) of kinetic energy, elastic energy, max speed, residual, external
//! load and mass-weighted squared displacement, in the same order as the GPU.

use super::load3;
use crate::params::{stat, StepParams};
use glam::Vec3;

/// Threads per reduce workgroup.
pub const REDUCE_WORKGROUP: usize = 256;
/// Quantities per partial: ke, elastic, max speed, residual², external², Σ m|u|².
pub const PARTIAL_LEN: usize = 6;

/// Number of partials `reduce_partial` writes.
pub fn n_partials(params: &StepParams) -> usize {
    (params.n_vertices.max(params.n_tets) as usize).div_ceil(REDUCE_WORKGROUP)
}

/// Tree-reduce 256 lanes in place like the workgroup loop: stride 128, 64, …, 1.
fn tree(lanes: &mut [[f32; PARTIAL_LEN]; REDUCE_WORKGROUP]) -> [f32; PARTIAL_LEN] {
    let mut s = REDUCE_WORKGROUP / 2;
    while s > 0 {
        for l in 0..s {
            let o = lanes[l + s];
            let a = &mut lanes[l];
            a[0] += o[0];
            a[1] += o[1];
            a[2] = a[2].max(o[2]);
            a[3] += o[3];
            a[4] += o[4];
            a[5] += o[5];
        }
        s /= 2;
    }
    lanes[0]
}

/// Per block of 256 indices i (vertex i and tet i; blocks in parallel, each reduced in the
/// fixed tree order): write 6 partial sums to `partials`. With `contact`, the external load
/// includes the contact force of surface vertices.
#[allow(clippy::too_many_arguments)]
pub fn reduce_partial(
    params: &StepParams,
    displacements: &[f32],
    velocities: &[f32],
    mass: &[f32],
    inv_mass: &[f32],
    forces: &[f32],
    external_forces: &[f32],
    tet_energy: &[f32],
    partials: &mut [f32],
    surface_index: &[u32],
    contact_forces: &[f32],
    contact: bool,
) {
    let g = Vec3::from_array(params.gravity);
    super::par::for_each_chunk::<PARTIAL_LEN>(partials, n_partials(params), |block, out| {
        let mut lanes = [[0.0f32; PARTIAL_LEN]; REDUCE_WORKGROUP];
        for (l, lane) in lanes.iter_mut().enumerate() {
            let i = block * REDUCE_WORKGROUP + l;
            if i < params.n_vertices as usize {
                let v = load3(velocities, i);
                lane[0] = 0.5 * mass[i] * v.dot(v);
                lane[2] = v.length();
                if inv_mass[i] > 0.0 {
                    let f = load3(forces, i);
                    lane[3] = f.dot(f);
                    let mut w = g * mass[i] + load3(external_forces, i);
                    if contact {
                        let s = surface_index[i];
                        if s != crate::contact::NOT_ON_SURFACE {
                            w += load3(contact_forces, s as usize);
                        }
                    }
                    lane[4] = w.dot(w);
                }
                let u = load3(displacements, i);
                lane[5] = mass[i] * u.dot(u);
            }
            if i < params.n_tets as usize {
                lane[1] = tet_energy[i];
            }
        }
        out.copy_from_slice(&tree(&mut lanes));
    });
}

/// One block: lane l sums partials l, l+256, …; then the tree. Writes `stats`.
pub fn reduce_final(params: &StepParams, partials: &[f32], stats: &mut [f32]) {
    let n = n_partials(params);
    let mut lanes = [[0.0f32; PARTIAL_LEN]; REDUCE_WORKGROUP];
    for (l, lane) in lanes.iter_mut().enumerate() {
        let mut k = l;
        while k < n {
            let p = &partials[PARTIAL_LEN * k..PARTIAL_LEN * k + PARTIAL_LEN];
            lane[0] += p[0];
            lane[1] += p[1];
            lane[2] = lane[2].max(p[2]);
            lane[3] += p[3];
            lane[4] += p[4];
            lane[5] += p[5];
            k += REDUCE_WORKGROUP;
        }
    }
    let r = tree(&mut lanes);
    stats[stat::KINETIC] = r[0];
    stats[stat::ELASTIC] = r[1];
    stats[stat::MAX_SPEED] = r[2];
    stats[stat::RESIDUAL_SQ] = r[3];
    stats[stat::EXTERNAL_SQ] = r[4];
    stats[stat::MASS_DISPLACEMENT_SQ] = r[5];
}
