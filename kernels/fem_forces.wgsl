// Stage 1: per tet, St. Venant–Kirchhoff forces with the paper's viscous stress (eq. 1–6).
// The state is the displacement u = x - X (finer f32 resolution than positions):
// H = Du Dm^-1, F = I + H, E = (H + H^T + H^T H)/2 (= (F^T F - I)/2 without cancellation),
// Edot = (Fdot^T F + F^T Fdot)/2 with Fdot = Dv Dm^-1,
// S = lambda tr(E) I + 2 mu E + phi tr(Edot) I + 2 psi Edot, P = F S,
// corner forces [f1 f2 f3] = -V P Dm^-T, f0 = -(f1 + f2 + f3); energy V (mu E:E + lambda/2 tr(E)^2).
// CPU twin: src/cpu/fem_forces.rs.
#import params
#import index

@group(0) @binding(0) var<uniform> params: StepParams;
@group(0) @binding(1) var<storage, read> displacements: array<f32>;
@group(0) @binding(2) var<storage, read> velocities: array<f32>;
@group(0) @binding(3) var<storage, read> tets: array<vec4<u32>>;
@group(0) @binding(4) var<storage, read> dm_inv: array<f32>;
@group(0) @binding(5) var<storage, read> rest_volume: array<f32>;
@group(0) @binding(6) var<storage, read_write> corner_forces: array<f32>;
@group(0) @binding(7) var<storage, read_write> tet_energy: array<f32>;

// Pipeline constant: false compiles the kernel without the viscous terms.
override VISCOUS: bool = true;

const WORKGROUP: u32 = 64u;

fn displacement(i: u32) -> vec3<f32> {
    return vec3<f32>(displacements[3u * i], displacements[3u * i + 1u], displacements[3u * i + 2u]);
}

fn velocity(i: u32) -> vec3<f32> {
    return vec3<f32>(velocities[3u * i], velocities[3u * i + 1u], velocities[3u * i + 2u]);
}

fn store_corner(c: u32, f: vec3<f32>) {
    corner_forces[3u * c] = f.x;
    corner_forces[3u * c + 1u] = f.y;
    corner_forces[3u * c + 2u] = f.z;
}

fn trace3(m: mat3x3<f32>) -> f32 {
    return m[0].x + m[1].y + m[2].z;
}

@compute @workgroup_size(64)
fn fem_forces(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
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
    let volume = rest_volume[e];
    let identity = mat3x3<f32>(vec3<f32>(1.0, 0.0, 0.0), vec3<f32>(0.0, 1.0, 0.0), vec3<f32>(0.0, 0.0, 1.0));
    let h_grad = du * dmi;
    let f = identity + h_grad;
    let strain = (h_grad + transpose(h_grad) + transpose(h_grad) * h_grad) * 0.5;
    let tr = trace3(strain);
    var s = identity * (params.lambda * tr) + strain * (2.0 * params.mu);
    if VISCOUS {
        let v0 = velocity(t.x);
        let dv = mat3x3<f32>(velocity(t.y) - v0, velocity(t.z) - v0, velocity(t.w) - v0);
        let f_dot = dv * dmi;
        let rate = (transpose(f_dot) * f + transpose(f) * f_dot) * 0.5;
        s = s + identity * (params.phi * trace3(rate)) + rate * (2.0 * params.psi);
    }
    let h = (f * s) * transpose(dmi) * (-volume);
    store_corner(4u * e, -(h[0] + h[1] + h[2]));
    store_corner(4u * e + 1u, h[0]);
    store_corner(4u * e + 2u, h[1]);
    store_corner(4u * e + 3u, h[2]);
    let ee = dot(strain[0], strain[0]) + dot(strain[1], strain[1]) + dot(strain[2], strain[2]);
    tet_energy[e] = volume * (params.mu * ee + 0.5 * params.lambda * tr * tr);
}
