//! CPU twin of `kernels/particle_reduce.wgsl`: the particles' diagnostics reduced over the
//! stress list in the GPU's tree order (blocks of 256 list entries, then one block over the
//! partials).

use super::load3;
use crate::particles::params::{mode, ParticleParams};

/// Threads per workgroup.
pub const WORKGROUP: usize = 256;
/// Floats per lane: kinetic, elastic, max speed, residual², Σ m|u|², largest stiffening κ
/// ([`crate::substeps::stiffening`]; 0 where no particle carries stress).
pub const LANE: usize = 6;

/// The most partials (the buffer's size: every particle in the stress set).
pub fn n_partials(pp: &ParticleParams) -> usize {
    (pp.n_particles as usize).div_ceil(WORKGROUP)
}

fn tree(lanes: &mut [[f32; LANE]; WORKGROUP]) -> [f32; LANE] {
    let mut s = WORKGROUP / 2;
    while s > 0 {
        for l in 0..s {
            let o = lanes[l + s];
            let a = &mut lanes[l];
            a[0] += o[0];
            a[1] += o[1];
            a[2] = a[2].max(o[2]);
            a[3] += o[3];
            a[4] += o[4];
            a[5] = a[5].max(o[5]);
        }
        s /= 2;
    }
    lanes[0]
}

/// Both passes over `stress_list` (the last activation's, which holds every particle then
/// dynamic; the modes are checked): writes `particle_stats[..6]`.
#[allow(clippy::too_many_arguments)]
pub fn particle_reduce(
    pp: &ParticleParams,
    stress_list: &[u32],
    particle_mode: &[u32],
    particle_displacements: &[f32],
    particle_velocities: &[f32],
    particle_forces: &[f32],
    particle_energy: &[f32],
    particle_gradient: &[f32],
    particle_partials: &mut [f32],
    particle_stats: &mut [f32],
) {
    let n = stress_list.len();
    let blocks = n.div_ceil(WORKGROUP);
    super::par::for_each_chunk::<LANE>(particle_partials, blocks, |block, out| {
        let mut lanes = [[0.0f32; LANE]; WORKGROUP];
        for (l, lane) in lanes.iter_mut().enumerate() {
            if let Some(&p) = stress_list.get(block * WORKGROUP + l) {
                let p = p as usize;
                let m = particle_mode[p];
                if m & mode::DYNAMIC != 0 {
                    let v = load3(particle_velocities, p);
                    lane[0] = 0.5 * pp.mass * v.dot(v);
                    lane[2] = v.length();
                    let f = load3(particle_forces, p);
                    lane[3] = f.dot(f);
                    let u = load3(particle_displacements, p);
                    lane[4] = pp.mass * u.dot(u);
                }
                if m & mode::IN_S != 0 {
                    lane[1] = particle_energy[p];
                }
                if m & (mode::DYNAMIC | mode::IN_S) != 0 {
                    let h = glam::Mat3::from_cols_slice(&particle_gradient[9 * p..9 * p + 9]);
                    lane[5] = crate::substeps::stiffening(glam::Mat3::IDENTITY + h);
                }
            }
        }
        out.copy_from_slice(&tree(&mut lanes));
    });
    let mut lanes = [[0.0f32; LANE]; WORKGROUP];
    for (l, lane) in lanes.iter_mut().enumerate() {
        let mut k = l;
        while k < blocks {
            let b = &particle_partials[LANE * k..LANE * k + LANE];
            lane[0] += b[0];
            lane[1] += b[1];
            lane[2] = lane[2].max(b[2]);
            lane[3] += b[3];
            lane[4] += b[4];
            lane[5] = lane[5].max(b[5]);
            k += WORKGROUP;
        }
    }
    let r = tree(&mut lanes);
    particle_stats[..LANE].copy_from_slice(&r);
}
