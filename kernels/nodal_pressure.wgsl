// Average nodal Jacobian, stage 2 (Bonet & Burton 1998; NiftySim T4ANP): per vertex a, over
// its tets e (CSR incidence, vertex -> tet*4 + corner, fixed order):
// J_a - 1 = sum_e (v_e - V_e) / sum_e V_e, vertex pressure p_a = U'(J_a) and volumetric
// energy density U(J_a). fem_forces_split.wgsl (NODAL_PRESSURE) then applies
// P_vol = mean_{a in e}(p_a) cof F_e, which is -d/dx of sum_a V_a U(J_a).
// CPU twin: src/cpu/nodal_pressure.rs.
#import params
#import index
#import hyperelastic

@group(0) @binding(0) var<uniform> params: StepParams;
@group(0) @binding(1) var<uniform> material_constants: MaterialConstants;
@group(0) @binding(2) var<storage, read> incidence_offsets: array<u32>;
@group(0) @binding(3) var<storage, read> incidence: array<u32>;
@group(0) @binding(4) var<storage, read> rest_volume: array<f32>;
@group(0) @binding(5) var<storage, read> tet_delta_volume: array<f32>;
@group(0) @binding(6) var<storage, read_write> vertex_pressure: array<f32>;
@group(0) @binding(7) var<storage, read_write> vertex_volumetric_energy: array<f32>;

// U(J): 0 quadratic, 1 log_squared, 2 simo_taylor (as fem_forces_split's VOLUMETRIC).
override VOLUMETRIC: u32 = 2u;

const WORKGROUP: u32 = 64u;

@compute @workgroup_size(64)
fn nodal_pressure(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let a = linear_index(gid, nwg, WORKGROUP);
    if a >= params.n_vertices {
        return;
    }
    var volume = 0.0;
    var delta = 0.0;
    for (var k = incidence_offsets[a]; k < incidence_offsets[a + 1u]; k++) {
        let e = incidence[k] / 4u;
        volume += rest_volume[e];
        delta += tet_delta_volume[e];
    }
    var up = vec2<f32>(0.0);
    if volume > 0.0 {
        up = volumetric_energy_pressure(VOLUMETRIC, material_constants.bulk_modulus, delta / volume);
    }
    vertex_pressure[a] = up.y;
    vertex_volumetric_energy[a] = up.x;
}
