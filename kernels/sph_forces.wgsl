// Stage (every particle sub-step; indirect over the force set F): the force on each particle
// from the SPH strain energy E = sum_{p in S} V Psi(F_p) (total-Lagrangian SPH):
//   tlsph: f_c = -dE/dx_c = V^2 sum_b (A_c + A_b) grad W(X_b - X_c), A = P G^T for particles
//          in S and 0 outside (an exact gradient: linear and angular momentum are conserved);
//          plus Ganzenmueller's (2015) hourglass penalty on pairs with a dynamic particle
//          (followers move with their tets and cannot form a zig-zag mode), a central pair force
//          f_c += alpha E V^2 W(X_cb)/|X_cb|^2 (delta_cb + delta_bc)/2 x_cb/|x_cb|,
//          delta_ab = (F_a X_ab - x_ab).x_ab/|x_ab| (zero for affine motion), evaluated
//          without a square root as ((F_c + F_b) X_cb).x_cb/|x_cb|^2 - 2 (a side outside S
//          drops its F and counts 0);
//   paper: eq. (13) as printed, one-sided: f_c = V^2 sum_b A_b grad W(X_b - X_c).
// Dynamic particles also get m g and the tool's contact on surface particles (area Δx^2),
// taken at x_p + F_p o_p (o_p the rest offset to the true surface, which the lattice's outer
// layer lies inside of), kept in particle_contact (the last sub-step's, a diagnostic the tests
// compare with the twin; the tool's report is recomputed by tool_force). particle_force_sum collects f/substeps
// over the sub-steps of a core step (ACCUMULATE is false on the first): embedded particles
// pass it to their host vertices in gather_coupled, so the vertices receive the impulse
// the particles received. CPU twin: src/cpu/sph_forces.rs. Each particle has LANES threads:
// lane j sums the pair terms of neighbours j, j + LANES, … and lane 0 adds the lanes' sums in
// lane order, then gravity and contact (the twin sums in list order: the two agree to
// rounding). One thread walking ~26 neighbours is a chain of dependent loads whose latency
// bounds the stage when F holds a few hundred particles (NVIDIA H200, 2026-11-27:
// BENCHMARKS.md).
#import params
#import index
#import tool
#import particles
#import material

@group(0) @binding(0) var<uniform> params: StepParams;
@group(0) @binding(1) var<uniform> particle_params: ParticleParams;
@group(0) @binding(2) var<uniform> tool_params: ToolParams;
@group(0) @binding(3) var<uniform> tool_input: ToolInput;
@group(0) @binding(4) var<storage, read> tool_state: ToolState;
@group(0) @binding(5) var<storage, read> particle_counts: array<u32>;
@group(0) @binding(6) var<storage, read> force_list: array<u32>;
@group(0) @binding(7) var<storage, read> particle_mode: array<u32>;
@group(0) @binding(8) var<storage, read> particle_rest: array<f32>;
@group(0) @binding(9) var<storage, read> particle_displacements: array<f32>;
@group(0) @binding(10) var<storage, read> particle_velocities: array<f32>;
@group(0) @binding(11) var<storage, read> neighbour_offsets: array<u32>;
@group(0) @binding(12) var<storage, read> neighbours: array<u32>;
@group(0) @binding(13) var<storage, read> particle_stress: array<f32>;
@group(0) @binding(14) var<storage, read> particle_gradient: array<f32>;
@group(0) @binding(15) var<storage, read> particle_area: array<f32>;
@group(0) @binding(16) var<storage, read_write> particle_forces: array<f32>;
@group(0) @binding(17) var<storage, read_write> particle_force_sum: array<f32>;
@group(0) @binding(18) var<storage, read_write> particle_contact: array<f32>;
@group(0) @binding(19) var<storage, read> particle_contact_offset: array<f32>;

// Pipeline constants: add to particle_force_sum (not the first sub-step); the scene has a tool.
override ACCUMULATE: bool = false;
override TOOL: bool = false;

const LANES: u32 = 4u;
const ITEMS_PER_WORKGROUP: u32 = 64u;

var<workgroup> lane_sums: array<vec3<f32>, 256>;

fn rest(p: u32) -> vec3<f32> {
    return vec3<f32>(particle_rest[3u * p], particle_rest[3u * p + 1u], particle_rest[3u * p + 2u]);
}

fn disp(p: u32) -> vec3<f32> {
    return vec3<f32>(particle_displacements[3u * p], particle_displacements[3u * p + 1u], particle_displacements[3u * p + 2u]);
}

fn mat(p: u32, which: u32) -> mat3x3<f32> {
    let c = 9u * p;
    if which == 0u {
        return mat3x3<f32>(
            vec3<f32>(particle_stress[c], particle_stress[c + 1u], particle_stress[c + 2u]),
            vec3<f32>(particle_stress[c + 3u], particle_stress[c + 4u], particle_stress[c + 5u]),
            vec3<f32>(particle_stress[c + 6u], particle_stress[c + 7u], particle_stress[c + 8u]),
        );
    }
    return mat3x3<f32>(
        vec3<f32>(particle_gradient[c], particle_gradient[c + 1u], particle_gradient[c + 2u]),
        vec3<f32>(particle_gradient[c + 3u], particle_gradient[c + 4u], particle_gradient[c + 5u]),
        vec3<f32>(particle_gradient[c + 6u], particle_gradient[c + 7u], particle_gradient[c + 8u]),
    );
}

