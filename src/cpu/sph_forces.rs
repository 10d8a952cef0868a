//! CPU twin of `kernels/sph_forces.wgsl`: the SPH force on each particle of the force set
//! (tlsph: the exact gradient of the particles' strain energy plus the hourglass penalty;
//! paper: eq. 13 one-sided), gravity and tool contact on dynamic particles, and the force
//! sum over sub-steps that embedded particles pass to their hosts.

use super::contact::contact_force;
use super::sph::{kernel_gradient, wendland};
use super::{load3, load3a};
use crate::contact::{ToolInput, ToolParams, ToolState};
use crate::params::StepParams;
use crate::particles::params::{mode, ParticleParams};
use glam::{Mat3A, Vec3, Vec3A};

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
    /// Rest-state pair quantities (None: computed on the fly, as the WGSL kernel does).
    pub pairs: Option<&'a super::sph::PairTable>,
}

/// What particle c's side of the pair (c, b) computes: the stress term V²(A_c + A_b)∇W
/// (tlsph; V² A_b ∇W for the paper model) and, for tlsph with hourglass control, the
/// hourglass term on pairs with a dynamic particle (zero where it does not apply); both
/// added to `f`. Nothing when neither is in S. SIMD-width glam types (`Mat3A`, `Vec3A`):
/// the same operations as the kernel, in registers.
#[inline]
fn add_pair_terms(inp: &ForceInputs, k: usize, side: &Side, f: &mut Vec3A) {
    if let Some((stress, hourglass)) = pair_terms(inp, k, side) {
        *f += stress;
        if let Some(h) = hourglass {
            *f += h;
        }
    }
}

/// The two terms of [`add_pair_terms`] on particle c (`side`) from the pair in its slot k:
/// None when neither particle is in S; the hourglass term only where it applies. tlsph's
/// terms are antisymmetric (the pair's other particle gets their negatives, up to rounding),
/// which lets `cpu::sph_pairs` evaluate each pair once (from per-step packed records, its
/// own `pair_term`).
#[inline]
pub(crate) fn pair_terms(
    inp: &ForceInputs,
    k: usize,
    side: &Side,
) -> Option<(Vec3A, Option<Vec3A>)> {
    let pp = inp.pp;
    let b = inp.neighbours[k] as usize;
    let mode_b = inp.mode[b];
    if !side.in_s && mode_b & mode::IN_S == 0 {
        return None;
    }
    // fl(X_c − X_b) = −fl(X_b − X_c): the offset the kernel's gradient takes, negated.
    let x0cb = side.x0 - load3a(inp.rest, b);
    match inp.pairs {
        Some(t) => pair_terms_at(inp, side, (b, mode_b), t.gradient[k].into(), x0cb, || {
            (t.rest_distance[k], t.hourglass[k])
        }),
        None => {
            let w = kernel_gradient(pp.model, (-x0cb).into(), pp.spacing, pp.support).into();
            pair_terms_at(inp, side, (b, mode_b), w, x0cb, || {
                let r0 = x0cb.length();
                let hg = 0.5 * pp.hourglass * pp.youngs * (pp.volume * pp.volume);
                (r0, hg * wendland(r0, pp.support) / (r0 * r0))
            })
        }
    }
}

/// [`pair_terms`] from the pair's rest quantities: neighbour b and its mode, the kernel
/// gradient w = ∇W(X_b − X_c), X_cb, and (called only where the hourglass term applies) r0
/// and the hourglass weight h·W(r0)/r0².
#[inline]
fn pair_terms_at(
    inp: &ForceInputs,
    side: &Side,
    (b, mode_b): (usize, u32),
    w: Vec3A,
    x0cb: Vec3A,
    rest_weight: impl FnOnce() -> (f32, f32),
) -> Option<(Vec3A, Option<Vec3A>)> {
    let pp = inp.pp;
    let in_s_b = mode_b & mode::IN_S != 0;
    let v2 = pp.volume * pp.volume;
    if pp.model == 1 {
        if in_s_b {
            return Some(((load_mat3a(inp.stress, b) * w) * v2, None));
        }
        return None;
    }
    let a_sum = if in_s_b {
        side.a + load_mat3a(inp.stress, b)
    } else {
        side.a
    };
    let stress = (a_sum * w) * v2;
    // Only pairs with a dynamic particle: followers move with their tets, so a pair of them
    // cannot form a zig-zag mode (their relative motion is the tets').
    let dynamic_pair = (mode_b | side.mode) & mode::DYNAMIC != 0;
    if pp.hourglass > 0.0 && dynamic_pair {
        let xcb = x0cb + side.u - load3a(inp.displacements, b);
        let r2 = xcb.length_squared();
        let (r0, weight) = rest_weight();
        if r2 > 0.0 && r0 > 0.0 {
            // δ/r = (Σ over the sides in S of (F X_cb)·x_cb)/r² − (their count).
            let (mut g, mut sides) = (Vec3A::ZERO, 0.0);
            if side.in_s {
                g += side.f * x0cb;
                sides += 1.0;
            }
            if in_s_b {
                g += (Mat3A::IDENTITY + load_mat3a(inp.gradient, b)) * x0cb;
                sides += 1.0;
            }
            return Some((stress, Some(xcb * (weight * (g.dot(xcb) / r2 - sides)))));
        }
    }
    Some((stress, None))
}

