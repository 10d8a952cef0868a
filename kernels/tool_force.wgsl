// Stage (last step of a batch): the force the tissue exerts on the tool, F = -sum f_i, and
// its frozen-tissue stiffness K = dF/dc = sum k A_i [(R/r)(I - n n^T) - I], with the tool
// and the vertices where the batch left them (tool_batch_end: `end`, or after a slice of the
// move, the move's position at that step); also the
// largest penetration, the number of contacts and their rest area. Two-level tree reduction
// like reduce.wgsl: tool_force_partial (128 surface vertices per workgroup),
// tool_force_particles (128 entries of the dynamic list per workgroup, blocks after the
// vertices'; scenes with particles; indirect over the dynamic list's arguments, which count
// 64-thread workgroups, so up to twice the blocks needed run and those past the buffer's
// blocks write nothing), tool_force_final (one workgroup: the vertices' blocks and the
// ceil(|D|/128) blocks of the dynamic list) -> tool_report. CPU twin: src/cpu/tool_force.rs.
#import params
#import tool
#import index

@group(0) @binding(0) var<uniform> params: StepParams;
@group(0) @binding(1) var<uniform> tool_params: ToolParams;
@group(0) @binding(2) var<uniform> tool_input: ToolInput;
@group(0) @binding(3) var<storage, read> surface_vertices: array<u32>;
@group(0) @binding(4) var<storage, read> surface_area: array<f32>;
@group(0) @binding(5) var<storage, read> rest_positions: array<f32>;
@group(0) @binding(6) var<storage, read> displacements: array<f32>;
@group(0) @binding(7) var<storage, read> velocities: array<f32>;
@group(0) @binding(8) var<storage, read_write> tool_partials: array<f32>;
@group(0) @binding(9) var<storage, read_write> tool_report: array<f32>;
@group(0) @binding(10) var<storage, read> contact_weight: array<f32>;
@group(0) @binding(11) var<storage, read> particle_mode: array<u32>;
@group(0) @binding(12) var<storage, read> particle_rest: array<f32>;
@group(0) @binding(13) var<storage, read> particle_displacements: array<f32>;
@group(0) @binding(14) var<storage, read> particle_velocities: array<f32>;
@group(0) @binding(15) var<storage, read> particle_area: array<f32>;
@group(0) @binding(16) var<storage, read> particle_gradient: array<f32>;
@group(0) @binding(17) var<storage, read> particle_contact_offset: array<f32>;
@group(0) @binding(18) var<storage, read> particle_counts: array<u32>;
@group(0) @binding(19) var<storage, read> dynamic_list: array<u32>;
@group(0) @binding(20) var<storage, read> tool_state: ToolState;

// Pipeline constant: the scene has particles (vertex contacts are weighted as in contact.wgsl;
// tool_force_particles adds the dynamic particles' contacts in blocks after the vertices').
override PARTICLES: bool = false;
const MODE_DYNAMIC: u32 = 1u;

const WORKGROUP: u32 = 128u;
const LANE: u32 = 15u;

var<workgroup> lanes: array<array<f32, 15>, 128>;

fn position(i: u32) -> vec3<f32> {
    return vec3<f32>(rest_positions[3u * i], rest_positions[3u * i + 1u], rest_positions[3u * i + 2u])
        + vec3<f32>(displacements[3u * i], displacements[3u * i + 1u], displacements[3u * i + 2u]);
}

fn velocity(i: u32) -> vec3<f32> {
    return vec3<f32>(velocities[3u * i], velocities[3u * i + 1u], velocities[3u * i + 2u]);
}

// Lane layout: 0..3 force on the tool, 3..12 stiffness (column-major), 12 max penetration,
// 13 contacts, 14 area in contact.
fn combine(l: u32, o: u32) {
    for (var k = 0u; k < LANE; k++) {
        if k == 12u {
            lanes[l][k] = max(lanes[l][k], lanes[o][k]);
        } else {
            lanes[l][k] += lanes[o][k];
        }
    }
}

fn tree(l: u32) {
    for (var s = WORKGROUP / 2u; s > 0u; s = s / 2u) {
        workgroupBarrier();
        if l < s {
            combine(l, l + s);
        }
    }
    workgroupBarrier();
}