fn kernel_gradient(d: vec3<f32>) -> vec3<f32> {
    return model_kernel_gradient(particle_params.model, d, particle_params.spacing, particle_params.support);
}

fn store3(p: u32, which: u32, v: vec3<f32>) {
    if which == 0u {
        particle_forces[3u * p] = v.x;
        particle_forces[3u * p + 1u] = v.y;
        particle_forces[3u * p + 2u] = v.z;
    } else if which == 1u {
        particle_force_sum[3u * p] = v.x;
        particle_force_sum[3u * p + 1u] = v.y;
        particle_force_sum[3u * p + 2u] = v.z;
    } else {
        particle_contact[3u * p] = v.x;
        particle_contact[3u * p + 1u] = v.y;
        particle_contact[3u * p + 2u] = v.z;
    }
}

@compute @workgroup_size(256)
fn sph_forces(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>, @builtin(local_invocation_index) local: u32) {
    let slot = local % ITEMS_PER_WORKGROUP;
    let lane = local / ITEMS_PER_WORKGROUP;
    let k = workgroup_index(wid, nwg) * ITEMS_PER_WORKGROUP + slot;
    let live = k < particle_counts[2];
    var c = 0u;
    if live {
        c = force_list[k];
    }
    lane_sums[local] = pair_forces(c, lane, live);
    workgroupBarrier();
    if !live || lane != 0u {
        return;
    }
    var f = lane_sums[slot];
    for (var j = 1u; j < LANES; j++) {
        f += lane_sums[slot + j * ITEMS_PER_WORKGROUP];
    }
    finish(c, f);
}

// This lane's share of the pair forces on particle c (zero when not `live`).
fn pair_forces(c: u32, lane: u32, live: bool) -> vec3<f32> {
    var f = vec3<f32>(0.0);
    if !live {
        return f;
    }
    let pp = particle_params;
    let mode_c = particle_mode[c];
    let in_s_c = (mode_c & MODE_IN_S) != 0u;
    let x0c = rest(c);
    let uc = disp(c);
    var a_c = mat3x3<f32>(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0));
    var f_c = identity3();
    if in_s_c {
        a_c = mat(c, 0u);
        f_c = identity3() + mat(c, 1u);
    }
    let v2 = pp.volume * pp.volume;
    let hg = 0.5 * pp.hourglass * pp.youngs * v2;
    for (var n = neighbour_offsets[c] + lane; n < neighbour_offsets[c + 1u]; n += LANES) {
        let b = neighbours[n];
        let mode_b = particle_mode[b];
        let in_s_b = (mode_b & MODE_IN_S) != 0u;
        if !in_s_c && !in_s_b {
            continue;
        }
        let x0b = rest(b);
        let w = kernel_gradient(x0b - x0c);
        var a_b = mat3x3<f32>(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0));
        if in_s_b {
            a_b = mat(b, 0u);
        }
        if pp.model == 1u {
            f += (a_b * w) * v2;
        } else {
            f += ((a_c + a_b) * w) * v2;
            if pp.hourglass > 0.0 && ((mode_c | mode_b) & MODE_DYNAMIC) != 0u {
                let x0cb = x0c - x0b;
                let xcb = x0cb + uc - disp(b);
                let r2 = dot(xcb, xcb);
                let r0 = length(x0cb);
                if r2 > 0.0 && r0 > 0.0 {
                    // delta/r = (sum over the sides in S of (F X_cb).x_cb)/r^2 - (their count).
                    var g = vec3<f32>(0.0);
                    var sides = 0.0;
                    if in_s_c {
                        g += f_c * x0cb;
                        sides += 1.0;
                    }
                    if in_s_b {
                        g += (identity3() + mat(b, 1u)) * x0cb;
                        sides += 1.0;
                    }
                    f += xcb * (hg * wendland(r0, pp.support) / (r0 * r0) * (dot(g, xcb) / r2 - sides));
                }
            }
        }
    }
    return f;
}

// Particle c's force from its pair forces `pairs`: gravity and contact on a dynamic particle,
// then the stores.
fn finish(c: u32, pairs: vec3<f32>) {
    let pp = particle_params;
    let mode_c = particle_mode[c];
    let x0c = rest(c);
    let uc = disp(c);
    var f_c = identity3();
    if (mode_c & MODE_IN_S) != 0u {
        f_c = identity3() + mat(c, 1u);
    }
    var f = pairs;
    var contact = vec3<f32>(0.0);
    if (mode_c & MODE_DYNAMIC) != 0u {
        f += params.gravity * pp.mass;
        let area = particle_area[c];
        if TOOL && area > 0.0 {
            let vc = (tool_input.end - tool_input.start) / (f32(max(tool_input.steps, 1u)) * params.dt);
            let v = vec3<f32>(particle_velocities[3u * c], particle_velocities[3u * c + 1u], particle_velocities[3u * c + 2u]);
            let o = vec3<f32>(particle_contact_offset[3u * c], particle_contact_offset[3u * c + 1u], particle_contact_offset[3u * c + 2u]);
            contact = contact_force(tool_params, x0c + uc + f_c * o, v, tool_state.position, vc, area).force;
            f += contact;
        }
    }
    store3(c, 0u, f);
    store3(c, 2u, contact);
    var sum = f / f32(max(pp.substeps, 1u));
    if ACCUMULATE {
        sum += vec3<f32>(particle_force_sum[3u * c], particle_force_sum[3u * c + 1u], particle_force_sum[3u * c + 2u]);
    }
    store3(c, 1u, sum);
}