/// The 3×3 matrix stored column-major at `a[9i..9i + 9]`.
#[inline]
pub(crate) fn load_mat3a(a: &[f32], i: usize) -> Mat3A {
    let m = &a[9 * i..9 * i + 9];
    Mat3A::from_cols(
        Vec3A::new(m[0], m[1], m[2]),
        Vec3A::new(m[3], m[4], m[5]),
        Vec3A::new(m[6], m[7], m[8]),
    )
}

/// Particle c's own quantities for [`add_pair_terms`].
pub(crate) struct Side {
    mode: u32,
    in_s: bool,
    x0: Vec3A,
    pub(crate) u: Vec3A,
    a: Mat3A,
    pub(crate) f: Mat3A,
}

impl Side {
    /// Particle c's mode, rest position, displacement, A and F (A = 0, F = I outside S).
    pub(crate) fn of(inp: &ForceInputs, c: usize) -> Side {
        let in_s = inp.mode[c] & mode::IN_S != 0;
        let (a, f) = if in_s {
            (
                load_mat3a(inp.stress, c),
                Mat3A::IDENTITY + load_mat3a(inp.gradient, c),
            )
        } else {
            (Mat3A::ZERO, Mat3A::IDENTITY)
        };
        Side {
            mode: inp.mode[c],
            in_s,
            x0: load3a(inp.rest, c),
            u: load3a(inp.displacements, c),
            a,
            f,
        }
    }
}

/// Add gravity and the tool's contact to f when particle c is dynamic (in that order, as
/// the kernel does); returns the contact force. `(u, deformation)`: c's displacement and F,
/// which place its contact point at X + u + F·offset.
pub(crate) fn add_external(
    inp: &ForceInputs,
    c: usize,
    (u, deformation): (Vec3A, Mat3A),
    f: &mut Vec3,
) -> Vec3 {
    let mut contact = Vec3::ZERO;
    if inp.mode[c] & mode::DYNAMIC != 0 {
        *f += Vec3::from_array(inp.params.gravity) * inp.pp.mass;
        let area = inp.area[c];
        if let Some((tp, ti, ts)) = inp.tool {
            if area > 0.0 {
                let vc = super::contact::tool_velocity(inp.params, ti);
                let o = load3(inp.contact_offset, c);
                contact = contact_force(
                    tp,
                    Vec3::from(load3a(inp.rest, c) + u + deformation * Vec3A::from(o)),
                    load3(inp.velocities, c),
                    Vec3::from_array(ts.position),
                    vc,
                    area,
                )
                .force;
                *f += contact;
            }
        }
    }
    contact
}

/// The force on particle c and its tool contact (twin of one `sph_forces` thread).
pub fn force_on(inp: &ForceInputs, c: usize) -> (Vec3, Vec3) {
    let side = Side::of(inp, c);
    let mut fa = Vec3A::ZERO;
    for k in inp.neighbour_offsets[c]..inp.neighbour_offsets[c + 1] {
        add_pair_terms(inp, k as usize, &side, &mut fa);
    }
    let mut f = Vec3::from(fa);
    let contact = add_external(inp, c, (side.u, side.f), &mut f);
    (f, contact)
}

pub(crate) fn store_forces(
    inp: &ForceInputs,
    force_list: &[u32],
    results: &[(Vec3, Vec3)],
    accumulate: bool,
    particle_forces: &mut [f32],
    particle_force_sum: &mut [f32],
    particle_contact: &mut [f32],
) {
    let s = inp.pp.substeps.max(1) as f32;
    for (&c, &(f, contact)) in force_list.iter().zip(results) {
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
    store_forces(
        inp,
        force_list,
        &results,
        accumulate,
        particle_forces,
        particle_force_sum,
        particle_contact,
    );
}
