//! CPU twin of `kernels/integrate.wgsl`: symplectic Euler (paper eq. 12) with
//! mass-proportional damping, fixed vertices (inverse mass 0), and a non-finite check that
//! records the lowest offending vertex.

use super::{load3, store3};
use crate::params::StepParams;
use glam::Vec3;

/// Status word meaning "all finite".
pub const ALL_FINITE: u32 = u32::MAX;

/// True when all components are finite (the WGSL twin tests the exponent bits).
#[inline]
pub fn is_finite3(v: Vec3) -> bool {
    v.is_finite()
}

/// Per vertex i: v ← (v + dt·f/m) / (1 + α·dt), u ← u + dt·v (u = x − X, the displacement);
/// fixed vertices (inverse mass 0) keep v = 0; a negative inverse mass marks a vertex moved
/// kinematically by its dynamic particles (u ← u + dt·v, v as given). `status[0]` becomes `min(status[0], i)` when u or
/// v is not finite or |v| exceeds `params.speed_limit`.
pub fn integrate(
    params: &StepParams,
    forces: &[f32],
    inv_mass: &[f32],
    displacements: &mut [f32],
    velocities: &mut [f32],
    status: &mut [u32],
) {
    let flagged = super::par::for_each_chunk2_min::<3, 3>(
        displacements,
        velocities,
        params.n_vertices as usize,
        |i, x_out, v_out| {
            let w = inv_mass[i];
            let mut v = load3(v_out, 0);
            let mut x = load3(x_out, 0);
            if w > 0.0 {
                v = (v + load3(forces, i) * (params.dt * w)) / (1.0 + params.damping * params.dt);
                x += v * params.dt;
            } else if w < 0.0 {
                x += v * params.dt;
            } else {
                v = Vec3::ZERO;
            }
            store3(v_out, 0, v);
            store3(x_out, 0, x);
            let bad = !(is_finite3(x) && is_finite3(v))
                || v.dot(v) > params.speed_limit * params.speed_limit;
            bad.then_some(i as u32)
        },
    );
    if let Some(i) = flagged {
        status[0] = status[0].min(i);
    }
}
