// Stage: per vertex, f = m g + f_ext + sum of incident corner forces over the CSR incidence list
// (vertex -> tet*4 + corner). No float atomics: deterministic. CPU twin: src/cpu/gather.rs.
// `gather` is the plain FEM sum; `gather_coupled` (scenes with a tool or particles) adds the
// tool's contact force on a surface vertex (CONTACT) and the forces on the embedded particles
// the vertex hosts, w_i f_p, over the CSR vertex -> particle slots (PARTICLES): over the short
// list of its force-set embedded particles' slots that activate_relump wrote at
// coupled_slots[offset_i ..] (coupled_count[i] of them, in CSR order) while coupled_valid[0] is
// set, else (before the first activation) over every slot. A checkpoint saves the lists with
// the modes they were built from.
#import params
#import index
#import tool
#import particles

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

// Pipeline constants of gather_coupled: the scene has a tool / particles.
override CONTACT: bool = false;
override PARTICLES: bool = false;

const WORKGROUP: u32 = 64u;

fn sum_corners(i: u32) -> vec3<f32> {
    var f = params.gravity * mass[i]
        + vec3<f32>(external_forces[3u * i], external_forces[3u * i + 1u], external_forces[3u * i + 2u]);
    for (var k = incidence_offsets[i]; k < incidence_offsets[i + 1u]; k++) {
        let c = incidence[k];
        f += vec3<f32>(corner_forces[3u * c], corner_forces[3u * c + 1u], corner_forces[3u * c + 2u]);
    }
    return f;
}

fn store(i: u32, f: vec3<f32>) {
    forces[3u * i] = f.x;
    forces[3u * i + 1u] = f.y;
    forces[3u * i + 2u] = f.z;
}

@compute @workgroup_size(64)
fn gather(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_index(gid, nwg, WORKGROUP);
    if i >= params.n_vertices {
        return;
    }
    store(i, sum_corners(i));
}

@compute @workgroup_size(64)
fn gather_coupled(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_index(gid, nwg, WORKGROUP);
    if i >= params.n_vertices {
        return;
    }
    var f = sum_corners(i);
    if CONTACT {
        let s = surface_index[i];
        if s != NOT_ON_SURFACE {
            f += vec3<f32>(contact_forces[3u * s], contact_forces[3u * s + 1u], contact_forces[3u * s + 2u]);
        }
    }
    if PARTICLES && (node_flags[i] & NODE_COUPLED) != 0u {
        let first = particle_slot_offsets[i];
        let short = coupled_valid[0] != 0u;
        var last = particle_slot_offsets[i + 1u];
        if short {
            last = first + coupled_count[i];
        }
        for (var k = first; k < last; k++) {
            var slot = particle_slots[k];
            if short {
                slot = coupled_slots[k];
            }
            let p = slot / 4u;
            let mode = particle_mode[p];
            if (mode & MODE_IN_F) != 0u && (mode & MODE_DYNAMIC) == 0u {
                let fp = vec3<f32>(particle_force_sum[3u * p], particle_force_sum[3u * p + 1u], particle_force_sum[3u * p + 2u]);
                f += fp * particle_weights[slot];
            }
        }
    }
    store(i, f);
}
