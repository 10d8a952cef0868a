// Stage 1 for the volume/shape split laws (nearly incompressible tissue): per tet,
// H = Du Dm^-1, F = I + H, Fbar = phi(J)^(-1/3) F, and
//   P = phi^(-1/3) [Pbar - (phi'/(3 phi)) (Pbar:F) cof F] + p cof F  (+ viscous F S_v),
// with Pbar = dPsibar/dFbar of the shape law (MATERIAL 3: stvk_split, mu Ebar:Ebar;
// 4: stable_neohookean_split, mu/2 (Ibar_C - 3); 5: corotational_split, mu |Fbar - R|^2;
// 6: guccione, C/2 (e^Q - 1) along the tet's fibre), and the pressure p = U'(J) of the tet
// (NODAL_PRESSURE off) or the mean of its 4 vertex pressures from nodal_pressure.wgsl
// (on: average nodal Jacobian, Bonet & Burton 1998 / NiftySim T4ANP).
// Corner forces [f1 f2 f3] = -V P Dm^-T, f0 = -(f1 + f2 + f3); energy V (Psibar + U), U of
// the tet or the mean of its vertices' U(J_a). Formulas: src/material.rs.
// CPU twin: src/cpu/fem_forces_split.rs.
#import params
#import index
#import tensor
#import hyperelastic

@group(0) @binding(0) var<uniform> params: StepParams;
@group(0) @binding(1) var<uniform> material_constants: MaterialConstants;
@group(0) @binding(2) var<storage, read> displacements: array<f32>;
@group(0) @binding(3) var<storage, read> velocities: array<f32>;
@group(0) @binding(4) var<storage, read> tets: array<vec4<u32>>;
@group(0) @binding(5) var<storage, read> dm_inv: array<f32>;
@group(0) @binding(6) var<storage, read> rest_volume: array<f32>;
@group(0) @binding(7) var<storage, read> fibres: array<f32>;
@group(0) @binding(8) var<storage, read> vertex_pressure: array<f32>;
@group(0) @binding(9) var<storage, read> vertex_volumetric_energy: array<f32>;
@group(0) @binding(10) var<storage, read_write> corner_forces: array<f32>;
@group(0) @binding(11) var<storage, read_write> tet_energy: array<f32>;

// Pipeline constants: the split law (3-6), viscous terms, U(J) (0 quadratic, 1 log_squared,
// 2 simo_taylor), and whether the volume term comes from the vertex pressures.
override MATERIAL: u32 = 6u;
override VISCOUS: bool = false;
override VOLUMETRIC: u32 = 2u;
override NODAL_PRESSURE: bool = false;

const WORKGROUP: u32 = 64u;
const STVK_SPLIT: u32 = 3u;
const STABLE_NEOHOOKEAN_SPLIT: u32 = 4u;
const COROTATIONAL_SPLIT: u32 = 5u;
// Q above which Guccione's e^Q continues as its Taylor polynomial (src/material.rs).
const GUCCIONE_Q_MAX: f32 = 40.0;

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

// Unit fibre of tet e for a fibred Guccione law (b_f, b_t, b_fs not all equal), else zero.
fn tet_fibre(e: u32) -> vec3<f32> {
    let m = material_constants;
    if m.guccione_bf != m.guccione_bt || m.guccione_bt != m.guccione_bfs {
        let f = vec3<f32>(fibres[3u * e], fibres[3u * e + 1u], fibres[3u * e + 2u]);
        return f * (1.0 / sqrt(max(dot(f, f), 1e-30)));
    }
    return vec3<f32>(0.0);
}

struct StressEnergy {
    p: mat3x3<f32>,
    psi: f32,
}

