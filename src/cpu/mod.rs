//! The CPU reference path: one function per WGSL kernel, with the same name and the same
//! inputs in the same order as the kernel's bindings, written to be read side by side with
//! `kernels/<name>.wgsl`. Loops run over the same index a GPU thread would own and write only
//! that index's outputs. f32 throughout, like the GPU. Index loops are kept on purpose, to
//! read like the shaders.
#![allow(clippy::needless_range_loop)]

pub mod activate;
pub mod active_region;
pub mod compact;
pub mod contact;
pub mod dispatch_probe;
pub mod exact_activation;
pub mod exact_coupling;
pub mod exact_stages;
pub mod fem_forces;
pub mod fem_forces_split;
pub mod follow;
pub mod follower_pressure;
pub mod follower_pressure_gather;
pub mod gather;
pub mod integrate;
pub mod integrate_particles;
pub mod memory;
pub mod neighbours;
pub mod nodal_pressure;
pub mod par;
pub mod particle_reduce;
pub mod reduce;
pub mod scan;
pub mod sph;
pub mod sph_forces;
pub mod sph_pairs;
pub mod sph_setup;
pub mod sph_stress;
pub mod stepper;
pub mod tet_volume_change;
pub mod tool_force;
pub mod tool_motion;
pub mod touched;

pub use contact::contact;
pub use fem_forces::fem_forces;
pub use gather::gather;
pub use integrate::integrate;
pub use reduce::{reduce_final, reduce_partial, REDUCE_WORKGROUP};
pub use stepper::CpuStepper;
pub use tool_force::{tool_force_final, tool_force_partial};
pub use tool_motion::tool_motion;

use glam::{Vec3, Vec3A};

/// Read vector `i` from a packed xyz array.
#[inline]
pub fn load3(a: &[f32], i: usize) -> Vec3 {
    let [x, y, z] = xyz(a, i);
    Vec3::new(x, y, z)
}

/// The three floats of vector `i`, with one bounds check (indexing each would check three
/// times, inside the neighbour and incidence loops).
#[inline(always)]
fn xyz(a: &[f32], i: usize) -> [f32; 3] {
    match a[3 * i..3 * i + 3] {
        [x, y, z] => [x, y, z],
        _ => unreachable!("a range of three"),
    }
}

/// [`load3`] into a SIMD-width vector.
#[inline]
pub fn load3a(a: &[f32], i: usize) -> Vec3A {
    let [x, y, z] = xyz(a, i);
    Vec3A::new(x, y, z)
}

/// Write vector `i` into a packed xyz array.
#[inline]
pub fn store3(a: &mut [f32], i: usize, v: Vec3) {
    a[3 * i] = v.x;
    a[3 * i + 1] = v.y;
    a[3 * i + 2] = v.z;
}
