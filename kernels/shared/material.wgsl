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
