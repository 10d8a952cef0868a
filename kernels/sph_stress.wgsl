// Stage (every particle sub-step; indirect over the stress set S): per particle, the
// displacement gradient H_p = [sum_b V (u_b - u_p) (x) grad W(X_b - X_p)] G_p (exact for
// affine motion, see sph_setup), F = I + H, and
//   tlsph: P and Psi from the element stage's material law (shared/material.wgsl);
//   paper: the paper's eq. (1)-(2) stress with strain eps = F^T F - I (no 1/2), which is
//          S = lambda tr(E) I + 2 mu E for E = eps/2 doubled; Psi = mu E:E + lambda/2 tr(E)^2.
// With VISCOUS, + the strain-rate stress from the particles' velocities (see
// shared/sph_stress_particle.wgsl). Writes A_p = P G_p^T (so that P g_pb = A_p grad W_pb), H_p (for the hourglass penalty) and
// V Psi (shared/sph_stress_particle.wgsl, which contact.wgsl's `contact_sph_stress` runs on
// the contact's grid). CPU twin: src/cpu/sph_stress.rs. Each particle has SPH_STRESS_LANES threads:
// lane j sums the neighbours j, j + 4, … and the lanes' sums are added in lane order (the twin sums in list
// order: the two agree to rounding). One thread walking ~26 neighbours is a chain of dependent
// loads whose latency bounds the stage when S holds a few hundred particles (NVIDIA H200,
// 2026-11-27: BENCHMARKS.md).
#import params
#import index
#import sph_stress_particle

@group(0) @binding(0) var<uniform> params: StepParams;

const ITEMS_PER_WORKGROUP: u32 = 64u;

@compute @workgroup_size(256)
fn sph_stress(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>, @builtin(local_invocation_index) local: u32) {
    sph_stress_entry(workgroup_index(wid, nwg) * SPH_STRESS_ITEMS + local % SPH_STRESS_ITEMS, local, params.lambda, params.mu, params.phi, params.psi);
}
