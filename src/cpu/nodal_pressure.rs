//! CPU twin of `kernels/nodal_pressure.wgsl`, the second stage of the average nodal
//! Jacobian (Bonet & Burton 1998, "A simple average nodal pressure tetrahedral element for
//! incompressible and nearly incompressible dynamic explicit applications", Commun. Numer.
//! Meth. Engng 14:437; the volume term of NiftySim's T4ANP, Joldes, Wittek & Miller 2009).
//!
//! Per vertex a, over its tets e (the CSR incidence list, in its fixed order):
//! J_a − 1 = Σ_e (v_e − V_e) / Σ_e V_e (the ratio of the deformed to the rest nodal volume,
//! V_a = Σ_e V_e / 4, v_a = Σ_e v_e / 4), then the vertex pressure p_a = U′(J_a) and the
//! volumetric energy density U(J_a). `fem_forces_split` with `NODAL_PRESSURE` applies
//! P_vol = p̄_e cof F_e, p̄_e = ¼ Σ_{a ∈ e} p_a, which is −∂/∂x of E_vol = Σ_a V_a U(J_a):
//! ∂v_a/∂x_b = Σ_{e ∋ a} ¼ V_e cof F_e ∇N_b, so ∂E_vol/∂x_b = Σ_e V_e (¼ Σ_{a∈e} p_a) cof F_e ∇N_b.
//! A vertex with no tet gets p = U = 0.

use crate::material::{volumetric_energy_pressure, MaterialConstants, VolumetricLaw};
use crate::params::StepParams;

/// Per vertex a: `vertex_pressure[a] = U′(J_a)` (Pa) and
/// `vertex_volumetric_energy[a] = U(J_a)` (J/m³), J_a as in the module docs.
#[allow(clippy::too_many_arguments)]
pub fn nodal_pressure(
    params: &StepParams,
    material_constants: &MaterialConstants,
    incidence_offsets: &[u32],
    incidence: &[u32],
    rest_volume: &[f32],
    tet_delta_volume: &[f32],
    vertex_pressure: &mut [f32],
    vertex_volumetric_energy: &mut [f32],
    volumetric: VolumetricLaw,
) {
    super::par::for_each_chunk2::<1, 1>(
        vertex_pressure,
        vertex_volumetric_energy,
        params.n_vertices as usize,
        |a, pressure, energy| {
            let mut volume = 0.0f32;
            let mut delta = 0.0f32;
            for k in incidence_offsets[a]..incidence_offsets[a + 1] {
                let e = (incidence[k as usize] / 4) as usize;
                volume += rest_volume[e];
                delta += tet_delta_volume[e];
            }
            let (u, p) = if volume > 0.0 {
                volumetric_energy_pressure(
                    volumetric,
                    material_constants.bulk_modulus,
                    delta / volume,
                )
            } else {
                (0.0, 0.0)
            };
            pressure[0] = p;
            energy[0] = u;
        },
    );
}
