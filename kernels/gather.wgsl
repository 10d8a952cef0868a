// Stage: per vertex, f = m g + f_ext + sum of incident corner forces over the CSR incidence list
// (vertex -> tet*4 + corner) + the tool's contact force on a surface vertex (CONTACT).
// No float atomics: deterministic. CPU twin: src/cpu/gather.rs.
#import params
#import index
#import tool

@group(0) @binding(0) var<uniform> params: StepParams;
@group(0) @binding(1) var<storage, read> corner_forces: array<f32>;
@group(0) @binding(2) var<storage, read> incidence_offsets: array<u32>;
@group(0) @binding(3) var<storage, read> incidence: array<u32>;
@group(0) @binding(4) var<storage, read> mass: array<f32>;
@group(0) @binding(5) var<storage, read> external_forces: array<f32>;
@group(0) @binding(6) var<storage, read_write> forces: array<f32>;
@group(0) @binding(7) var<storage, read> surface_index: array<u32>;
@group(0) @binding(8) var<storage, read> contact_forces: array<f32>;

// Pipeline constant: the scene has a tool (contact forces are added).
override CONTACT: bool = false;

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
    if CONTACT {
        let s = surface_index[i];
        if s != NOT_ON_SURFACE {
            f += vec3<f32>(contact_forces[3u * s], contact_forces[3u * s + 1u], contact_forces[3u * s + 2u]);
        }
    }
    forces[3u * i] = f.x;
    forces[3u * i + 1u] = f.y;
    forces[3u * i + 2u] = f.z;
}
