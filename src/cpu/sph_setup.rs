//! CPU twin of `kernels/sph_setup.wgsl`: each particle's kernel-gradient correction
//! G_p = M_p⁻¹, M_p = Σ_b V (X_b − X_p) ⊗ ∇W(X_b − X_p) (0 when M is singular).

use super::sph::kernel_gradient;
use super::{load3, load3a};
use crate::particles::params::ParticleParams;
use glam::{Mat3, Vec3A};

/// The correction matrix of particle p.
pub fn correction(
    pp: &ParticleParams,
    rest: &[f32],
    neighbour_offsets: &[u32],
    neighbours: &[u32],
    p: usize,
) -> Mat3 {
    let x = load3(rest, p);
    let mut m = Mat3::ZERO;
    for k in neighbour_offsets[p]..neighbour_offsets[p + 1] {
        let d = load3(rest, neighbours[k as usize] as usize) - x;
        let w = kernel_gradient(pp.model, d, pp.spacing, pp.support) * pp.volume;
        m += Mat3::from_cols(d * w.x, d * w.y, d * w.z);
    }
    let det = m.determinant();
    let scale = m.x_axis.x.abs() + m.y_axis.y.abs() + m.z_axis.z.abs();
    if det.abs() > 1e-6 * scale * scale * scale {
        let r0 = m.y_axis.cross(m.z_axis);
        let r1 = m.z_axis.cross(m.x_axis);
        let r2 = m.x_axis.cross(m.y_axis);
        Mat3::from_cols(r0, r1, r2).transpose() * (1.0 / det)
    } else {
        Mat3::ZERO
    }
}

/// Per particle: `particle_correction[9p..]` = G_p, column-major.
pub fn sph_setup(
    pp: &ParticleParams,
    rest: &[f32],
    neighbour_offsets: &[u32],
    neighbours: &[u32],
    particle_correction: &mut [f32],
) {
    super::par::for_each_chunk::<9>(particle_correction, pp.n_particles as usize, |p, out| {
        out.copy_from_slice(
            &correction(pp, rest, neighbour_offsets, neighbours, p).to_cols_array(),
        );
    });
}

/// The reference neighbour lists of particles at `rest` (kernel support `support`) and every
/// particle's correction G_p over them, as `sph_setup` leaves them (packed, 9 floats each).
pub fn lists_and_corrections(
    pp: &ParticleParams,
    rest: &[f32],
    support: f32,
) -> (super::neighbours::NeighbourLists, Vec<f32>) {
    let grid = crate::particles::params::GridParams::over(rest, support);
    let lists = super::neighbours::build(&grid, rest);
    let mut correction = vec![0.0; 9 * (rest.len() / 3)];
    sph_setup(
        pp,
        rest,
        &lists.neighbour_offsets,
        &lists.neighbours,
        &mut correction,
    );
    (lists, correction)
}

/// Σ_b V (a_b − a_p) ⊗ ∇W(X_b − X_p) (the bracket of F_p; a = displacements or positions),
/// with the kernel gradients from `pairs` when given: [`gradient_sums`] of one array.
pub fn gradient_sum(
    pp: &ParticleParams,
    rest: &[f32],
    a: &[f32],
    neighbour_offsets: &[u32],
    neighbours: &[u32],
    pairs: Option<&super::sph::PairTable>,
    p: usize,
) -> Mat3 {
    let [s] = gradient_sums(pp, rest, [a], neighbour_offsets, neighbours, pairs, p);
    s
}

/// Σ_b V (a_b − a_p) ⊗ ∇W(X_b − X_p) for each array a of `arrays`, in one walk over p's
/// neighbours (the displacements' and the velocities' for a viscous stress), with the kernel
/// gradients from `pairs` when given. Summed in SIMD-width columns (`Vec3A`): the same
/// products and sums, element by element, as the kernel, and for each array as alone.
pub fn gradient_sums<const N: usize>(
    pp: &ParticleParams,
    rest: &[f32],
    arrays: [&[f32]; N],
    neighbour_offsets: &[u32],
    neighbours: &[u32],
    pairs: Option<&super::sph::PairTable>,
    p: usize,
) -> [Mat3; N] {
    let x = load3(rest, p);
    let own = arrays.map(|a| load3a(a, p));
    let mut cols = [[Vec3A::ZERO; 3]; N];
    for k in neighbour_offsets[p]..neighbour_offsets[p + 1] {
        let b = neighbours[k as usize] as usize;
        let w = match pairs {
            Some(t) => t.gradient[k as usize],
            None => kernel_gradient(pp.model, load3(rest, b) - x, pp.spacing, pp.support),
        } * pp.volume;
        for ((c, a), ap) in cols.iter_mut().zip(arrays).zip(own) {
            let du = load3a(a, b) - ap;
            c[0] += du * w.x;
            c[1] += du * w.y;
            c[2] += du * w.z;
        }
    }
    cols.map(|c| Mat3::from_cols(c[0].into(), c[1].into(), c[2].into()))
}
