//! CPU twin of `kernels/gather.wgsl`: per vertex, f = m·g + f_ext + Σ incident corner forces,
//! summed in CSR order (no atomics, deterministic), + the tool's contact force on a surface
//! vertex when `contact` (the `CONTACT` pipeline constant).

use super::{load3, store3};
use crate::params::StepParams;
use glam::Vec3;

/// Per vertex i: `forces[i] = mass[i]·g + external_forces[i] + Σ_{k ∈ offsets[i]..offsets[i+1]} corner_forces[incidence[k]]`
/// (+ `contact_forces[surface_index[i]]` when `contact` and i is on the surface).
#[allow(clippy::too_many_arguments)]
pub fn gather(
    params: &StepParams,
    corner_forces: &[f32],
    incidence_offsets: &[u32],
    incidence: &[u32],
    mass: &[f32],
    external_forces: &[f32],
    forces: &mut [f32],
    surface_index: &[u32],
    contact_forces: &[f32],
    contact: bool,
) {
    let g = Vec3::from_array(params.gravity);
    super::par::for_each_chunk::<3>(forces, params.n_vertices as usize, |i, out| {
        let mut f = g * mass[i] + load3(external_forces, i);
        for k in incidence_offsets[i]..incidence_offsets[i + 1] {
            f += load3(corner_forces, incidence[k as usize] as usize);
        }
        if contact {
            let s = surface_index[i];
            if s != crate::contact::NOT_ON_SURFACE {
                f += load3(contact_forces, s as usize);
            }
        }
        store3(out, 0, f);
    });
}
