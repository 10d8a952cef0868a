// Constitutive laws shared by the element (fem_forces) and particle (sph_stress) stages:
// the first Piola-Kirchhoff stress P and the energy density Psi from the displacement
// gradient H = F - I (formulas in src/material.rs, the CPU twin). MATERIAL values:
// 0 St. Venant-Kirchhoff, 1 stable Neo-Hookean, 2 corotational.

const ROTATION_ITERATIONS: u32 = 24u;

fn trace3(m: mat3x3<f32>) -> f32 {
    return m[0].x + m[1].y + m[2].z;
}

fn ddot(a: mat3x3<f32>, b: mat3x3<f32>) -> f32 {
    return dot(a[0], b[0]) + dot(a[1], b[1]) + dot(a[2], b[2]);
}

fn cofactor(a: mat3x3<f32>) -> mat3x3<f32> {
    return mat3x3<f32>(cross(a[1], a[2]), cross(a[2], a[0]), cross(a[0], a[1]));
}

fn identity3() -> mat3x3<f32> {
    return mat3x3<f32>(vec3<f32>(1.0, 0.0, 0.0), vec3<f32>(0.0, 1.0, 0.0), vec3<f32>(0.0, 0.0, 1.0));
}

struct StressEnergy {
    p: mat3x3<f32>,
    psi: f32,
}

// St. Venant-Kirchhoff: E = (H + H^T + H^T H)/2, S = lambda tr(E) I + 2 mu E, P = F S.
fn stvk(h: mat3x3<f32>, lambda: f32, mu: f32) -> StressEnergy {
    let e = (h + transpose(h) + transpose(h) * h) * 0.5;
    let tr = trace3(e);
    let s = identity3() * (lambda * tr) + e * (2.0 * mu);
    return StressEnergy((identity3() + h) * s, mu * ddot(e, e) + 0.5 * lambda * tr * tr);
}

// Stable Neo-Hookean with lambda_hat = lambda + mu, written in H to avoid cancellation.
fn stable_neohookean(h: mat3x3<f32>, lambda: f32, mu: f32) -> StressEnergy {
    let lambda_hat = lambda + mu;
    let tr = trace3(h);
    let j_minus_1 = tr + 0.5 * (tr * tr - trace3(h * h)) + determinant(h);
    let f_minus_cof = h + transpose(h) - identity3() * tr - cofactor(h);
    let p = f_minus_cof * mu + cofactor(identity3() + h) * (lambda_hat * j_minus_1);
    let psi = 0.5 * mu * (2.0 * tr + ddot(h, h)) - mu * j_minus_1 + 0.5 * lambda_hat * j_minus_1 * j_minus_1;
    return StressEnergy(p, psi);
}

fn quat_to_mat(q: vec4<f32>) -> mat3x3<f32> {
    let x = q.x;
    let y = q.y;
    let z = q.z;
    let w = q.w;
    return mat3x3<f32>(
        vec3<f32>(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)),
        vec3<f32>(2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x)),
        vec3<f32>(2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)),
    );
}

fn quat_mul(a: vec4<f32>, b: vec4<f32>) -> vec4<f32> {
    return vec4<f32>(a.w * b.xyz + b.w * a.xyz + cross(a.xyz, b.xyz), a.w * b.w - dot(a.xyz, b.xyz));
}

// The rotation nearest F (Mueller et al. 2016), from the identity.
fn extract_rotation(f: mat3x3<f32>) -> mat3x3<f32> {
    var q = vec4<f32>(0.0, 0.0, 0.0, 1.0);
    for (var k = 0u; k < ROTATION_ITERATIONS; k++) {
        let r = quat_to_mat(q);
        let num = cross(r[0], f[0]) + cross(r[1], f[1]) + cross(r[2], f[2]);
        let den = abs(dot(r[0], f[0]) + dot(r[1], f[1]) + dot(r[2], f[2])) + 1e-9;
        let omega = num / den;
        let w = length(omega);
        if w < 1e-9 {
            break;
        }
        let axis = omega / w;
        let dq = vec4<f32>(axis * sin(0.5 * w), cos(0.5 * w));
        q = normalize(quat_mul(dq, q));
    }
    return quat_to_mat(q);
}

// Corotational: P = 2 mu (F - R) + lambda tr(R^T F - I) R.
fn corotational(h: mat3x3<f32>, lambda: f32, mu: f32) -> StressEnergy {
    let f = identity3() + h;
    let r = extract_rotation(f);
    let f_minus_r = f - r;
    let tr = trace3(transpose(r) * f) - 3.0;
    let p = f_minus_r * (2.0 * mu) + r * (lambda * tr);
    return StressEnergy(p, mu * ddot(f_minus_r, f_minus_r) + 0.5 * lambda * tr * tr);
}

// P and Psi of material `model` at displacement gradient h.
fn material_stress_energy(model: u32, h: mat3x3<f32>, lambda: f32, mu: f32) -> StressEnergy {
    if model == 1u {
        return stable_neohookean(h, lambda, mu);
    } else if model == 2u {
        return corotational(h, lambda, mu);
    }
    return stvk(h, lambda, mu);
}
