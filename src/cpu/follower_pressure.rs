//! CPU twin of `kernels/follower_pressure.wgsl`: a pressure load on the deformed surface
//! (a follower load, as in the Land et al. 2015 benchmark problems, where it turns and
//! stretches with the wall). Per selected boundary face (a, b, c), oriented with its normal
//! out of the body, at the current positions x = X + u:
//! area vector A n = ½ (x_b − x_a) × (x_c − x_a), and each corner gets
//! f = −s·p_face·A n / 3 (the consistent load of a linear triangle, ∫ N_a dA = A/3), with
//! s = `load_factor` (a ramp in [0, 1] the engine sets per batch) and p_face in Pa
//! (positive pushes into the body). Forces go to per-face-corner slots (face·3 + corner);
//! `follower_pressure_gather` sums them per vertex in a fixed order (no float atomics).
//!
//! Over a closed surface under one pressure the corner forces sum to zero for any
//! deformation (Σ A n = 0), and the load does work p ΔV (conservative); on an open surface
//! it is not conservative in general.

use super::{load3, store3};
use bytemuck::{Pod, Zeroable};
use glam::Vec3;

/// The follower-pressure uniform (WGSL `FollowerLoad`, binding `follower_load`), 16 bytes;
/// a test checks the layout against naga's.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct FollowerLoad {
    /// Number of loaded faces.
    pub n_faces: u32,
    /// Ramp factor s ∈ [0, 1] applied to every face pressure (s = min(t / t_ramp, 1)).
    pub load_factor: f32,
    /// Padding to 16 bytes.
    pub _pad0: u32,
    /// Padding.
    pub _pad1: u32,
}

/// Corner forces of one face with corners at current positions `x`, pressure `p` (Pa,
/// already ramped): each −p·½(x₁ − x₀)×(x₂ − x₀)/3. `rest` and `u` are passed apart so that
/// edges are (X_b − X_a) + (u_b − u_a), as the kernel computes them.
#[inline]
pub fn face_corner_force(rest: [Vec3; 3], u: [Vec3; 3], p: f32) -> Vec3 {
    let e1 = (rest[1] - rest[0]) + (u[1] - u[0]);
    let e2 = (rest[2] - rest[0]) + (u[2] - u[0]);
    e1.cross(e2) * (-p / 6.0)
}

/// Per face i: the force of each corner to `follower_corner_forces[(3i + c)·3 ..]`, N.
/// `follower_faces` holds 3 vertex ids per face, oriented outward.
pub fn follower_pressure(
    follower_load: &FollowerLoad,
    rest_positions: &[f32],
    displacements: &[f32],
    follower_faces: &[u32],
    follower_face_pressure: &[f32],
    follower_corner_forces: &mut [f32],
) {
    super::par::for_each_chunk::<9>(
        follower_corner_forces,
        follower_load.n_faces as usize,
        |i, out| {
            let v = [0, 1, 2].map(|c| follower_faces[3 * i + c] as usize);
            let f = face_corner_force(
                v.map(|k| load3(rest_positions, k)),
                v.map(|k| load3(displacements, k)),
                follower_load.load_factor * follower_face_pressure[i],
            );
            for c in 0..3 {
                store3(out, c, f);
            }
        },
    );
}
