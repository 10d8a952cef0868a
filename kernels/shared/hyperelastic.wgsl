// The split laws' constants and the volume functions shared by fem_forces_split and
// nodal_pressure. Mirrors src/material.rs (`MaterialConstants`, `log1p_f32`,
// `x_minus_log1p_f32`, `expm1_f32`, `inv_cbrt_minus_one_f32`, `jacobian_minus_one`,
// `volumetric_energy_pressure`): same series, same branches, so the twins agree to f32
// round-off. A test checks the struct's layout against the Rust one.

struct MaterialConstants {
    bulk_modulus: f32,    // kappa, Pa
    guccione_c: f32,      // C, Pa
    guccione_bf: f32,
    guccione_bt: f32,
    guccione_bfs: f32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

// J_min: below it phi(J) and the logarithmic U(J) switch to their smooth extensions.
const VOLUME_RATIO_FLOOR: f32 = 0.1;
// |x| below which the series replace the library functions.
const SERIES_RADIUS: f32 = 0.1;

const VOLUMETRIC_QUADRATIC: u32 = 0u;
const VOLUMETRIC_LOG_SQUARED: u32 = 1u;
const VOLUMETRIC_SIMO_TAYLOR: u32 = 2u;

// ln(1 + d): Taylor series (12 terms, Horner) for |d| < 0.1.
fn log1p_f32(d: f32) -> f32 {
    if abs(d) < SERIES_RADIUS {
        var acc = 1.0 / 12.0;
        for (var k = 11u; k >= 1u; k--) {
            acc = 1.0 / f32(k) - d * acc;
        }
        return d * acc;
    }
    return log(1.0 + d);
}

// d - ln(1 + d) = d^2/2 - d^3/3 + ...
fn x_minus_log1p_f32(d: f32) -> f32 {
    if abs(d) < SERIES_RADIUS {
        var acc = 1.0 / 13.0;
        for (var k = 12u; k >= 2u; k--) {
            acc = 1.0 / f32(k) - d * acc;
        }
        return d * d * acc;
    }
    return d - log(1.0 + d);
}

// e^x - 1: series (10 terms) for |x| < 0.1.
fn expm1_f32(x: f32) -> f32 {
    if abs(x) < SERIES_RADIUS {
        var acc = 1.0;
        for (var k = 10u; k >= 2u; k--) {
            acc = 1.0 + x * acc / f32(k);
        }
        return x * acc;
    }
    return exp(x) - 1.0;
}

// (1 + d)^(-1/3) - 1: binomial series (10 terms) for |d| < 0.1.
fn inv_cbrt_minus_one_f32(d: f32) -> f32 {
    if abs(d) < SERIES_RADIUS {
        var term = 1.0;
        var sum = 0.0;
        for (var k = 1u; k <= 10u; k++) {
            term *= (-1.0 / 3.0 - f32(k - 1u)) / f32(k) * d;
            sum += term;
        }
        return sum;
    }
    return pow(1.0 + d, -1.0 / 3.0) - 1.0;
}

// J - 1 = det(I + H) - 1 = tr H + ((tr H)^2 - tr H^2)/2 + det H, without cancellation.
fn jacobian_minus_one(h: mat3x3<f32>) -> f32 {
    let tr = h[0].x + h[1].y + h[2].z;
    let h2 = h * h;
    return tr + 0.5 * (tr * tr - (h2[0].x + h2[1].y + h2[2].z)) + determinant(h);
}

// (U, U', U'') of the logarithmic laws at J = 1 + d > 0.
fn log_law(law: u32, kappa: f32, d: f32) -> vec3<f32> {
    let j = 1.0 + d;
    if law == VOLUMETRIC_LOG_SQUARED {
        let l = log1p_f32(d);
        return vec3<f32>(0.5 * kappa * l * l, kappa * l / j, kappa * (1.0 - l) / (j * j));
    }
    return vec3<f32>(
        0.25 * kappa * (d * d + 2.0 * x_minus_log1p_f32(d)),
        0.5 * kappa * d * (2.0 + d) / j,
        0.5 * kappa * (1.0 + 1.0 / (j * j)),
    );
}

// (U, p = U') of the volumetric law at J = 1 + d:
//   quadratic   U = kappa/2 (J-1)^2,          p = kappa (J-1)
//   log_squared U = kappa/2 (ln J)^2,         p = kappa ln J / J
//   simo_taylor U = kappa/4 (J^2 - 1 - 2 ln J), p = kappa/2 (J - 1/J)
// Below J_min the logarithmic laws continue as their 2nd-order Taylor polynomial at J_min.
fn volumetric_energy_pressure(law: u32, kappa: f32, d: f32) -> vec2<f32> {
    if law == VOLUMETRIC_QUADRATIC {
        return vec2<f32>(0.5 * kappa * d * d, kappa * d);
    }
    let j = 1.0 + d;
    if j >= VOLUME_RATIO_FLOOR {
        return log_law(law, kappa, d).xy;
    }
    let u0 = log_law(law, kappa, VOLUME_RATIO_FLOOR - 1.0);
    let delta = j - VOLUME_RATIO_FLOOR;
    return vec2<f32>(u0.x + u0.y * delta + 0.5 * u0.z * delta * delta, u0.y + u0.z * delta);
}
