// Average nodal Jacobian, stage 1 (Bonet & Burton 1998; NiftySim T4ANP): per tet, the
// volume change v_e - V_e = V_e (J_e - 1), with J - 1 from H = Du Dm^-1 without the
// cancellation of det F - 1. Next: nodal_pressure.wgsl. CPU twin: src/cpu/tet_volume_change.rs.
#import params
#import index
#import hyperelastic

@group(0) @binding(0) var<uniform> params: StepParams;
@group(0) @binding(1) var<storage, read> displacements: array<f32>;
@group(0) @binding(2) var<storage, read> tets: array<vec4<u32>>;
@group(0) @binding(3) var<storage, read> dm_inv: array<f32>;
@group(0) @binding(4) var<storage, read> rest_volume: array<f32>;
@group(0) @binding(5) var<storage, read_write> tet_delta_volume: array<f32>;

const WORKGROUP: u32 = 64u;

fn displacement(i: u32) -> vec3<f32> {
    return vec3<f32>(displacements[3u * i], displacements[3u * i + 1u], displacements[3u * i + 2u]);
}

@compute @workgroup_size(64)
fn tet_volume_change(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let e = linear_index(gid, nwg, WORKGROUP);
    if e >= params.n_tets {
        return;
    }
    let t = tets[e];
    let u0 = displacement(t.x);
    let du = mat3x3<f32>(displacement(t.y) - u0, displacement(t.z) - u0, displacement(t.w) - u0);
    let b = 9u * e;
    let dmi = mat3x3<f32>(
        vec3<f32>(dm_inv[b], dm_inv[b + 1u], dm_inv[b + 2u]),
        vec3<f32>(dm_inv[b + 3u], dm_inv[b + 4u], dm_inv[b + 5u]),
        vec3<f32>(dm_inv[b + 6u], dm_inv[b + 7u], dm_inv[b + 8u]),
    );
    tet_delta_volume[e] = rest_volume[e] * jacobian_minus_one(du * dmi);
}
