//! CPU twin of `kernels/fem_forces.wgsl`: per tet, H = Du·Dm⁻¹, F = I + H, the material's
//! first Piola–Kirchhoff stress P (plus the viscous F·S_v of paper eq. 3–4), and the four
//! corner forces −V·P·Dm⁻ᵀ (paper eq. 6), plus the elastic energy V·Ψ.

use super::{load3, store3};
use crate::material::{elastic_stress_energy, green_strain_rate, stvk_second_piola, MaterialModel};
use crate::params::StepParams;
use glam::{Mat3, Vec3};

/// The pipeline constants of `fem_forces.wgsl`: which material, and whether viscous terms run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FemVariant {
    /// `MATERIAL` constant.
    pub model: MaterialModel,
    /// `VISCOUS` constant.
    pub viscous: bool,
}

/// Dm⁻¹ of tet `e` from the packed column-major array (9 floats per tet).
#[inline]
pub fn load_dm_inv(dm_inv: &[f32], e: usize) -> Mat3 {
    Mat3::from_cols_slice(&dm_inv[9 * e..9 * e + 9])
}

/// Corner forces and energy of one tet from its corner displacements `u` and velocities.
///
/// Returns ([f₀, f₁, f₂, f₃], V·Ψ) for the material and viscosity of `variant`.
pub fn tet_forces(
    params: &StepParams,
    u: [Vec3; 4],
    v: [Vec3; 4],
    dmi: Mat3,
    volume: f32,
    variant: FemVariant,
) -> ([Vec3; 4], f32) {
    let h = displacement_gradient(u, dmi);
    let (mut p, psi_density) = elastic_stress_energy(variant.model, h, params.lambda, params.mu);
    if variant.viscous {
        p += viscous_first_piola(params, h, v, dmi);
    }
    (
        corner_forces_of_stress(p, dmi, volume),
        volume * psi_density,
    )
}

/// H = Du·Dm⁻¹ from the corner displacements.
#[inline]
pub fn displacement_gradient(u: [Vec3; 4], dmi: Mat3) -> Mat3 {
    Mat3::from_cols(u[1] - u[0], u[2] - u[0], u[3] - u[0]) * dmi
}

/// The viscous stress of paper eq. (3–4) as a first Piola–Kirchhoff stress: F·S_v with
/// S_v = φ tr(Ė) I + 2ψ Ė, Ė = ½(ḞᵀF + FᵀḞ), Ḟ = Dv·Dm⁻¹.
#[inline]
pub fn viscous_first_piola(params: &StepParams, h: Mat3, v: [Vec3; 4], dmi: Mat3) -> Mat3 {
    let dv = Mat3::from_cols(v[1] - v[0], v[2] - v[0], v[3] - v[0]);
    viscous_stress(params, Mat3::IDENTITY + h, dv * dmi)
}

/// F·S_v for deformation gradient F and its rate Ḟ: S_v = φ tr(Ė) I + 2ψ Ė with
/// Ė = ½(ḞᵀF + FᵀḞ) (paper eq. 3–4; the tets' and, from the particles' velocities, tlsph's).
#[inline]
pub fn viscous_stress(params: &StepParams, f: Mat3, f_dot: Mat3) -> Mat3 {
    let rate = green_strain_rate(f, f_dot);
    f * stvk_second_piola(Mat3::ZERO, rate, 0.0, 0.0, params.phi, params.psi)
}

/// Corner forces of a tet with stress P: [f₁ f₂ f₃] = −V P Dm⁻ᵀ, f₀ = −(f₁ + f₂ + f₃).
#[inline]
pub fn corner_forces_of_stress(p: Mat3, dmi: Mat3, volume: f32) -> [Vec3; 4] {
    let g = p * dmi.transpose() * (-volume);
    let (f1, f2, f3) = (g.x_axis, g.y_axis, g.z_axis);
    [-(f1 + f2 + f3), f1, f2, f3]
}

/// Per tet e (in parallel, one index per tet as on the GPU): write corner force c to
/// `corner_forces[(4e + c)·3 ..]` and V·Ψ to `tet_energy[e]`.
#[allow(clippy::too_many_arguments)]
pub fn fem_forces(
    params: &StepParams,
    displacements: &[f32],
    velocities: &[f32],
    tets: &[[u32; 4]],
    dm_inv: &[f32],
    rest_volume: &[f32],
    corner_forces: &mut [f32],
    tet_energy: &mut [f32],
    variant: FemVariant,
) {
    super::par::for_each_chunk2::<12, 1>(
        corner_forces,
        tet_energy,
        params.n_tets as usize,
        |e, corner, energy| {
            let t = tets[e];
            let u = t.map(|i| load3(displacements, i as usize));
            let v = t.map(|i| load3(velocities, i as usize));
            let (forces, psi) = tet_forces(
                params,
                u,
                v,
                load_dm_inv(dm_inv, e),
                rest_volume[e],
                variant,
            );
            for (c, f) in forces.iter().enumerate() {
                store3(corner, c, *f);
            }
            energy[0] = psi;
        },
    );
}
