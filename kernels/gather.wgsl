// Stage: per vertex, f = m g + f_ext + sum of incident corner forces over the CSR incidence list
// (vertex -> tet*4 + corner). No float atomics: deterministic. CPU twin: src/cpu/gather.rs.
// Each vertex has LANES threads: lane j sums the list entries j, j + LANES, … and lane 0 adds
// the lanes' sums in lane order (a fixed order; the twin sums in list order, so the two agree
// to rounding). One thread walking a vertex's ~20–100 entries is a chain of dependent loads
// whose latency, not bandwidth, bounds a small mesh's step on a real GPU (measured on an
// NVIDIA H200, 2026-11-27: BENCHMARKS.md).
// `gather` is the plain FEM sum; `gather_coupled` (scenes with a tool or particles) adds the
// tool's contact force on a surface vertex (CONTACT) and the forces on the embedded particles
// the vertex hosts, w_i f_p, over the CSR vertex -> particle slots (PARTICLES): over the short
// list of its force-set embedded particles' slots that activate_relump wrote at
// coupled_slots[offset_i ..] (coupled_count[i] of them, in CSR order) while coupled_valid[0] is
// set, else (before the first activation) over every slot. A checkpoint saves the lists with
// the modes they were built from.
// `gather_exact` (design 8, `particles.coupling = "exact"`) adds to the core sum and the
// contact, over every slot (p, a) of vertex i whose particle p is in the force set F,
// w_ap exact_host_force_p + exact_tangent_(p,a) (exact_forces' and exact_stress' outputs).
// `gather_coupled_integrate` does gather_coupled's work and, on the same grid, the dynamic
// particles' symplectic Euler (integrate_particles.wgsl's work, a grid-stride loop over the
// dynamic list: thread t takes entries t, t + T, …, T the grid's threads, which the host
// grows so that it takes at most MAX_RIDER_ROUNDS: Domain::CoveringParticles): the gather reads
// no particle position or velocity and the integration no vertex array, so the GPU records
// this one dispatch in place of the integrate_particles and gather_coupled passes when the
// plan allows (`StepPlan::gpu_fusions`).
#import params
#import index
#import tool
#import particles
#import integrate_particle

@group(0) @binding(0) var<uniform> params: StepParams;
@group(0) @binding(1) var<storage, read> corner_forces: array<f32>;
@group(0) @binding(2) var<storage, read> incidence_offsets: array<u32>;
@group(0) @binding(3) var<storage, read> incidence: array<u32>;
@group(0) @binding(4) var<storage, read> mass: array<f32>;
@group(0) @binding(5) var<storage, read> external_forces: array<f32>;
@group(0) @binding(6) var<storage, read_write> forces: array<f32>;
@group(0) @binding(7) var<storage, read> surface_index: array<u32>;
@group(0) @binding(8) var<storage, read> contact_forces: array<f32>;
@group(0) @binding(9) var<storage, read> node_flags: array<u32>;
@group(0) @binding(10) var<storage, read> particle_slot_offsets: array<u32>;
@group(0) @binding(11) var<storage, read> particle_slots: array<u32>;
@group(0) @binding(12) var<storage, read> particle_weights: array<f32>;
@group(0) @binding(13) var<storage, read> particle_mode: array<u32>;
@group(0) @binding(14) var<storage, read> particle_force_sum: array<f32>;
@group(0) @binding(15) var<storage, read> coupled_slots: array<u32>;
@group(0) @binding(16) var<storage, read> coupled_count: array<u32>;
@group(0) @binding(17) var<storage, read> coupled_valid: array<u32>;
@group(0) @binding(18) var<storage, read> exact_host_force: array<f32>;
@group(0) @binding(19) var<storage, read> exact_tangent: array<f32>;
// gather_coupled_integrate's dynamic list (the other integration arrays are
// shared/integrate_particle.wgsl's).
@group(0) @binding(20) var<storage, read> particle_counts: array<u32>;
@group(0) @binding(21) var<storage, read> dynamic_list: array<u32>;

// Pipeline constants of gather_coupled: the scene has a tool / particles.
override CONTACT: bool = false;
override PARTICLES: bool = false;

const LANES: u32 = 4u;
const ITEMS_PER_WORKGROUP: u32 = 64u;

var<workgroup> lane_sums: array<vec3<f32>, 256>;

// This lane's share of vertex i's incident corner forces.
fn sum_corners(i: u32, lane: u32) -> vec3<f32> {
    var f = vec3<f32>(0.0);
    for (var k = incidence_offsets[i] + lane; k < incidence_offsets[i + 1u]; k += LANES) {
        let c = incidence[k];
        f += vec3<f32>(corner_forces[3u * c], corner_forces[3u * c + 1u], corner_forces[3u * c + 2u]);
    }
    return f;
}

// The body load on vertex i: m g + f_ext.
fn body_force(i: u32) -> vec3<f32> {
    return params.gravity * mass[i]
        + vec3<f32>(external_forces[3u * i], external_forces[3u * i + 1u], external_forces[3u * i + 2u]);
}

