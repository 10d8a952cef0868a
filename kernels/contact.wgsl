// Stage: per boundary-surface vertex, the penalty contact force of the tool (a sphere):
// f = A (k d - b min(0, (v - v_tool).n)) n for penetration d = R - |x - c| > 0, with
// x = X + u the vertex position, A its share of the rest surface area, n = (x - c)/|x - c|
// (src/contact.rs). The tool moves at v_tool = (end - start)/(steps dt) during the batch.
// Writes contact_forces[s]; gather adds it to the vertex. CPU twin: src/cpu/contact.rs.
// `contact_sph_stress` does the same per surface vertex (lane 1 of each of a 256-thread
// workgroup's 64 slots) and, on the same grid, sph_stress.wgsl's work over the stress set S
// (shared/sph_stress_particle.wgsl, 64 entries a workgroup with 4 lanes each): the two read
// nothing the other writes, so the GPU records this one dispatch in place of the sph_stress
// and contact passes when the plan allows (`StepPlan::gpu_fusions`). Its grid is indirect,
// the larger of S's and the surface's (compact.wgsl's fourth arguments), so S takes one
// round; the loop takes more only on a grid that does not cover it.
#import params
#import tool
#import index
#import sph_stress_particle

@group(0) @binding(0) var<uniform> params: StepParams;
@group(0) @binding(1) var<uniform> tool_params: ToolParams;
@group(0) @binding(2) var<uniform> tool_input: ToolInput;
@group(0) @binding(3) var<storage, read> tool_state: ToolState;
@group(0) @binding(4) var<storage, read> surface_vertices: array<u32>;
@group(0) @binding(5) var<storage, read> surface_area: array<f32>;
@group(0) @binding(6) var<storage, read> rest_positions: array<f32>;
@group(0) @binding(7) var<storage, read> displacements: array<f32>;
@group(0) @binding(8) var<storage, read> velocities: array<f32>;
@group(0) @binding(9) var<storage, read_write> contact_forces: array<f32>;
@group(0) @binding(10) var<storage, read> contact_weight: array<f32>;

// Pipeline constant: the scene has particles; a vertex's contact is then scaled by
// contact_weight (the smallest energy weight of its tets: where dynamic particles carry the
// surface, they take the contact).
override PARTICLES: bool = false;

const WORKGROUP: u32 = 64u;
// Surface vertices a workgroup takes (`contact_sph_stress` also 64: one thread each, lane 1
// of its 256 threads).
const ITEMS_PER_WORKGROUP: u32 = 64u;

fn position(i: u32) -> vec3<f32> {
    return vec3<f32>(rest_positions[3u * i], rest_positions[3u * i + 1u], rest_positions[3u * i + 2u])
        + vec3<f32>(displacements[3u * i], displacements[3u * i + 1u], displacements[3u * i + 2u]);
}

fn velocity(i: u32) -> vec3<f32> {
    return vec3<f32>(velocities[3u * i], velocities[3u * i + 1u], velocities[3u * i + 2u]);
}

@compute @workgroup_size(64)
fn contact(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let s = linear_index(gid, nwg, WORKGROUP);
    if s < tool_params.n_surface {
        contact_at(s);
    }
}

@compute @workgroup_size(256)
fn contact_sph_stress(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>, @builtin(local_invocation_index) local: u32) {
    let first = workgroup_index(wid, nwg);
    // The second 64 threads (lane 1: lane 0 also ends each stress entry).
    let s = first * ITEMS_PER_WORKGROUP + local % ITEMS_PER_WORKGROUP;
    if local / ITEMS_PER_WORKGROUP == 1u && s < tool_params.n_surface {
        contact_at(s);
    }
    let groups = nwg.x * nwg.y;
    let per_round = groups * SPH_STRESS_ITEMS;
    let rounds = (particle_counts[1] + per_round - 1u) / per_round;
    for (var r = 0u; r < rounds; r++) {
        if r > 0u {
            workgroupBarrier();
        }
        sph_stress_entry((r * groups + first) * SPH_STRESS_ITEMS + local % SPH_STRESS_ITEMS, local, params.lambda, params.mu, params.phi, params.psi);
    }
}

// The contact force of surface vertex s.
fn contact_at(s: u32) {
    let i = surface_vertices[s];
    let x = position(i);
    let v = velocity(i);
    let vc = (tool_input.end - tool_input.start) / (f32(max(tool_input.steps, 1u)) * params.dt);
    var area = surface_area[s];
    if PARTICLES {
        area *= contact_weight[i];
    }
    let c = contact_force(tool_params, x, v, tool_state.position, vc, area);
    contact_forces[3u * s] = c.force.x;
    contact_forces[3u * s + 1u] = c.force.y;
    contact_forces[3u * s + 2u] = c.force.z;
}
