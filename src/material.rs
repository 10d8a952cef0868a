//! Materials: Lamé parameters, and the first Piola–Kirchhoff stress and energy density of
//! each constitutive model, all with the paper's viscous stress added (eq. 3–4).
//!
//! ## St. Venant–Kirchhoff (`stvk`, the paper's model)
//!
//! Paper eq. (1)–(4) use ε = FᵀF − I and σ = λ tr(ε) I + 2μ ε, with f = vol/2 Σ … in eq. (6).
//! With the Green strain E = ½(FᵀF − I) this is exactly St. Venant–Kirchhoff:
//!
//! * second Piola–Kirchhoff stress S = λ tr(E) I + 2μ E  (+ viscous φ tr(Ė) I + 2ψ Ė),
//! * first Piola–Kirchhoff stress P = F S,
//! * energy density Ψ = μ E:E + ½ λ tr(E)²,
//! * corner forces f₁..₃ = columns of −V P Dm⁻ᵀ, f₀ = −(f₁ + f₂ + f₃).
//!
//! It loses resistance under strong compression and has no restoring force for inverted
//! elements. ## Stable Neo-Hookean (`stable_neohookean`, Smith, de Goes & Kim 2018)
//!
//! Ψ = μ/2 (I_C − 3) − μ (J − 1) + λ̂/2 (J − 1)², λ̂ = λ + μ (so that it linearises to the
//! given λ, μ), I_C = tr FᵀF, J = det F;
//! P = μ (F − cof F) + λ̂ (J − 1) cof F, cof F = ∂J/∂F. Defined and restoring for J ≤ 0.
//! Computed from H = F − I without cancellation: I_C − 3 = 2 tr H + |H|², J − 1 = tr H +
//! ½((tr H)² − tr H²) + det H, F − cof F = H + Hᵀ − (tr H) I − cof H.
//!
//! ## Corotational linear elasticity (`corotational`)
//!
//! F = R S (R the rotation nearest F); Ψ = μ |F − R|² + λ/2 tr(RᵀF − I)²,
//! P = 2μ (F − R) + λ tr(RᵀF − I) R. R is found by the quaternion iteration of Müller et al.
//! 2016 ("A robust method to extract the rotational part of deformations"), which always
//! returns a proper rotation, also for inverted elements.
//!
//! Viscous stress, all models: P_v = F S_v, S_v = φ tr(Ė) I + 2ψ Ė.

use glam::{Mat3, Quat, Vec3};

/// Constitutive model; the value is the `MATERIAL` pipeline constant of `fem_forces.wgsl`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MaterialModel {
    /// St. Venant–Kirchhoff (paper eq. 1–6).
    #[default]
    Stvk = 0,
    /// Stable Neo-Hookean (Smith, de Goes, Kim 2018).
    StableNeohookean = 1,
    /// Corotational linear elasticity.
    Corotational = 2,
}

impl MaterialModel {
    /// All models.
    pub const ALL: [MaterialModel; 3] = [
        MaterialModel::Stvk,
        MaterialModel::StableNeohookean,
        MaterialModel::Corotational,
    ];

    /// The scene-file name.
    pub fn name(self) -> &'static str {
        match self {
            MaterialModel::Stvk => "stvk",
            MaterialModel::StableNeohookean => "stable_neohookean",
            MaterialModel::Corotational => "corotational",
        }
    }

    /// Parse a scene-file name.
    pub fn from_name(name: &str) -> Option<MaterialModel> {
        MaterialModel::ALL.into_iter().find(|m| m.name() == name)
    }
}

/// Lamé parameters and viscosity of one material, SI units (Pa, Pa·s, kg/m³).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct MaterialParams {
    /// First Lamé parameter λ, Pa.
    pub lambda: f64,
    /// Shear modulus μ, Pa.
    pub mu: f64,
    /// Bulk viscosity φ of eq. (4), Pa·s.
    pub phi: f64,
    /// Shear viscosity ψ of eq. (4), Pa·s.
    pub psi: f64,
    /// Rest density ρ, kg/m³.
    pub density: f64,
    /// Constitutive model.
    pub model: MaterialModel,
}

