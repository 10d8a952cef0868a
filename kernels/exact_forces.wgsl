// Stage (design 8, `particles.coupling = "exact"`; every step; indirect over the force set F):
// per particle c, the pair terms of sph_forces' tlsph model, kept apart:
//   pair       V^2 sum_b (A_c + A_b) grad W(X_b - X_c) (A from exact_stress: the remainder's
//              stress; 0 outside S),
//   hourglass  Ganzenmueller's penalty on pairs with a dynamic end (as in sph_forces).
// A dynamic particle takes pair + hourglass + m g + the tool's contact (particle_forces,
// particle_contact) and its host vertices take -pair through its weights (exact_host_force:
// the remainder's force on the embedded place); a follower takes no pair force (its delta is
// 0 whatever its hosts do) and passes its hourglass force to its hosts. CPU twin:
// src/cpu/exact_stages.rs (exact_forces). Each particle has LANES threads, their sums added
// in lane order (the twin sums in list order: they agree to rounding).
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
@group(0) @binding(16) var<storage, read> particle_contact_offset: array<f32>;
@group(0) @binding(17) var<storage, read_write> particle_forces: array<f32>;
@group(0) @binding(18) var<storage, read_write> particle_contact: array<f32>;
@group(0) @binding(19) var<storage, read_write> exact_host_force: array<f32>;

// Pipeline constant: the scene has a tool.
override TOOL: bool = false;

const LANES: u32 = 4u;
const ITEMS_PER_WORKGROUP: u32 = 64u;

var<workgroup> lane_pairs: array<vec3<f32>, 256>;
var<workgroup> lane_hourglass: array<vec3<f32>, 256>;

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

fn store3(which: u32, p: u32, v: vec3<f32>) {
    if which == 0u {
        particle_forces[3u * p] = v.x;
        particle_forces[3u * p + 1u] = v.y;
        particle_forces[3u * p + 2u] = v.z;
    } else if which == 1u {
        particle_contact[3u * p] = v.x;
        particle_contact[3u * p + 1u] = v.y;
        particle_contact[3u * p + 2u] = v.z;
    } else {
        exact_host_force[3u * p] = v.x;
        exact_host_force[3u * p + 1u] = v.y;
        exact_host_force[3u * p + 2u] = v.z;
    }
}

@compute @workgroup_size(256)
fn exact_forces(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>, @builtin(local_invocation_index) local: u32) {
    let slot = local % ITEMS_PER_WORKGROUP;
    let lane = local / ITEMS_PER_WORKGROUP;
    let k = workgroup_index(wid, nwg) * ITEMS_PER_WORKGROUP + slot;
    let live = k < particle_counts[2];
    var c = 0u;
    var pair = vec3<f32>(0.0);
    var hourglass = vec3<f32>(0.0);
    if live {
        c = force_list[k];
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
            let w = wendland_gradient(x0b - x0c, pp.support);
            var a_b = mat3x3<f32>(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0));
            if in_s_b {
                a_b = mat(b, 0u);
            }
            pair += ((a_c + a_b) * w) * v2;
            if pp.hourglass > 0.0 && ((mode_c | mode_b) & MODE_DYNAMIC) != 0u {
                let x0cb = x0c - x0b;
                let xcb = x0cb + uc - disp(b);
                let r2 = dot(xcb, xcb);
                let r0 = length(x0cb);
                if r2 > 0.0 && r0 > 0.0 {
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
                    hourglass += xcb * (hg * wendland(r0, pp.support) / (r0 * r0) * (dot(g, xcb) / r2 - sides));
                }
            }
        }
    }
    lane_pairs[local] = pair;
    lane_hourglass[local] = hourglass;
    workgroupBarrier();
    if !live || lane != 0u {
        return;
    }
    for (var j = 1u; j < LANES; j++) {
        pair += lane_pairs[slot + j * ITEMS_PER_WORKGROUP];
        hourglass += lane_hourglass[slot + j * ITEMS_PER_WORKGROUP];
    }
    let mode_c = particle_mode[c];
    if (mode_c & MODE_DYNAMIC) == 0u {
        store3(0u, c, hourglass);
        store3(1u, c, vec3<f32>(0.0));
        store3(2u, c, hourglass);
        return;
    }
    var f = pair + hourglass + params.gravity * particle_params.mass;
    var contact = vec3<f32>(0.0);
    let area = particle_area[c];
    if TOOL && area > 0.0 {
        var f_c = identity3();
        if (mode_c & MODE_IN_S) != 0u {
            f_c = identity3() + mat(c, 1u);
        }
        let vc = (tool_input.end - tool_input.start) / (f32(max(tool_input.steps, 1u)) * params.dt);
        let v = vec3<f32>(particle_velocities[3u * c], particle_velocities[3u * c + 1u], particle_velocities[3u * c + 2u]);
        let o = vec3<f32>(particle_contact_offset[3u * c], particle_contact_offset[3u * c + 1u], particle_contact_offset[3u * c + 2u]);
        contact = contact_force(tool_params, rest(c) + disp(c) + f_c * o, v, tool_state.position, vc, area).force;
        f += contact;
    }
    store3(0u, c, f);
    store3(1u, c, contact);
    store3(2u, c, -pair);
}
