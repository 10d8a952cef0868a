//! CPU twin of `kernels/tet_volume_change.wgsl`, the first stage of the average nodal
//! Jacobian (Bonet & Burton 1998; NiftySim T4ANP): per tet, the volume change
//! v_e − V_e = V_e (J_e − 1), with J − 1 = tr H + ½((tr H)² − tr H²) + det H computed from
//! H = Du·Dm⁻¹ without the cancellation of det F − 1 in f32.

use super::fem_forces::{displacement_gradient, load_dm_inv};
use super::load3;
use crate::material::jacobian_minus_one;
use crate::params::StepParams;

/// Per tet e: `tet_delta_volume[e] = rest_volume[e] · (J_e − 1)`, m³.
pub fn tet_volume_change(
    params: &StepParams,
    displacements: &[f32],
    tets: &[[u32; 4]],
    dm_inv: &[f32],
    rest_volume: &[f32],
    tet_delta_volume: &mut [f32],
) {
    super::par::for_each_chunk::<1>(tet_delta_volume, params.n_tets as usize, |e, out| {
        let u = tets[e].map(|i| load3(displacements, i as usize));
        let h = displacement_gradient(u, load_dm_inv(dm_inv, e));
        out[0] = rest_volume[e] * jacobian_minus_one(h);
    });
}
