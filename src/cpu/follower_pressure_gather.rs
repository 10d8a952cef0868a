//! CPU twin of `kernels/follower_pressure_gather.wgsl`: per vertex, the constant loads plus
//! the follower-pressure corner forces around it, summed over a CSR list
//! (vertex → face·3 + corner, ascending) in a fixed order, like `gather` (no float
//! atomics). It writes `external_forces`, which `gather` then adds with m·g and the
//! element forces; the constant (dead) loads live in `dead_load_forces`.

use super::{load3, store3};
use crate::params::StepParams;

/// CSR incidence of face corners: vertex i's corners are
/// `incidence[offsets[i]..offsets[i + 1]]`, each face·3 + corner, ascending. Built once, on
/// the CPU, from the loaded faces.
pub fn follower_incidence(n_vertices: usize, faces: &[[u32; 3]]) -> (Vec<u32>, Vec<u32>) {
    let mut offsets = vec![0u32; n_vertices + 1];
    for face in faces {
        for &v in face {
            offsets[v as usize + 1] += 1;
        }
    }
    for i in 0..n_vertices {
        offsets[i + 1] += offsets[i];
    }
    let mut fill = offsets.clone();
    let mut incidence = vec![0u32; 3 * faces.len()];
    for (i, face) in faces.iter().enumerate() {
        for (c, &v) in face.iter().enumerate() {
            incidence[fill[v as usize] as usize] = (3 * i + c) as u32;
            fill[v as usize] += 1;
        }
    }
    (offsets, incidence)
}

/// Per vertex i: `external_forces[i] = dead_load_forces[i] + Σ_k follower_corner_forces[follower_incidence[k]]`
/// over k ∈ `follower_incidence_offsets[i]..follower_incidence_offsets[i + 1]`.
pub fn follower_pressure_gather(
    params: &StepParams,
    follower_corner_forces: &[f32],
    follower_incidence_offsets: &[u32],
    follower_incidence: &[u32],
    dead_load_forces: &[f32],
    external_forces: &mut [f32],
) {
    super::par::for_each_chunk::<3>(external_forces, params.n_vertices as usize, |i, out| {
        let mut f = load3(dead_load_forces, i);
        for k in follower_incidence_offsets[i]..follower_incidence_offsets[i + 1] {
            f += load3(
                follower_corner_forces,
                follower_incidence[k as usize] as usize,
            );
        }
        store3(out, 0, f);
    });
}
