// Constitutive laws shared by the element (fem_forces) and particle (sph_stress) stages:
// the first Piola-Kirchhoff stress P and the energy density Psi from the displacement
// gradient H = F - I (formulas in src/material.rs, the CPU twin). MATERIAL values:
// 0 St. Venant-Kirchhoff, 1 stable Neo-Hookean, 2 corotational. Helpers (trace3, ddot,
// cofactor, identity3, extract_rotation) are in shared/tensor.wgsl.

#import tensor

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

// The stress differential dP = (d/ds) P(H + s dH) at s = 0 of material `model` (the
// exact coupling's tangent term; CPU twin: material::elastic_stress_differential).
//   StVK: dP = dH S + F dS, dS = lambda tr(dE) I + 2 mu dE, dE = (dH^T F + F^T dH)/2;
//   stable Neo-Hookean: dP = mu (dH - dcof) + lambda_hat (cof : dH) cof + lambda_hat (J - 1) dcof,
//     dcof the cofactor's differential (columns db x c + b x dc, ...);
//   corotational: dP = 2 mu (dH - dR) + lambda tr(R^T dH) R + lambda (tr S - 3) dR, dR = R [w]x,
//     (tr(S) I - S) w = axial(R^T dH - dH^T R), S = R^T F.
fn material_stress_differential(model: u32, h: mat3x3<f32>, dh: mat3x3<f32>, lambda: f32, mu: f32) -> mat3x3<f32> {
    let f = identity3() + h;
    if model == 1u {
        let lambda_hat = lambda + mu;
        let cof = cofactor(f);
        let dcof = mat3x3<f32>(
            cross(dh[1], f[2]) + cross(f[1], dh[2]),
            cross(dh[2], f[0]) + cross(f[2], dh[0]),
            cross(dh[0], f[1]) + cross(f[0], dh[1]),
        );
        let tr = trace3(h);
        let j_minus_1 = tr + 0.5 * (tr * tr - trace3(h * h)) + determinant(h);
        return (dh - dcof) * mu + cof * (lambda_hat * ddot(cof, dh)) + dcof * (lambda_hat * j_minus_1);
    } else if model == 2u {
        let r = extract_rotation(f);
        let s = transpose(r) * f;
        let k = transpose(r) * dh - transpose(dh) * r;
        let axial = vec3<f32>(k[1].z, k[2].x, k[0].y);
        let m = identity3() * trace3(s) - s;
        let w = transpose(cofactor(m)) * axial / determinant(m);
        let skew = mat3x3<f32>(vec3<f32>(0.0, w.z, -w.y), vec3<f32>(-w.z, 0.0, w.x), vec3<f32>(w.y, -w.x, 0.0));
        let dr = r * skew;
        return (dh - dr) * (2.0 * mu) + r * (lambda * trace3(transpose(r) * dh)) + dr * (lambda * (trace3(s) - 3.0));
    }
    let e = green_strain(h);
    let s = identity3() * (lambda * trace3(e)) + e * (2.0 * mu);
    let de = (transpose(dh) * f + transpose(f) * dh) * 0.5;
    let ds = identity3() * (lambda * trace3(de)) + de * (2.0 * mu);
    return dh * s + f * ds;
}
