// Stage (every particle sub-step; indirect over the stress set S): per particle, the
// displacement gradient H_p = [sum_b V (u_b - u_p) (x) grad W(X_b - X_p)] G_p (exact for
// affine motion, see sph_setup), F = I + H, and
//   tlsph: P and Psi from the element stage's material law (shared/material.wgsl);
//   paper: the paper's eq. (1)-(2) stress with strain eps = F^T F - I (no 1/2), which is
//          S = lambda tr(E) I + 2 mu E for E = eps/2 doubled; Psi = mu E:E + lambda/2 tr(E)^2.
// Writes A_p = P G_p^T (so that P g_pb = A_p grad W_pb), H_p (for the hourglass penalty) and
// V Psi. CPU twin: src/cpu/sph_stress.rs. Each particle has LANES threads: lane j sums the
// neighbours j, j + LANES, … and the lanes' sums are added in lane order (the twin sums in list
// order: the two agree to rounding). One thread walking ~26 neighbours is a chain of dependent
// loads whose latency bounds the stage when S holds a few hundred particles (NVIDIA H200,
// 2026-11-27: BENCHMARKS.md).
#import params
#import index
#import particles
#import material

@group(0) @binding(0) var<uniform> params: StepParams;
@group(0) @binding(1) var<uniform> particle_params: ParticleParams;
@group(0) @binding(2) var<storage, read> particle_counts: array<u32>;
@group(0) @binding(3) var<storage, read> stress_list: array<u32>;
@group(0) @binding(4) var<storage, read> particle_rest: array<f32>;
@group(0) @binding(5) var<storage, read> particle_displacements: array<f32>;
@group(0) @binding(6) var<storage, read> neighbour_offsets: array<u32>;
@group(0) @binding(7) var<storage, read> neighbours: array<u32>;
@group(0) @binding(8) var<storage, read> particle_correction: array<f32>;
@group(0) @binding(9) var<storage, read_write> particle_stress: array<f32>;
@group(0) @binding(10) var<storage, read_write> particle_gradient: array<f32>;
@group(0) @binding(11) var<storage, read_write> particle_energy: array<f32>;

// Pipeline constant: the material law (as fem_forces' MATERIAL).
override MATERIAL: u32 = 0u;

const LANES: u32 = 4u;
const ITEMS_PER_WORKGROUP: u32 = 64u;

var<workgroup> lane_sums: array<mat3x3<f32>, 256>;

fn rest(p: u32) -> vec3<f32> {
    return vec3<f32>(particle_rest[3u * p], particle_rest[3u * p + 1u], particle_rest[3u * p + 2u]);
}

fn disp(p: u32) -> vec3<f32> {
    return vec3<f32>(particle_displacements[3u * p], particle_displacements[3u * p + 1u], particle_displacements[3u * p + 2u]);
}

fn kernel_gradient(d: vec3<f32>) -> vec3<f32> {
    if particle_params.model == 1u {
        return paper_gradient(d, particle_params.spacing, particle_params.support);
    }
    return wendland_gradient(d, particle_params.support);
}

fn store9(a: u32, p: u32, m: mat3x3<f32>) {
    for (var c = 0u; c < 3u; c++) {
        let v = m[c];
        if a == 0u {
            particle_stress[9u * p + 3u * c] = v.x;
            particle_stress[9u * p + 3u * c + 1u] = v.y;
            particle_stress[9u * p + 3u * c + 2u] = v.z;
        } else {
            particle_gradient[9u * p + 3u * c] = v.x;
            particle_gradient[9u * p + 3u * c + 1u] = v.y;
            particle_gradient[9u * p + 3u * c + 2u] = v.z;
        }
    }
}

@compute @workgroup_size(256)
fn sph_stress(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>, @builtin(local_invocation_index) local: u32) {
    let slot = local % ITEMS_PER_WORKGROUP;
    let lane = local / ITEMS_PER_WORKGROUP;
    let k = workgroup_index(wid, nwg) * ITEMS_PER_WORKGROUP + slot;
    let live = k < particle_counts[1];
    var p = 0u;
    var mine = mat3x3<f32>(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0));
    if live {
        p = stress_list[k];
        let x = rest(p);
        let up = disp(p);
        for (var n = neighbour_offsets[p] + lane; n < neighbour_offsets[p + 1u]; n += LANES) {
            let b = neighbours[n];
            let w = kernel_gradient(rest(b) - x) * particle_params.volume;
            let du = disp(b) - up;
            mine += mat3x3<f32>(du * w.x, du * w.y, du * w.z);
        }
    }
    lane_sums[local] = mine;
    workgroupBarrier();
    if !live || lane != 0u {
        return;
    }
    var s = lane_sums[slot];
    for (var j = 1u; j < LANES; j++) {
        s += lane_sums[slot + j * ITEMS_PER_WORKGROUP];
    }
    let c = 9u * p;
    let g = mat3x3<f32>(
        vec3<f32>(particle_correction[c], particle_correction[c + 1u], particle_correction[c + 2u]),
        vec3<f32>(particle_correction[c + 3u], particle_correction[c + 4u], particle_correction[c + 5u]),
        vec3<f32>(particle_correction[c + 6u], particle_correction[c + 7u], particle_correction[c + 8u]),
    );
    let h = s * g;
    var se: StressEnergy;
    if particle_params.model == 1u {
        let f = identity3() + h;
        let eps = transpose(f) * f - identity3();
        let tr = trace3(eps);
        se = StressEnergy(
            identity3() * (params.lambda * tr) + eps * (2.0 * params.mu),
            0.25 * params.mu * ddot(eps, eps) + 0.125 * params.lambda * tr * tr,
        );
    } else {
        se = material_stress_energy(MATERIAL, h, params.lambda, params.mu);
    }
    store9(0u, p, se.p * transpose(g));
    store9(1u, p, h);
    particle_energy[p] = particle_params.volume * se.psi;
}
