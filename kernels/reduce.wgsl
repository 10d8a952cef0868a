// Stage: two-level tree reduction of kinetic energy, elastic energy, max speed, residual
// force, external load (gravity, pressures and, with CONTACT, the tool's contact forces) and
// mass-weighted squared displacement. `reduce_partial`: one
// workgroup per 256 indices (vertex i and tet i) writes 6 partials; `reduce_final`: one
// workgroup reduces the partials into `stats`. CPU twin: src/cpu/reduce.rs.
#import params
#import index
#import tool

@group(0) @binding(0) var<uniform> params: StepParams;
@group(0) @binding(1) var<storage, read> displacements: array<f32>;
@group(0) @binding(2) var<storage, read> velocities: array<f32>;
@group(0) @binding(3) var<storage, read> mass: array<f32>;
@group(0) @binding(4) var<storage, read> inv_mass: array<f32>;
@group(0) @binding(5) var<storage, read> forces: array<f32>;
@group(0) @binding(6) var<storage, read> external_forces: array<f32>;
@group(0) @binding(7) var<storage, read> tet_energy: array<f32>;
@group(0) @binding(8) var<storage, read_write> partials: array<f32>;
@group(0) @binding(9) var<storage, read_write> stats: array<f32>;
@group(0) @binding(10) var<storage, read> surface_index: array<u32>;
@group(0) @binding(11) var<storage, read> contact_forces: array<f32>;

// Pipeline constant: the scene has a tool (the contact force counts as external load).
override CONTACT: bool = false;

const WORKGROUP: u32 = 256u;
const PARTIAL_LEN: u32 = 6u;

var<workgroup> lanes: array<array<f32, 6>, 256>;

fn combine(l: u32, o: u32) {
    lanes[l][0] += lanes[o][0];
    lanes[l][1] += lanes[o][1];
    lanes[l][2] = max(lanes[l][2], lanes[o][2]);
    lanes[l][3] += lanes[o][3];
    lanes[l][4] += lanes[o][4];
    lanes[l][5] += lanes[o][5];
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

@compute @workgroup_size(256)
fn reduce_partial(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) l: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
) {
    let i = linear_index(gid, nwg, WORKGROUP);
    var lane = array<f32, 6>(0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    if i < params.n_vertices {
        let v = vec3<f32>(velocities[3u * i], velocities[3u * i + 1u], velocities[3u * i + 2u]);
        lane[0] = 0.5 * mass[i] * dot(v, v);
        lane[2] = length(v);
        if inv_mass[i] > 0.0 {
            let f = vec3<f32>(forces[3u * i], forces[3u * i + 1u], forces[3u * i + 2u]);
            lane[3] = dot(f, f);
            var w = params.gravity * mass[i]
                + vec3<f32>(external_forces[3u * i], external_forces[3u * i + 1u], external_forces[3u * i + 2u]);
            if CONTACT {
                let s = surface_index[i];
                if s != NOT_ON_SURFACE {
                    w += vec3<f32>(contact_forces[3u * s], contact_forces[3u * s + 1u], contact_forces[3u * s + 2u]);
                }
            }
            lane[4] = dot(w, w);
        }
        let u = vec3<f32>(displacements[3u * i], displacements[3u * i + 1u], displacements[3u * i + 2u]);
        lane[5] = mass[i] * dot(u, u);
    }
    if i < params.n_tets {
        lane[1] = tet_energy[i];
    }
    lanes[l] = lane;
    tree(l);
    if l == 0u {
        let block = wid.y * nwg.x + wid.x;
        for (var k = 0u; k < PARTIAL_LEN; k++) {
            partials[PARTIAL_LEN * block + k] = lanes[0][k];
        }
    }
}

@compute @workgroup_size(256)
fn reduce_final(@builtin(local_invocation_index) l: u32) {
    let n = (max(params.n_vertices, params.n_tets) + WORKGROUP - 1u) / WORKGROUP;
    var lane = array<f32, 6>(0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for (var k = l; k < n; k += WORKGROUP) {
        let b = PARTIAL_LEN * k;
        lane[0] += partials[b];
        lane[1] += partials[b + 1u];
        lane[2] = max(lane[2], partials[b + 2u]);
        lane[3] += partials[b + 3u];
        lane[4] += partials[b + 4u];
        lane[5] += partials[b + 5u];
    }
    lanes[l] = lane;
    tree(l);
    if l == 0u {
        let r = lanes[0];
        stats[STAT_KINETIC] = r[0];
        stats[STAT_ELASTIC] = r[1];
        stats[STAT_MAX_SPEED] = r[2];
        stats[STAT_RESIDUAL_SQ] = r[3];
        stats[STAT_EXTERNAL_SQ] = r[4];
        stats[STAT_MASS_DISPLACEMENT_SQ] = r[5];
    }
}