// The lane of one contact point at x (velocity v, rest area share `area`).
fn contact_lane(x: vec3<f32>, v: vec3<f32>, area: f32) -> array<f32, 15> {
    var lane: array<f32, 15>;
    for (var k = 0u; k < LANE; k++) {
        lane[k] = 0.0;
    }
    let vc = (tool_input.end - tool_input.start) / (f32(max(tool_input.steps, 1u)) * params.dt);
    let c = contact_force(tool_params, x, v, tool_batch_end(tool_input, tool_state), vc, area);
    if c.penetration > 0.0 {
        let n = c.normal;
        let a = tool_params.radius / c.distance;
        let ka = tool_params.stiffness * area;
        lane[0] = -c.force.x;
        lane[1] = -c.force.y;
        lane[2] = -c.force.z;
        for (var col = 0u; col < 3u; col++) {
            for (var row = 0u; row < 3u; row++) {
                var delta = 0.0;
                if row == col {
                    delta = 1.0;
                }
                lane[3u + 3u * col + row] = ka * (a * (delta - n[row] * n[col]) - delta);
            }
        }
        lane[12] = c.penetration;
        lane[13] = 1.0;
        lane[14] = area;
    }
    return lane;
}

fn finish_block(l: u32, block: u32) {
    tree(l);
    if l == 0u {
        for (var k = 0u; k < LANE; k++) {
            tool_partials[LANE * block + k] = lanes[0][k];
        }
    }
}

@compute @workgroup_size(128)
fn tool_force_partial(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) l: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
) {
    let s = linear_index(gid, nwg, WORKGROUP);
    var lane: array<f32, 15>;
    for (var k = 0u; k < LANE; k++) {
        lane[k] = 0.0;
    }
    if s < tool_params.n_surface {
        let i = surface_vertices[s];
        var area = surface_area[s];
        if PARTICLES {
            area *= contact_weight[i];
        }
        lane = contact_lane(position(i), velocity(i), area);
    }
    lanes[l] = lane;
    finish_block(l, wid.y * nwg.x + wid.x);
}

@compute @workgroup_size(128)
fn tool_force_particles(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) l: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
) {
    let d = linear_index(gid, nwg, WORKGROUP);
    var lane: array<f32, 15>;
    for (var k = 0u; k < LANE; k++) {
        lane[k] = 0.0;
    }
    var p = 0u;
    var touches = false;
    if d < particle_counts[0] {
        // (the list is the last activation's, written and checkpointed with the modes; the
        // mode is checked all the same)
        p = dynamic_list[d];
        touches = (particle_mode[p] & MODE_DYNAMIC) != 0u && particle_area[p] > 0.0;
    }
    if touches {
        let g = 9u * p;
        let f = mat3x3<f32>(
            vec3<f32>(1.0 + particle_gradient[g], particle_gradient[g + 1u], particle_gradient[g + 2u]),
            vec3<f32>(particle_gradient[g + 3u], 1.0 + particle_gradient[g + 4u], particle_gradient[g + 5u]),
            vec3<f32>(particle_gradient[g + 6u], particle_gradient[g + 7u], 1.0 + particle_gradient[g + 8u]),
        );
        let o = vec3<f32>(particle_contact_offset[3u * p], particle_contact_offset[3u * p + 1u], particle_contact_offset[3u * p + 2u]);
        let x = vec3<f32>(particle_rest[3u * p], particle_rest[3u * p + 1u], particle_rest[3u * p + 2u])
            + vec3<f32>(particle_displacements[3u * p], particle_displacements[3u * p + 1u], particle_displacements[3u * p + 2u])
            + f * o;
        let v = vec3<f32>(particle_velocities[3u * p], particle_velocities[3u * p + 1u], particle_velocities[3u * p + 2u]);
        lane = contact_lane(x, v, particle_area[p]);
    }
    lanes[l] = lane;
    tree(l);
    let block = wid.y * nwg.x + wid.x;
    if l == 0u && block < (tool_params.n_particles + WORKGROUP - 1u) / WORKGROUP {
        let at = (tool_params.n_surface + WORKGROUP - 1u) / WORKGROUP + block;
        for (var k = 0u; k < LANE; k++) {
            tool_partials[LANE * at + k] = lanes[0][k];
        }
    }
}

@compute @workgroup_size(128)
fn tool_force_final(@builtin(local_invocation_index) l: u32) {
    var n = (tool_params.n_surface + WORKGROUP - 1u) / WORKGROUP;
    if PARTICLES {
        n += (particle_counts[0] + WORKGROUP - 1u) / WORKGROUP;
    }
    var lane: array<f32, 15>;
    for (var k = 0u; k < LANE; k++) {
        lane[k] = 0.0;
    }
    for (var b = l; b < n; b += WORKGROUP) {
        for (var k = 0u; k < LANE; k++) {
            let p = tool_partials[LANE * b + k];
            if k == 12u {
                lane[k] = max(lane[k], p);
            } else {
                lane[k] += p;
            }
        }
    }
    lanes[l] = lane;
    tree(l);
    if l == 0u {
        for (var k = 0u; k < LANE; k++) {
            tool_report[k] = lanes[0][k];
        }
        tool_report[15] = 0.0;
    }
}