// Guccione at Ebar with unit fibre f (zero: isotropic b_t Ebar:Ebar):
// Q = b_f E_ff^2 + b_t (E:E - 2|E f|^2 + E_ff^2) + 2 b_fs (|E f|^2 - E_ff^2),
// S = C e^Q [b_t E + (b_f + b_t - 2 b_fs) E_ff f(x)f + (b_fs - b_t)(E f (x) f + f (x) E f)].
fn guccione(e: mat3x3<f32>, f: vec3<f32>) -> StressEnergy {
    let m = material_constants;
    let ef = e * f;
    let eff = dot(f, ef);
    let efef = dot(ef, ef);
    let q = m.guccione_bf * eff * eff + m.guccione_bt * (ddot(e, e) - 2.0 * efef + eff * eff)
        + 2.0 * m.guccione_bfs * (efef - eff * eff);
    // e^Q, continued above Q_max as e^Qmax (1 + dq + dq^2/2) (finite for inverted tets).
    var g_minus_1 = expm1_f32(q);
    var g_prime = exp(q);
    if q > GUCCIONE_Q_MAX {
        let eq = exp(GUCCIONE_Q_MAX);
        let dq = q - GUCCIONE_Q_MAX;
        g_minus_1 = eq * (1.0 + dq + 0.5 * dq * dq) - 1.0;
        g_prime = eq * (1.0 + dq);
    }
    let s = (e * m.guccione_bt
        + outer(f, f) * ((m.guccione_bf + m.guccione_bt - 2.0 * m.guccione_bfs) * eff)
        + (outer(ef, f) + outer(f, ef)) * (m.guccione_bfs - m.guccione_bt))
        * (m.guccione_c * g_prime);
    return StressEnergy(s, 0.5 * m.guccione_c * g_minus_1);
}

// The shape law at Hbar = Fbar - I: (Pbar, Psibar).
fn isochoric_law(hb: mat3x3<f32>, fibre: vec3<f32>) -> StressEnergy {
    let mu = params.mu;
    let fb = identity3() + hb;
    if MATERIAL == STVK_SPLIT {
        let e = green_strain(hb);
        return StressEnergy(fb * (e * (2.0 * mu)), mu * ddot(e, e));
    } else if MATERIAL == STABLE_NEOHOOKEAN_SPLIT {
        let tr = trace3(hb);
        let p = (hb + transpose(hb) - identity3() * tr - cofactor(hb)) * mu;
        let psi = 0.5 * mu * (ddot(hb, hb) - tr * tr + trace3(hb * hb)) - mu * determinant(hb);
        return StressEnergy(p, psi);
    } else if MATERIAL == COROTATIONAL_SPLIT {
        let f_minus_r = fb - extract_rotation(fb);
        return StressEnergy(f_minus_r * (2.0 * mu), mu * ddot(f_minus_r, f_minus_r));
    }
    let g = guccione(green_strain(hb), fibre);
    return StressEnergy(fb * g.p, g.psi);
}

@compute @workgroup_size(64)
fn fem_forces_split(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
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

    // Split kinematics: d = J - 1, s = phi^(-1/3) - 1, r = phi'/phi, Hbar = (1 + s) H + s I.
    let d = jacobian_minus_one(h);
    let j = 1.0 + d;
    var s: f32;
    var r: f32;
    if j >= VOLUME_RATIO_FLOOR {
        s = inv_cbrt_minus_one_f32(d);
        r = 1.0 / j;
    } else {
        let a = VOLUME_RATIO_FLOOR;
        s = pow(a, -1.0 / 3.0) * exp(-(j - a) / (3.0 * a)) - 1.0;
        r = 1.0 / a;
    }
    let cof_f = cofactor(identity3() + h);
    let hb = h * (1.0 + s) + identity3() * s;

    let iso = isochoric_law(hb, tet_fibre(e));
    let pb_f = trace3(iso.p) + ddot(iso.p, h);
    var p = (iso.p - cof_f * (r / 3.0 * pb_f)) * (1.0 + s);

    var pressure: f32;
    var u_vol: f32;
    if NODAL_PRESSURE {
        pressure = 0.25 * (vertex_pressure[t.x] + vertex_pressure[t.y] + vertex_pressure[t.z] + vertex_pressure[t.w]);
        u_vol = 0.25 * (vertex_volumetric_energy[t.x] + vertex_volumetric_energy[t.y]
            + vertex_volumetric_energy[t.z] + vertex_volumetric_energy[t.w]);
    } else {
        let up = volumetric_energy_pressure(VOLUMETRIC, material_constants.bulk_modulus, d);
        u_vol = up.x;
        pressure = up.y;
    }
    p = p + cof_f * pressure;

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
    tet_energy[e] = volume * (iso.psi + u_vol);
}
