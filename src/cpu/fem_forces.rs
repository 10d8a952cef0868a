//! CPU twin of `kernels/fem_forces.wgsl`: per tet, H = Du·Dm⁻¹, F = I + H, E, Ė, S, P = F·S
//! and the four corner forces −V·P·Dm⁻ᵀ (paper eq. 1–6), plus the elastic energy V·Ψ(E).

use super::{load3, store3};
use crate::material::{
    green_strain_from_gradient, green_strain_rate, stvk_energy_density, stvk_second_piola,
};
use crate::params::StepParams;
use glam::{Mat3, Vec3};

/// Dm⁻¹ of tet `e` from the packed column-major array (9 floats per tet).
#[inline]
pub fn load_dm_inv(dm_inv: &[f32], e: usize) -> Mat3 {
    Mat3::from_cols_slice(&dm_inv[9 * e..9 * e + 9])
}

/// Corner forces and energy of one tet from its corner displacements `u` and velocities.
///
/// Returns ([f₀, f₁, f₂, f₃], V·Ψ). `viscous` selects the viscous-stress variant.
#[allow(clippy::too_many_arguments)]
pub fn tet_forces(
    params: &StepParams,
    u: [Vec3; 4],
    v: [Vec3; 4],
    dmi: Mat3,
    volume: f32,
    viscous: bool,
) -> ([Vec3; 4], f32) {
    let du = Mat3::from_cols(u[1] - u[0], u[2] - u[0], u[3] - u[0]);
    let h = du * dmi;
    let f = Mat3::IDENTITY + h;
    let strain = green_strain_from_gradient(h);
    let rate = if viscous {
        let dv = Mat3::from_cols(v[1] - v[0], v[2] - v[0], v[3] - v[0]);
        green_strain_rate(f, dv * dmi)
    } else {
        Mat3::ZERO
    };
    let (phi, psi) = if viscous {
        (params.phi, params.psi)
    } else {
        (0.0, 0.0)
    };
    let s = stvk_second_piola(strain, rate, params.lambda, params.mu, phi, psi);
    let p = f * s;
    let g = p * dmi.transpose() * (-volume);
    let f1 = g.x_axis;
    let f2 = g.y_axis;
    let f3 = g.z_axis;
    let f0 = -(f1 + f2 + f3);
    let energy = volume * stvk_energy_density(strain, params.lambda, params.mu);
    ([f0, f1, f2, f3], energy)
}

/// Per tet e: write corner force c to `corner_forces[(4e + c)·3 ..]` and V·Ψ to `tet_energy[e]`.
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
    viscous: bool,
) {
    for e in 0..params.n_tets as usize {
        let t = tets[e];
        let u = t.map(|i| load3(displacements, i as usize));
        let v = t.map(|i| load3(velocities, i as usize));
        let (forces, energy) = tet_forces(
            params,
            u,
            v,
            load_dm_inv(dm_inv, e),
            rest_volume[e],
            viscous,
        );
        for (c, f) in forces.iter().enumerate() {
            store3(corner_forces, 4 * e + c, *f);
        }
        tet_energy[e] = energy;
    }
}
