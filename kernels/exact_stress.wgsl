// Stage (design 8, `particles.coupling = "exact"`; every step). Two entry points:
//   exact_offsets  per particle of S that is dynamic or blending back onto its host (indirect
//                  over the stress list, which holds them all): its offset off its embedded
//                  place, delta_q = u_q - sum_a w_aq u_a (the others keep 0: an activation
//                  clears them);
//   exact_stress   per particle p of S (indirect over the stress list): the host tet's
//                  gradient H_bar = Du Dm^-1, the remainder gradient
//                  D_p = [sum_q V (delta_q - delta_p) (x) grad W(X_q - X_p)] G_p, and
//                    A_p = [P(F_bar + D) - P(F_bar)] G_p^T       -> particle_stress,
//                    H_bar + D_p                                 -> particle_gradient,
//                    V [Psi(F_bar + D) - Psi(F_bar) - P(F_bar):D] -> particle_energy,
//                  and the tangent term T = P(F_bar + D) - P(F_bar) - dP(F_bar)[D] on p's host
//                  tet as four corner forces [f1 f2 f3] = -V T Dm^-T, f0 = -(f1 + f2 + f3)
//                  (exact_tangent, 4 per particle).
// The tets keep their full energy; the particles add the Bregman remainder of their motion
// off their embedded place (docs/hybrid_coupling.md, design 8). CPU twins:
// src/cpu/exact_stages.rs (embedded_offsets, exact_stress). The neighbour sum has LANES
// threads per particle, added in lane order (the twin sums in list order: they agree to
// rounding).
#import params
#import index
#import particles
#import material

@group(0) @binding(0) var<uniform> params: StepParams;
@group(0) @binding(1) var<uniform> particle_params: ParticleParams;
@group(0) @binding(2) var<storage, read> particle_counts: array<u32>;
@group(0) @binding(4) var<storage, read> stress_list: array<u32>;
@group(0) @binding(5) var<storage, read> particle_rest: array<f32>;
@group(0) @binding(6) var<storage, read> particle_displacements: array<f32>;
@group(0) @binding(7) var<storage, read> particle_host: array<u32>;
@group(0) @binding(8) var<storage, read> particle_weights: array<f32>;
@group(0) @binding(9) var<storage, read> tets: array<vec4<u32>>;
@group(0) @binding(10) var<storage, read> dm_inv: array<f32>;
@group(0) @binding(11) var<storage, read> displacements: array<f32>;
@group(0) @binding(12) var<storage, read> neighbour_offsets: array<u32>;
@group(0) @binding(13) var<storage, read> neighbours: array<u32>;
@group(0) @binding(14) var<storage, read> particle_correction: array<f32>;
@group(0) @binding(15) var<storage, read_write> exact_delta: array<f32>;
@group(0) @binding(16) var<storage, read_write> particle_stress: array<f32>;
@group(0) @binding(17) var<storage, read_write> particle_gradient: array<f32>;
@group(0) @binding(18) var<storage, read_write> particle_energy: array<f32>;
@group(0) @binding(19) var<storage, read_write> exact_tangent: array<f32>;
@group(0) @binding(20) var<storage, read> particle_mode: array<u32>;

// Pipeline constant: the material law (as fem_forces' MATERIAL).
override MATERIAL: u32 = 0u;

const WORKGROUP: u32 = 64u;
const LANES: u32 = 4u;
const ITEMS_PER_WORKGROUP: u32 = 64u;

var<workgroup> lane_sums: array<mat3x3<f32>, 256>;

fn rest(p: u32) -> vec3<f32> {
    return vec3<f32>(particle_rest[3u * p], particle_rest[3u * p + 1u], particle_rest[3u * p + 2u]);
}

fn node_u(i: u32) -> vec3<f32> {
    return vec3<f32>(displacements[3u * i], displacements[3u * i + 1u], displacements[3u * i + 2u]);
}

fn delta(p: u32) -> vec3<f32> {
    return vec3<f32>(exact_delta[3u * p], exact_delta[3u * p + 1u], exact_delta[3u * p + 2u]);
}

