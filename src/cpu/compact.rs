//! CPU twin of `kernels/compact.wgsl`: the dynamic, stress and force lists in ascending
//! particle order, their counts and the indirect dispatch arguments.

use crate::particles::params::mode;

/// Workgroup size of the indirect-dispatched particle kernels.
pub const PARTICLE_WORKGROUP: u32 = 64;
const MAX_GROUPS: u32 = 65535;

/// The lists and counts (twin of compact_mark + the three scans + compact_scatter +
/// compact_args, but for compact_args' fourth grid, the fused contact + sph_stress
/// dispatch's, which no CPU stage dispatches: [`grid`] of it is checked in the tests).
pub fn compact(
    particle_mode: &[u32],
    dynamic_list: &mut Vec<u32>,
    stress_list: &mut Vec<u32>,
    force_list: &mut Vec<u32>,
    particle_counts: &mut [u32; 4],
    particle_dispatch: &mut [u32; 9],
) {
    dynamic_list.clear();
    stress_list.clear();
    force_list.clear();
    for (p, &m) in particle_mode.iter().enumerate() {
        if m & mode::DYNAMIC != 0 {
            dynamic_list.push(p as u32);
        }
        if m & mode::IN_S != 0 {
            stress_list.push(p as u32);
        }
        if m & mode::IN_F != 0 {
            force_list.push(p as u32);
        }
    }
    counts_and_dispatch(
        [dynamic_list, stress_list, force_list],
        particle_counts,
        particle_dispatch,
    );
}

/// The lists' counts and their three indirect dispatch arguments (twin of compact_args but
/// for its fourth grid).
pub fn counts_and_dispatch(
    lists: [&[u32]; 3],
    particle_counts: &mut [u32; 4],
    particle_dispatch: &mut [u32; 9],
) {
    let counts = lists.map(|l| l.len() as u32);
    *particle_counts = [counts[0], counts[1], counts[2], 0];
    for (k, &count) in counts.iter().enumerate() {
        let (x, y) = grid(count.div_ceil(PARTICLE_WORKGROUP));
        particle_dispatch[3 * k..3 * k + 3].copy_from_slice(&[x, y, 1]);
    }
}

/// `groups` workgroups as a grid every adapter allows: (x, y) with x ≤ 65,535 and x·y ≥
/// groups (twin of compact.wgsl's `write_args`).
pub fn grid(groups: u32) -> (u32, u32) {
    if groups > MAX_GROUPS {
        (MAX_GROUPS, groups.div_ceil(MAX_GROUPS))
    } else {
        (groups, 1)
    }
}
