//! CPU twin of `kernels/fem_forces_split.wgsl`: per tet, the volume/shape split laws
//! (`MATERIAL` 3–6: `stvk_split`, `stable_neohookean_split`, `corotational_split`,
//! `guccione`; formulas in `src/material.rs`). H = Du·Dm⁻¹, F = I + H;
//! P = P_iso(F̄) + p cof F (+ the viscous F·S_v of paper eq. 3–4), where the pressure p is
//! U′(J_e) of the tet itself (`NODAL_PRESSURE` off) or the mean of its four vertex
//! pressures p̄_e = ¼ Σ_c p_{t_c} from the `nodal_pressure` stage (on: Bonet & Burton 1998
//! average nodal Jacobian, NiftySim's T4ANP volume term). Corner forces −V·P·Dm⁻ᵀ; energy
//! V (Ψ_iso + U(J_e)), or V (Ψ_iso + ¼ Σ_c U_{t_c}) with the nodal average, whose sum over
//! tets is Σ_e V_e Ψ_iso + Σ_a V_a U(J_a), the energy the forces derive from.

use super::fem_forces::{
    corner_forces_of_stress, displacement_gradient, load_dm_inv, viscous_first_piola,
};
use super::load3;
use crate::material::{
    isochoric_stress_energy, volumetric_energy_pressure, MaterialConstants, MaterialModel,
    VolumetricLaw,
};
use crate::params::StepParams;
use glam::Vec3;

/// The pipeline constants of `fem_forces_split.wgsl`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SplitVariant {
    /// `MATERIAL` constant (one of [`MaterialModel::SPLIT`]).
    pub model: MaterialModel,
    /// `VISCOUS` constant.
    pub viscous: bool,
    /// `VOLUMETRIC` constant: U(J).
    pub volumetric: VolumetricLaw,
    /// `NODAL_PRESSURE` constant: the volume term from the vertex pressures.
    pub nodal_pressure: bool,
}

/// Unit fibre of tet `e` when the law is fibred (Guccione with b_f, b_t, b_fs not all
/// equal), else zero (the isotropic case reads no fibre).
#[inline]
pub fn tet_fibre(material: &MaterialConstants, fibres: &[f32], e: usize) -> Vec3 {
    if material.is_fibred() {
        let f = load3(fibres, e);
        f * (1.0 / f.dot(f).max(1e-30).sqrt())
    } else {
        Vec3::ZERO
    }
}

/// Corner forces and energy of one tet from its corner displacements `u`, velocities `v`,
/// unit fibre, and (with `nodal_pressure`) its corners' vertex pressures and volumetric
/// energy densities. Returns ([f₀, f₁, f₂, f₃], V·Ψ).
#[allow(clippy::too_many_arguments)]
pub fn tet_forces_split(
    params: &StepParams,
    material: &MaterialConstants,
    u: [Vec3; 4],
    v: [Vec3; 4],
    dmi: glam::Mat3,
    volume: f32,
    fibre: Vec3,
    corner_pressure: [f32; 4],
    corner_volumetric_energy: [f32; 4],
    variant: SplitVariant,
) -> ([Vec3; 4], f32) {
    let h = displacement_gradient(u, dmi);
    let (mut p, psi_iso, k) = isochoric_stress_energy(variant.model, h, params.mu, material, fibre);
    let (pressure, u_vol) = if variant.nodal_pressure {
        (
            0.25 * (corner_pressure[0]
                + corner_pressure[1]
                + corner_pressure[2]
                + corner_pressure[3]),
            0.25 * (corner_volumetric_energy[0]
                + corner_volumetric_energy[1]
                + corner_volumetric_energy[2]
                + corner_volumetric_energy[3]),
        )
    } else {
        let (u_vol, pressure) =
            volumetric_energy_pressure(variant.volumetric, material.bulk_modulus, k.j_minus_1);
        (pressure, u_vol)
    };
    p += k.cof_f * pressure;
    if variant.viscous {
        p += viscous_first_piola(params, h, v, dmi);
    }
    (
        corner_forces_of_stress(p, dmi, volume),
        volume * (psi_iso + u_vol),
    )
}

/// Per tet e (in parallel, one index per tet as on the GPU): corner force c to
/// `corner_forces[(4e + c)·3 ..]`, V·Ψ to `tet_energy[e]`.
/// `fibres` is read only for a fibred law, `vertex_pressure` and
/// `vertex_volumetric_energy` only with `nodal_pressure` (they may be empty otherwise).
#[allow(clippy::too_many_arguments)]
pub fn fem_forces_split(
    params: &StepParams,
    material_constants: &MaterialConstants,
    displacements: &[f32],
    velocities: &[f32],
    tets: &[[u32; 4]],
    dm_inv: &[f32],
    rest_volume: &[f32],
    fibres: &[f32],
    vertex_pressure: &[f32],
    vertex_volumetric_energy: &[f32],
    corner_forces: &mut [f32],
    tet_energy: &mut [f32],
    variant: SplitVariant,
) {
    super::par::for_each_chunk2::<12, 1>(
        corner_forces,
        tet_energy,
        params.n_tets as usize,
        |e, corner, energy| {
            let t = tets[e];
            let u = t.map(|i| load3(displacements, i as usize));
            let v = if variant.viscous {
                t.map(|i| load3(velocities, i as usize))
            } else {
                [Vec3::ZERO; 4]
            };
            let (corner_pressure, corner_energy) = if variant.nodal_pressure {
                (
                    t.map(|i| vertex_pressure[i as usize]),
                    t.map(|i| vertex_volumetric_energy[i as usize]),
                )
            } else {
                ([0.0; 4], [0.0; 4])
            };
            let (forces, psi) = tet_forces_split(
                params,
                material_constants,
                u,
                v,
                load_dm_inv(dm_inv, e),
                rest_volume[e],
                tet_fibre(material_constants, fibres, e),
                corner_pressure,
                corner_energy,
                variant,
            );
            for (c, f) in forces.iter().enumerate() {
                super::store3(corner, c, *f);
            }
            energy[0] = psi;
        },
    );
}