fn correction(p: u32) -> mat3x3<f32> {
    let c = 9u * p;
    return mat3x3<f32>(
        vec3<f32>(particle_correction[c], particle_correction[c + 1u], particle_correction[c + 2u]),
        vec3<f32>(particle_correction[c + 3u], particle_correction[c + 4u], particle_correction[c + 5u]),
        vec3<f32>(particle_correction[c + 6u], particle_correction[c + 7u], particle_correction[c + 8u]),
    );
}

fn rest_inverse(e: u32) -> mat3x3<f32> {
    let c = 9u * e;
    return mat3x3<f32>(
        vec3<f32>(dm_inv[c], dm_inv[c + 1u], dm_inv[c + 2u]),
        vec3<f32>(dm_inv[c + 3u], dm_inv[c + 4u], dm_inv[c + 5u]),
        vec3<f32>(dm_inv[c + 6u], dm_inv[c + 7u], dm_inv[c + 8u]),
    );
}

fn store9(which: u32, p: u32, m: mat3x3<f32>) {
    for (var c = 0u; c < 3u; c++) {
        let v = m[c];
        if which == 0u {
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

fn store_tangent(k: u32, f: vec3<f32>) {
    exact_tangent[3u * k] = f.x;
    exact_tangent[3u * k + 1u] = f.y;
    exact_tangent[3u * k + 2u] = f.z;
}

@compute @workgroup_size(64)
fn exact_offsets(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let k = linear_index(gid, nwg, WORKGROUP);
    if k >= particle_counts[1] {
        return;
    }
    let q = stress_list[k];
    if (particle_mode[q] & (MODE_DYNAMIC | MODE_BLENDING)) == 0u {
        return;
    }
    let t = tets[particle_host[q]];
    let w = vec4<f32>(particle_weights[4u * q], particle_weights[4u * q + 1u], particle_weights[4u * q + 2u], particle_weights[4u * q + 3u]);
    let embedded = node_u(t.x) * w.x + node_u(t.y) * w.y + node_u(t.z) * w.z + node_u(t.w) * w.w;
    let u = vec3<f32>(particle_displacements[3u * q], particle_displacements[3u * q + 1u], particle_displacements[3u * q + 2u]);
    let d = u - embedded;
    exact_delta[3u * q] = d.x;
    exact_delta[3u * q + 1u] = d.y;
    exact_delta[3u * q + 2u] = d.z;
}

@compute @workgroup_size(256)
fn exact_stress(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>, @builtin(local_invocation_index) local: u32) {
    let slot = local % ITEMS_PER_WORKGROUP;
    let lane = local / ITEMS_PER_WORKGROUP;
    let k = workgroup_index(wid, nwg) * ITEMS_PER_WORKGROUP + slot;
    let live = k < particle_counts[1];
    var p = 0u;
    var mine = mat3x3<f32>(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0));
    if live {
        p = stress_list[k];
        let x = rest(p);
        let dp = delta(p);
        for (var n = neighbour_offsets[p] + lane; n < neighbour_offsets[p + 1u]; n += LANES) {
            let b = neighbours[n];
            let w = wendland_gradient(rest(b) - x, particle_params.support) * particle_params.volume;
            let dd = delta(b) - dp;
            mine += mat3x3<f32>(dd * w.x, dd * w.y, dd * w.z);
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
    let g = correction(p);
    let d = s * g;
    let e = particle_host[p];
    let t = tets[e];
    let dmi = rest_inverse(e);
    let u0 = node_u(t.x);
    let h_bar = mat3x3<f32>(node_u(t.y) - u0, node_u(t.z) - u0, node_u(t.w) - u0) * dmi;
    let se1 = material_stress_energy(MATERIAL, h_bar + d, params.lambda, params.mu);
    let se0 = material_stress_energy(MATERIAL, h_bar, params.lambda, params.mu);
    let dpd = material_stress_differential(MATERIAL, h_bar, d, params.lambda, params.mu);
    let v = particle_params.volume;
    store9(0u, p, (se1.p - se0.p) * transpose(g));
    store9(1u, p, h_bar + d);
    particle_energy[p] = v * (se1.psi - se0.psi - ddot(se0.p, d));
    let c = (se1.p - se0.p - dpd) * transpose(dmi) * (-v);
    store_tangent(4u * p, -(c[0] + c[1] + c[2]));
    store_tangent(4u * p + 1u, c[0]);
    store_tangent(4u * p + 2u, c[1]);
    store_tangent(4u * p + 3u, c[2]);
}