// The item's lanes' sums added in lane order (call in uniform control flow: it has a barrier).
fn add_lanes(local: u32, mine: vec3<f32>) -> vec3<f32> {
    lane_sums[local] = mine;
    workgroupBarrier();
    let slot = local % ITEMS_PER_WORKGROUP;
    var f = lane_sums[slot];
    for (var j = 1u; j < LANES; j++) {
        f += lane_sums[slot + j * ITEMS_PER_WORKGROUP];
    }
    return f;
}

// f plus the tool's contact force on vertex i when it is on the surface (CONTACT).
fn with_contact(i: u32, f: vec3<f32>) -> vec3<f32> {
    if CONTACT {
        let s = surface_index[i];
        if s != NOT_ON_SURFACE {
            return f + vec3<f32>(contact_forces[3u * s], contact_forces[3u * s + 1u], contact_forces[3u * s + 2u]);
        }
    }
    return f;
}

fn store(i: u32, f: vec3<f32>) {
    forces[3u * i] = f.x;
    forces[3u * i + 1u] = f.y;
    forces[3u * i + 2u] = f.z;
}

@compute @workgroup_size(256)
fn gather(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>, @builtin(local_invocation_index) local: u32) {
    let i = workgroup_index(wid, nwg) * ITEMS_PER_WORKGROUP + local % ITEMS_PER_WORKGROUP;
    let lane = local / ITEMS_PER_WORKGROUP;
    let live = i < params.n_vertices;
    var mine = vec3<f32>(0.0);
    if live {
        mine = sum_corners(i, lane);
    }
    let f = add_lanes(local, mine);
    if live && lane == 0u {
        store(i, body_force(i) + f);
    }
}

@compute @workgroup_size(256)
fn gather_coupled(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>, @builtin(local_invocation_index) local: u32) {
    coupled_vertex(wid, nwg, local);
}

@compute @workgroup_size(256)
fn gather_coupled_integrate(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>, @builtin(local_invocation_index) local: u32) {
    coupled_vertex(wid, nwg, local);
    let threads = nwg.x * nwg.y * LANES * ITEMS_PER_WORKGROUP;
    let n = particle_counts[0];
    for (var k = workgroup_index(wid, nwg) * LANES * ITEMS_PER_WORKGROUP + local; k < n; k += threads) {
        integrate_particle(dynamic_list[k], params.damping, params.speed_limit, params.n_vertices);
    }
}

// gather_coupled's work for this thread: its vertex's lane share, then the vertex's force
// (lane 0). Call in uniform control flow: it has a barrier.
fn coupled_vertex(wid: vec3<u32>, nwg: vec3<u32>, local: u32) {
    let i = workgroup_index(wid, nwg) * ITEMS_PER_WORKGROUP + local % ITEMS_PER_WORKGROUP;
    let lane = local / ITEMS_PER_WORKGROUP;
    let live = i < params.n_vertices;
    var mine = vec3<f32>(0.0);
    if live {
        mine = sum_corners(i, lane);
        if PARTICLES && (node_flags[i] & NODE_COUPLED) != 0u {
            let first = particle_slot_offsets[i];
            let short = coupled_valid[0] != 0u;
            var last = particle_slot_offsets[i + 1u];
            if short {
                last = first + coupled_count[i];
            }
            // Over the short list a lane takes every LANES-th slot that passes the filter, as
            // the twin does; over every slot (before the first activation, when no slot
            // passes) every LANES-th slot.
            for (var k = first + lane; k < last; k += LANES) {
                var slot = particle_slots[k];
                if short {
                    slot = coupled_slots[k];
                }
                let p = slot / 4u;
                let mode = particle_mode[p];
                if (mode & MODE_IN_F) != 0u && (mode & MODE_DYNAMIC) == 0u {
                    let fp = vec3<f32>(particle_force_sum[3u * p], particle_force_sum[3u * p + 1u], particle_force_sum[3u * p + 2u]);
                    mine += fp * particle_weights[slot];
                }
            }
        }
    }
    let sum = add_lanes(local, mine);
    if live && lane == 0u {
        store(i, with_contact(i, body_force(i) + sum));
    }
}

@compute @workgroup_size(256)
fn gather_exact(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>, @builtin(local_invocation_index) local: u32) {
    let i = workgroup_index(wid, nwg) * ITEMS_PER_WORKGROUP + local % ITEMS_PER_WORKGROUP;
    let lane = local / ITEMS_PER_WORKGROUP;
    let live = i < params.n_vertices;
    var mine = vec3<f32>(0.0);
    if live {
        mine = sum_corners(i, lane);
        for (var k = particle_slot_offsets[i] + lane; k < particle_slot_offsets[i + 1u]; k += LANES) {
            let slot = particle_slots[k];
            let p = slot / 4u;
            if (particle_mode[p] & MODE_IN_F) != 0u {
                let fp = vec3<f32>(exact_host_force[3u * p], exact_host_force[3u * p + 1u], exact_host_force[3u * p + 2u]);
                let ft = vec3<f32>(exact_tangent[3u * slot], exact_tangent[3u * slot + 1u], exact_tangent[3u * slot + 2u]);
                mine += fp * particle_weights[slot] + ft;
            }
        }
    }
    let sum = add_lanes(local, mine);
    if live && lane == 0u {
        store(i, with_contact(i, body_force(i) + sum));
    }
}
