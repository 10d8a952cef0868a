// Per vertex: external_forces = dead_load_forces + the follower-pressure corner forces around
// the vertex, summed over a CSR list (vertex -> face*3 + corner, ascending) in a fixed
// order. gather.wgsl then adds m g and the element forces. CPU twin:
// src/cpu/follower_pressure_gather.rs.
#import params
#import index

@group(0) @binding(0) var<uniform> params: StepParams;
@group(0) @binding(1) var<storage, read> follower_corner_forces: array<f32>;
@group(0) @binding(2) var<storage, read> follower_incidence_offsets: array<u32>;
@group(0) @binding(3) var<storage, read> follower_incidence: array<u32>;
@group(0) @binding(4) var<storage, read> dead_load_forces: array<f32>;
@group(0) @binding(5) var<storage, read_write> external_forces: array<f32>;

const WORKGROUP: u32 = 64u;

@compute @workgroup_size(64)
fn follower_pressure_gather(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_index(gid, nwg, WORKGROUP);
    if i >= params.n_vertices {
        return;
    }
    var f = vec3<f32>(dead_load_forces[3u * i], dead_load_forces[3u * i + 1u], dead_load_forces[3u * i + 2u]);
    for (var k = follower_incidence_offsets[i]; k < follower_incidence_offsets[i + 1u]; k++) {
        let c = follower_incidence[k];
        f += vec3<f32>(follower_corner_forces[3u * c], follower_corner_forces[3u * c + 1u], follower_corner_forces[3u * c + 2u]);
    }
    external_forces[3u * i] = f.x;
    external_forces[3u * i + 1u] = f.y;
    external_forces[3u * i + 2u] = f.z;
}
