// Stage 5: per vertex, f = m g + f_ext + sum of incident corner forces over the CSR incidence list
// (vertex -> tet*4 + corner). No float atomics: deterministic. CPU twin: src/cpu/gather.rs.
#import params
#import index

@group(0) @binding(0) var<uniform> params: StepParams;
@group(0) @binding(1) var<storage, read> corner_forces: array<f32>;
@group(0) @binding(2) var<storage, read> incidence_offsets: array<u32>;
@group(0) @binding(3) var<storage, read> incidence: array<u32>;
@group(0) @binding(4) var<storage, read> mass: array<f32>;
@group(0) @binding(5) var<storage, read> external_forces: array<f32>;
@group(0) @binding(6) var<storage, read_write> forces: array<f32>;

const WORKGROUP: u32 = 64u;

@compute @workgroup_size(64)
fn gather(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_index(gid, nwg, WORKGROUP);
    if i >= params.n_vertices {
        return;
    }
    var f = params.gravity * mass[i]
        + vec3<f32>(external_forces[3u * i], external_forces[3u * i + 1u], external_forces[3u * i + 2u]);
    for (var k = incidence_offsets[i]; k < incidence_offsets[i + 1u]; k++) {
        let c = incidence[k];
        f += vec3<f32>(corner_forces[3u * c], corner_forces[3u * c + 1u], corner_forces[3u * c + 2u]);
    }
    forces[3u * i] = f.x;
    forces[3u * i + 1u] = f.y;
    forces[3u * i + 2u] = f.z;
}
