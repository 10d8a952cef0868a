//! Materials: Lamé parameters, St. Venant–Kirchhoff stress with the paper's viscous stress.
//!
//! Paper eq. (1)–(4) use ε = FᵀF − I and σ = λ tr(ε) I + 2μ ε, with f = vol/2 Σ … in eq. (6).
//! With the Green strain E = ½(FᵀF − I) this is exactly St. Venant–Kirchhoff:
//!
//! * second Piola–Kirchhoff stress S = λ tr(E) I + 2μ E  (+ viscous φ tr(Ė) I + 2ψ Ė),
//! * first Piola–Kirchhoff stress P = F S,
//! * energy density Ψ = μ E:E + ½ λ tr(E)²,
//! * corner forces f₁..₃ = columns of −V P Dm⁻ᵀ, f₀ = −(f₁ + f₂ + f₃).

use glam::Mat3;

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