impl MaterialParams {
    /// Lamé parameters from Young's modulus E and Poisson ratio ν:
    /// λ = Eν / ((1+ν)(1−2ν)), μ = E / (2(1+ν)).
    pub fn lame_from_young(youngs_modulus: f64, poisson_ratio: f64) -> (f64, f64) {
        let (e, nu) = (youngs_modulus, poisson_ratio);
        (
            e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)),
            e / (2.0 * (1.0 + nu)),
        )
    }

    /// An inviscid St. Venant–Kirchhoff material from Young's modulus E (Pa), Poisson ratio ν
    /// and density ρ (kg/m³).
    pub fn elastic(youngs_modulus: f64, poisson_ratio: f64, density: f64) -> MaterialParams {
        let (lambda, mu) = MaterialParams::lame_from_young(youngs_modulus, poisson_ratio);
        MaterialParams {
            lambda,
            mu,
            phi: 0.0,
            psi: 0.0,
            density,
            model: MaterialModel::Stvk,
        }
    }

    /// Dilatational (P-) wave speed c_p = sqrt((λ + 2μ)/ρ), m/s.
    pub fn p_wave_speed(&self) -> f64 {
        ((self.lambda + 2.0 * self.mu) / self.density).sqrt()
    }

    /// True when the viscous stress is non-zero (selects the viscous kernel variant).
    pub fn is_viscous(&self) -> bool {
        self.phi != 0.0 || self.psi != 0.0
    }
}

/// Green strain E = ½(FᵀF − I).
pub fn green_strain(f: Mat3) -> Mat3 {
    (f.transpose() * f - Mat3::IDENTITY) * 0.5
}

/// Green strain from the displacement gradient H = F − I: E = ½(H + Hᵀ + HᵀH), the same
/// tensor as [`green_strain`] without the cancellation in FᵀF − I (better in f32).
pub fn green_strain_from_gradient(h: Mat3) -> Mat3 {
    (h + h.transpose() + h.transpose() * h) * 0.5
}

/// Green strain rate Ė = ½(ḞᵀF + FᵀḞ).
pub fn green_strain_rate(f: Mat3, f_dot: Mat3) -> Mat3 {
    (f_dot.transpose() * f + f.transpose() * f_dot) * 0.5
}

/// St. Venant–Kirchhoff second Piola–Kirchhoff stress with viscosity:
/// S = λ tr(E) I + 2μ E + φ tr(Ė) I + 2ψ Ė.
pub fn stvk_second_piola(e: Mat3, e_dot: Mat3, lambda: f32, mu: f32, phi: f32, psi: f32) -> Mat3 {
    let tr = e.x_axis.x + e.y_axis.y + e.z_axis.z;
    let tr_dot = e_dot.x_axis.x + e_dot.y_axis.y + e_dot.z_axis.z;
    Mat3::from_diagonal(glam::Vec3::splat(lambda * tr + phi * tr_dot))
        + e * (2.0 * mu)
        + e_dot * (2.0 * psi)
}

/// St. Venant–Kirchhoff energy density Ψ = μ E:E + ½ λ tr(E)², J/m³.
pub fn stvk_energy_density(e: Mat3, lambda: f32, mu: f32) -> f32 {
    let tr = e.x_axis.x + e.y_axis.y + e.z_axis.z;
    let ee = e.x_axis.dot(e.x_axis) + e.y_axis.dot(e.y_axis) + e.z_axis.dot(e.z_axis);
    mu * ee + 0.5 * lambda * tr * tr
}

/// Trace of a 3×3 matrix.
#[inline]
pub fn trace(m: Mat3) -> f32 {
    m.x_axis.x + m.y_axis.y + m.z_axis.z
}

