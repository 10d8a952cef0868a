// Stage 1: per tet, element forces (paper eq. 1-6) for the scene's material.
// The state is the displacement u = x - X (finer f32 resolution than positions):
// H = Du Dm^-1, F = I + H; P = first Piola-Kirchhoff stress of the material
// (MATERIAL 0: St. Venant-Kirchhoff, 1: stable Neo-Hookean, 2: corotational; see
// src/material.rs for the formulas), plus the viscous F S_v, S_v = phi tr(Edot) I + 2 psi Edot,
// Edot = (Fdot^T F + F^T Fdot)/2, Fdot = Dv Dm^-1 (eq. 3-4);
// corner forces [f1 f2 f3] = -V P Dm^-T, f0 = -(f1 + f2 + f3); energy V Psi.
// The volume/shape split laws (MATERIAL 3-6) run in fem_forces_split.wgsl instead.
// CPU twin: src/cpu/fem_forces.rs.
#import params
#import index
#import tensor

@group(0) @binding(0) var<uniform> params: StepParams;
@group(0) @binding(1) var<storage, read> displacements: array<f32>;
@group(0) @binding(2) var<storage, read> velocities: array<f32>;
@group(0) @binding(3) var<storage, read> tets: array<vec4<u32>>;
@group(0) @binding(4) var<storage, read> dm_inv: array<f32>;
@group(0) @binding(5) var<storage, read> rest_volume: array<f32>;
@group(0) @binding(6) var<storage, read_write> corner_forces: array<f32>;
@group(0) @binding(7) var<storage, read_write> tet_energy: array<f32>;

// Pipeline constants: the material model, and whether the viscous terms are compiled in.
override MATERIAL: u32 = 0u;
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

struct StressEnergy {
    p: mat3x3<f32>,
    psi: f32,
}

// St. Venant-Kirchhoff: E = (H + H^T + H^T H)/2, S = lambda tr(E) I + 2 mu E, P = F S.
fn stvk(h: mat3x3<f32>) -> StressEnergy {
    let e = (h + transpose(h) + transpose(h) * h) * 0.5;
    let tr = trace3(e);
    let s = identity3() * (params.lambda * tr) + e * (2.0 * params.mu);
    return StressEnergy((identity3() + h) * s, params.mu * ddot(e, e) + 0.5 * params.lambda * tr * tr);
}

// Stable Neo-Hookean with lambda_hat = lambda + mu, written in H to avoid cancellation.
fn stable_neohookean(h: mat3x3<f32>) -> StressEnergy {
    let lambda_hat = params.lambda + params.mu;
    let tr = trace3(h);
    let j_minus_1 = tr + 0.5 * (tr * tr - trace3(h * h)) + determinant(h);
    let f_minus_cof = h + transpose(h) - identity3() * tr - cofactor(h);
    let p = f_minus_cof * params.mu + cofactor(identity3() + h) * (lambda_hat * j_minus_1);
    let psi = 0.5 * params.mu * (2.0 * tr + ddot(h, h)) - params.mu * j_minus_1 + 0.5 * lambda_hat * j_minus_1 * j_minus_1;
    return StressEnergy(p, psi);
}

// Corotational: P = 2 mu (F - R) + lambda tr(R^T F - I) R.
fn corotational(h: mat3x3<f32>) -> StressEnergy {
    let f = identity3() + h;
    let r = extract_rotation(f);
    let f_minus_r = f - r;
    let tr = trace3(transpose(r) * f) - 3.0;
    let p = f_minus_r * (2.0 * params.mu) + r * (params.lambda * tr);
    return StressEnergy(p, params.mu * ddot(f_minus_r, f_minus_r) + 0.5 * params.lambda * tr * tr);
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
    let h = du * dmi;
    var se: StressEnergy;
    if MATERIAL == 1u {
        se = stable_neohookean(h);
    } else if MATERIAL == 2u {
        se = corotational(h);
    } else {
        se = stvk(h);
    }
    var p = se.p;
    if VISCOUS {
        let f = identity3() + h;
        let v0 = velocity(t.x);
        let dv = mat3x3<f32>(velocity(t.y) - v0, velocity(t.z) - v0, velocity(t.w) - v0);
        let f_dot = dv * dmi;
        let rate = (transpose(f_dot) * f + transpose(f) * f_dot) * 0.5;
        p = p + f * (identity3() * (params.phi * trace3(rate)) + rate * (2.0 * params.psi));
    }
    let g = p * transpose(dmi) * (-volume);
    store_corner(4u * e, -(g[0] + g[1] + g[2]));
    store_corner(4u * e + 1u, g[0]);
    store_corner(4u * e + 2u, g[1]);
    store_corner(4u * e + 3u, g[2]);
    tet_energy[e] = volume * se.psi;
}
