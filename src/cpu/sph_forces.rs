//! CPU twin of `kernels/sph_forces.wgsl`: the SPH force on each particle of the force set
//! (tlsph: the exact gradient of the particles' strain energy plus the hourglass penalty;
//! paper: eq. 13 one-sided), gravity and tool contact on dynamic particles, and the force
//! sum over sub-steps that embedded particles pass to their hosts.

use super::contact::contact_force;
use super::fem_forces::load_dm_inv;
use super::load3;
use super::sph::{kernel_gradient, wendland};
use crate::contact::{ToolInput, ToolParams, ToolState};
use crate::params::StepParams;
use crate::particles::params::{mode, ParticleParams};
use glam::{Mat3, Vec3};

/// Inputs of the force kernel.
pub struct ForceInputs<'a> {
    /// Per-step parameters (gravity, dt).
    pub params: &'a StepParams,
    /// Particle constants.
    pub pp: &'a ParticleParams,
    /// Tool constants, input and state, and whether there is a tool.
    pub tool: Option<(&'a ToolParams, &'a ToolInput, &'a ToolState)>,
    /// Particle modes.
    pub mode: &'a [u32],
    /// Rest positions.
    pub rest: &'a [f32],
    /// Particle displacements.
    pub displacements: &'a [f32],
    /// Particle velocities.
    pub velocities: &'a [f32],
    /// Neighbour CSR offsets.
    pub neighbour_offsets: &'a [u32],
    /// Neighbour lists.
    pub neighbours: &'a [u32],
    /// A_p per particle (9 floats).
    pub stress: &'a [f32],
    /// H_p per particle (9 floats).
    pub gradient: &'a [f32],
    /// Contact area per particle.
    pub area: &'a [f32],
    /// Rest offset to the true surface per particle (xyz).
    pub contact_offset: &'a [f32],
}

/// The force on particle c and its tool contact (twin of one `sph_forces` thread).
pub fn force_on(inp: &ForceInputs, c: usize) -> (Vec3, Vec3) {
    let pp = inp.pp;
    let mode_c = inp.mode[c];
    let in_s_c = mode_c & mode::IN_S != 0;
    let x0c = load3(inp.rest, c);
    let uc = load3(inp.displacements, c);
    let (a_c, f_c) = if in_s_c {
        (
            load_dm_inv(inp.stress, c),
            Mat3::IDENTITY + load_dm_inv(inp.gradient, c),
        )
    } else {
        (Mat3::ZERO, Mat3::IDENTITY)
    };
    let v2 = pp.volume * pp.volume;
    let hg = 0.5 * pp.hourglass * pp.youngs * v2;
    let mut f = Vec3::ZERO;
    for k in inp.neighbour_offsets[c]..inp.neighbour_offsets[c + 1] {
        let b = inp.neighbours[k as usize] as usize;
        let in_s_b = inp.mode[b] & mode::IN_S != 0;
        if !in_s_c && !in_s_b {
            continue;
        }
        let x0b = load3(inp.rest, b);
        let w = kernel_gradient(pp.model, x0b - x0c, pp.spacing, pp.support);
        let a_b = if in_s_b {
            load_dm_inv(inp.stress, b)
        } else {
            Mat3::ZERO
        };
        if pp.model == 1 {
            f += (a_b * w) * v2;
        } else {
            f += ((a_c + a_b) * w) * v2;
            if pp.hourglass > 0.0 {
                let x0cb = x0c - x0b;
                let xcb = x0cb + uc - load3(inp.displacements, b);
                let r = xcb.length();
                let r0 = x0cb.length();
                if r > 0.0 && r0 > 0.0 {
                    let mut delta = 0.0;
                    if in_s_c {
                        delta += (f_c * x0cb - xcb).dot(xcb) / r;
                    }
                    if in_s_b {
                        delta += ((Mat3::IDENTITY + load_dm_inv(inp.gradient, b)) * x0cb - xcb)
                            .dot(xcb)
                            / r;
                    }
                    f += xcb * (hg * wendland(r0, pp.support) / (r0 * r0) * delta / r);
                }
            }
        }
    }
    let mut contact = Vec3::ZERO;
    if mode_c & mode::DYNAMIC != 0 {
        f += Vec3::from_array(inp.params.gravity) * pp.mass;
        let area = inp.area[c];
        if let Some((tp, ti, ts)) = inp.tool {
            if area > 0.0 {
                let vc = super::contact::tool_velocity(inp.params, ti);
                let o = load3(inp.contact_offset, c);
                contact = contact_force(
                    tp,
                    x0c + uc + f_c * o,
                    load3(inp.velocities, c),
                    Vec3::from_array(ts.position),
                    vc,
                    area,
                )
                .force;
                f += contact;
            }
        }
    }
    (f, contact)
}

/// Per particle of `force_list`: `particle_forces`, `particle_contact` and the sub-step sum
/// (`accumulate`: add to it; else start it).
pub fn sph_forces(
    inp: &ForceInputs,
    force_list: &[u32],
    accumulate: bool,
    particle_forces: &mut [f32],
    particle_force_sum: &mut [f32],
    particle_contact: &mut [f32],
) {
    use rayon::prelude::*;
    let results: Vec<(Vec3, Vec3)> = force_list
        .par_iter()
        .map(|&c| force_on(inp, c as usize))
        .collect();
    let s = inp.pp.substeps.max(1) as f32;
    for (&c, (f, contact)) in force_list.iter().zip(results) {
        let c = c as usize;
        super::store3(particle_forces, c, f);
        super::store3(particle_contact, c, contact);
        let mut sum = f / s;
        if accumulate {
            sum += load3(particle_force_sum, c);
        }
        super::store3(particle_force_sum, c, sum);
    }
}