/// Frobenius product A:B.
#[inline]
pub fn ddot(a: Mat3, b: Mat3) -> f32 {
    a.x_axis.dot(b.x_axis) + a.y_axis.dot(b.y_axis) + a.z_axis.dot(b.z_axis)
}

/// Cofactor matrix (columns c₀ = a₁×a₂, c₁ = a₂×a₀, c₂ = a₀×a₁) = det(A) A⁻ᵀ = ∂det/∂A.
#[inline]
pub fn cofactor(a: Mat3) -> Mat3 {
    Mat3::from_cols(
        a.y_axis.cross(a.z_axis),
        a.z_axis.cross(a.x_axis),
        a.x_axis.cross(a.y_axis),
    )
}

/// Stable Neo-Hookean P and Ψ from the displacement gradient H (see module docs).
pub fn snh_stress_energy(h: Mat3, lambda: f32, mu: f32) -> (Mat3, f32) {
    let lambda_hat = lambda + mu;
    let f = Mat3::IDENTITY + h;
    let tr = trace(h);
    let j_minus_1 = tr + 0.5 * (tr * tr - trace(h * h)) + h.determinant();
    let f_minus_cof = h + h.transpose() - Mat3::from_diagonal(Vec3::splat(tr)) - cofactor(h);
    let p = f_minus_cof * mu + cofactor(f) * (lambda_hat * j_minus_1);
    let ic_minus_3 = 2.0 * tr + ddot(h, h);
    let psi = 0.5 * mu * ic_minus_3 - mu * j_minus_1 + 0.5 * lambda_hat * j_minus_1 * j_minus_1;
    (p, psi)
}

/// Iterations of the rotation extraction, from the identity.
pub const ROTATION_ITERATIONS: u32 = 24;

/// The rotation R nearest F (Müller et al. 2016): q ← exp(ω) q with
/// ω = Σᵢ rᵢ × fᵢ / (|Σᵢ rᵢ·fᵢ| + 1e-9), rᵢ, fᵢ the columns of R(q) and F.
pub fn extract_rotation(f: Mat3) -> Mat3 {
    let mut q = Quat::IDENTITY;
    for _ in 0..ROTATION_ITERATIONS {
        let r = Mat3::from_quat(q);
        let num = r.x_axis.cross(f.x_axis) + r.y_axis.cross(f.y_axis) + r.z_axis.cross(f.z_axis);
        let den =
            (r.x_axis.dot(f.x_axis) + r.y_axis.dot(f.y_axis) + r.z_axis.dot(f.z_axis)).abs() + 1e-9;
        let omega = num / den;
        let w = omega.length();
        if w < 1e-9 {
            break;
        }
        q = (Quat::from_axis_angle(omega / w, w) * q).normalize();
    }
    Mat3::from_quat(q)
}

/// Corotational P and Ψ from the displacement gradient H (see module docs).
pub fn corotational_stress_energy(h: Mat3, lambda: f32, mu: f32) -> (Mat3, f32) {
    let f = Mat3::IDENTITY + h;
    let r = extract_rotation(f);
    let f_minus_r = f - r;
    let tr = trace(r.transpose() * f) - 3.0;
    let p = f_minus_r * (2.0 * mu) + r * (lambda * tr);
    (p, mu * ddot(f_minus_r, f_minus_r) + 0.5 * lambda * tr * tr)
}

/// First Piola–Kirchhoff stress and energy density of `model` (elastic part only).
pub fn elastic_stress_energy(model: MaterialModel, h: Mat3, lambda: f32, mu: f32) -> (Mat3, f32) {
    match model {
        MaterialModel::Stvk => {
            let e = green_strain_from_gradient(h);
            let s = stvk_second_piola(e, Mat3::ZERO, lambda, mu, 0.0, 0.0);
            ((Mat3::IDENTITY + h) * s, stvk_energy_density(e, lambda, mu))
        }
        MaterialModel::StableNeohookean => snh_stress_energy(h, lambda, mu),
        MaterialModel::Corotational => corotational_stress_energy(h, lambda, mu),
    }
}
