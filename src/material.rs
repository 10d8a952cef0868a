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
//!
//! ## Volume/shape split (`*_split`, `guccione`; nearly incompressible tissue)
//!
//! Ψ(F) = Ψ̄(F̄) + U(J), F̄ = J^(−1/3) F (det F̄ = 1), with the shape part Ψ̄ carrying the
//! shear modulus μ (or Guccione's C) and the volume part U the bulk modulus κ
//! (`bulk_modulus`; from ν: κ = 2μ(1 + ν) / (3(1 − 2ν)), [`HyperelasticParams::bulk_modulus_from_poisson`]).
//! Flory 1961; Simo, Taylor & Pister 1985; Holzapfel, *Nonlinear Solid Mechanics* §6.4.
//! λ is not used: the split laws linearise to P = 2μ dev ε + κ tr(ε) I.
//!
//! * `stvk_split`: Ψ̄ = μ Ē:Ē, Ē = ½(F̄ᵀF̄ − I); ∂Ψ̄/∂F̄ = P̄ = F̄ (2μ Ē).
//! * `stable_neohookean_split`: Ψ̄ = μ/2 (I_C(F̄) − 3) − μ (det F̄ − 1) = μ/2 (Ī_C − 3) (the
//!   shape part of stable Neo-Hookean; the second term is zero on det F̄ = 1 and makes P̄ small
//!   at rest); P̄ = μ (F̄ − cof F̄).
//! * `corotational_split`: Ψ̄ = μ |F̄ − R|², R the rotation of F (= of F̄); P̄ = 2μ (F̄ − R).
//! * `guccione` (Guccione, Costa & McCulloch 1995, *J. Biomech.* 28:1167): with the fibre f
//!   of the tet, sheet s and sheet-normal n, Ē in that frame, Ψ̄ = C/2 (e^Q − 1) with
//!   Q = b_f Ē_ff² + b_t (Ē_ss² + Ē_nn² + Ē_sn² + Ē_ns²) + b_fs (Ē_fs² + Ē_sf² + Ē_fn² + Ē_nf²).
//!   The law is transversely isotropic about f, so Q needs no sheet direction: with
//!   e_f = Ē f, Ē_ff = f·Ē f,
//!   Q = b_f Ē_ff² + b_t (Ē:Ē − 2|e_f|² + Ē_ff²) + 2 b_fs (|e_f|² − Ē_ff²) ([`guccione_q`];
//!   [`guccione_q_in_frame`] evaluates the component form in [`fibre_frame`]'s frame, and a
//!   test checks both agree). Second Piola–Kirchhoff S̄ = ∂Ψ̄/∂Ē =
//!   C e^Q [b_t Ē + (b_f + b_t − 2b_fs) Ē_ff f⊗f + (b_fs − b_t)(e_f⊗f + f⊗e_f)], P̄ = F̄ S̄.
//!   Isotropic case b_f = b_t = b_fs = b: Q = b Ē:Ē, no fibre needed. Small strain:
//!   μ_eff ≤ C max(b)/2 ([`GuccioneParams::effective_shear_modulus`]). Above Q = 40 e^Q
//!   continues as its Taylor polynomial ([`guccione_exp`]) so that inverted tets stay finite.
//!
//! Chain rule through F̄ (any Ψ̄): P_iso = φ^(−1/3) [P̄ − (φ′/(3φ)) (P̄:F) cof F], written with
//! the cofactor cof F = ∂J/∂F so that nothing divides by J. φ(J) = J for
//! J ≥ J_min = [`VOLUME_RATIO_FLOOR`]; below it φ = J_min e^((J − J_min)/J_min) (C¹, positive),
//! so the laws stay defined, and P = ∂Ψ/∂F exact, for strongly compressed and inverted tets.
//! In f32, F̄ − I = (1 + s) H + s I with s = φ^(−1/3) − 1 from J − 1 by a series
//! ([`inv_cbrt_minus_one_f32`]), and every P̄ above is first order in F̄ − I, so neither the
//! projection nor the energy cancels catastrophically near rest.
//!
//! Volume part U(J) ([`VolumetricLaw`], [`volumetric_energy_pressure`]), p = U′(J), from
//! d = J − 1 computed from H (no cancellation):
//!
//! * `quadratic`: U = κ/2 (J − 1)², p = κ (J − 1) (NiftySim, Joldes et al. 2009). Bounded
//!   (κ/2) at J = 0 and p(0) = −κ: no barrier against inversion.
//! * `log_squared`: U = κ/2 (ln J)², p = κ ln J / J (Simo & Taylor 1982). U → ∞ as J → 0, but
//!   p peaks at J = e and U is not convex for J > e (softens in strong dilatation).
//! * `simo_taylor`: U = κ/4 (J² − 1 − 2 ln J), p = κ/2 (J − 1/J) (Simo & Taylor 1991; Ogden
//!   β = −2). Convex for all J > 0, U → ∞ as J → 0 and as J → ∞. The default.
//!
//! All three have U(1) = U′(1) = 0, U″(1) = κ. Below J_min the two logarithmic laws continue as
//! their second-order Taylor polynomial at J_min (C², defined for J ≤ 0).
//!
//! Volume term per element (`VolumeTerm::Element`): P_vol = U′(J_e) cof F_e, energy V_e U(J_e).
//! Linear tets lock in volume as κ/μ grows; `VolumeTerm::NodalAverage` is the locking-free
//! average nodal Jacobian of Bonet & Burton 1998 (the volume term of NiftySim's T4ANP element,
//! Joldes, Wittek & Miller 2009): J_a = Σ_e v_e / Σ_e V_e over the tets e around vertex a,
//! p_a = U′(J_a), and per tet P_vol = p̄_e cof F_e with p̄_e the mean of its 4 vertex
//! pressures. This is exactly −∂/∂x of E_vol = Σ_a V_a U(J_a), V_a = Σ_e V_e / 4
//! (kernels `tet_volume_change`, `nodal_pressure`, `fem_forces_split`; see
//! `src/cpu/nodal_pressure.rs`).

use bytemuck::{Pod, Zeroable};
use glam::{Mat3, Quat, Vec3};

/// Largest Guccione exponent b_f, b_t, b_fs accepted: with Q = b E² the law's e^Q leaves
/// single precision (e^88) at a strain of 0.3 for b = 1000 (published values: 1 to 50).
pub const MAX_GUCCIONE_EXPONENT: f64 = 1000.0;

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
    /// St. Venant–Kirchhoff shape part μ Ē:Ē at F̄ = J^(−1/3) F, plus U(J) (module docs).
    StvkSplit = 3,
    /// The shape part of stable Neo-Hookean at F̄, μ/2 (Ī_C − 3), plus U(J).
    StableNeohookeanSplit = 4,
    /// Corotational shape part μ |F̄ − R|², plus U(J).
    CorotationalSplit = 5,
    /// Guccione, Costa & McCulloch 1995, transversely isotropic along the tet's fibre:
    /// C/2 (e^Q − 1) at Ē, plus U(J).
    Guccione = 6,
}

impl MaterialModel {
    /// The models parametrised by (λ, μ) alone, run by `fem_forces.wgsl`.
    pub const ALL: [MaterialModel; 3] = [
        MaterialModel::Stvk,
        MaterialModel::StableNeohookean,
        MaterialModel::Corotational,
    ];

    /// The volume/shape split models, run by `fem_forces_split.wgsl`; they also need a
    /// [`HyperelasticParams`] (bulk modulus, volumetric law, Guccione constants).
    pub const SPLIT: [MaterialModel; 4] = [
        MaterialModel::StvkSplit,
        MaterialModel::StableNeohookeanSplit,
        MaterialModel::CorotationalSplit,
        MaterialModel::Guccione,
    ];

    /// Every model: [`MaterialModel::ALL`] then [`MaterialModel::SPLIT`].
    pub const EVERY: [MaterialModel; 7] = [
        MaterialModel::Stvk,
        MaterialModel::StableNeohookean,
        MaterialModel::Corotational,
        MaterialModel::StvkSplit,
        MaterialModel::StableNeohookeanSplit,
        MaterialModel::CorotationalSplit,
        MaterialModel::Guccione,
    ];

    /// The scene-file name.
    pub fn name(self) -> &'static str {
        match self {
            MaterialModel::Stvk => "stvk",
            MaterialModel::StableNeohookean => "stable_neohookean",
            MaterialModel::Corotational => "corotational",
            MaterialModel::StvkSplit => "stvk_split",
            MaterialModel::StableNeohookeanSplit => "stable_neohookean_split",
            MaterialModel::CorotationalSplit => "corotational_split",
            MaterialModel::Guccione => "guccione",
        }
    }

    /// Parse a scene-file name among [`MaterialModel::ALL`] (the models today's scene
    /// schema can configure; the split models need keys it does not have yet).
    pub fn from_name(name: &str) -> Option<MaterialModel> {
        MaterialModel::ALL.into_iter().find(|m| m.name() == name)
    }

    /// Parse a scene-file name among [`MaterialModel::EVERY`].
    pub fn from_any_name(name: &str) -> Option<MaterialModel> {
        MaterialModel::EVERY.into_iter().find(|m| m.name() == name)
    }

    /// True for the volume/shape split models (`MATERIAL` ≥ 3, `fem_forces_split.wgsl`).
    pub fn is_split(self) -> bool {
        (self as u32) >= MaterialModel::StvkSplit as u32
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
    /// Young's modulus from the Lamé parameters: E = μ(3λ + 2μ)/(λ + μ), Pa.
    pub fn youngs_modulus(&self) -> f64 {
        self.mu * (3.0 * self.lambda + 2.0 * self.mu) / (self.lambda + self.mu)
    }

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

/// Stable Neo-Hookean P and Ψ from the displacement gradient H (see module docs). Computed
/// in SIMD-width columns (`Mat3A`): the same products and sums, element by element.
pub fn snh_stress_energy(h: Mat3, lambda: f32, mu: f32) -> (Mat3, f32) {
    let lambda_hat = lambda + mu;
    let h = glam::Mat3A::from(h);
    let f = glam::Mat3A::IDENTITY + h;
    let trace_a = |m: glam::Mat3A| m.x_axis.x + m.y_axis.y + m.z_axis.z;
    let cofactor_a = |a: glam::Mat3A| {
        glam::Mat3A::from_cols(
            a.y_axis.cross(a.z_axis),
            a.z_axis.cross(a.x_axis),
            a.x_axis.cross(a.y_axis),
        )
    };
    let tr = trace_a(h);
    let j_minus_1 = tr + 0.5 * (tr * tr - trace_a(h * h)) + h.determinant();
    let f_minus_cof =
        h + h.transpose() - glam::Mat3A::from_diagonal(Vec3::splat(tr)) - cofactor_a(h);
    let p = f_minus_cof * mu + cofactor_a(f) * (lambda_hat * j_minus_1);
    let ic_minus_3 =
        2.0 * tr + (h.x_axis.dot(h.x_axis) + h.y_axis.dot(h.y_axis) + h.z_axis.dot(h.z_axis));
    let psi = 0.5 * mu * ic_minus_3 - mu * j_minus_1 + 0.5 * lambda_hat * j_minus_1 * j_minus_1;
    (Mat3::from(p), psi)
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
        // The split models need constants this signature does not carry: with the default
        // ones (κ = 0, Guccione C = 0) only the μ shape part of the first three remains.
        _ => split_stress_energy(
            model,
            h,
            mu,
            &MaterialConstants::default(),
            VolumetricLaw::default(),
            Vec3::ZERO,
        ),
    }
}

/// The directional derivative ∂P(H)\[dH\] of [`elastic_stress_energy`]'s stress, d/dt P(H + t dH)
/// at t = 0 (the tangent C(F):dF), for the laws the particle layer can have; None for the split
/// laws. With F = I + H:
///
/// * `stvk`: dP = dF S + F (λ tr(dE) I + 2μ dE), dE = ½(dFᵀF + FᵀdF);
/// * `stable_neohookean`: dP = μ (dF − d cof F) + λ̂ [(cof F : dF) cof F + (J − 1) d cof F],
///   d cof F the cofactor's derivative (column by column, d(a × b) = da × b + a × db);
/// * `corotational`: with S = RᵀF and dR = R \[w\]×, (tr S I − S) w = axial(RᵀdF − dFᵀR),
///   dP = 2μ (dF − dR) + λ tr(RᵀdF) R + λ (tr S − 3) dR.
pub fn elastic_stress_differential(
    model: MaterialModel,
    h: Mat3,
    dh: Mat3,
    lambda: f32,
    mu: f32,
) -> Option<Mat3> {
    let f = Mat3::IDENTITY + h;
    match model {
        MaterialModel::Stvk => {
            let e = green_strain_from_gradient(h);
            let s = stvk_second_piola(e, Mat3::ZERO, lambda, mu, 0.0, 0.0);
            let de = (dh.transpose() * f + f.transpose() * dh) * 0.5;
            let ds = Mat3::from_diagonal(Vec3::splat(lambda * trace(de))) + de * (2.0 * mu);
            Some(dh * s + f * ds)
        }
        MaterialModel::StableNeohookean => {
            let lambda_hat = lambda + mu;
            let cof = cofactor(f);
            let (a, b, c) = (f.x_axis, f.y_axis, f.z_axis);
            let (da, db, dc) = (dh.x_axis, dh.y_axis, dh.z_axis);
            let dcof = Mat3::from_cols(
                db.cross(c) + b.cross(dc),
                dc.cross(a) + c.cross(da),
                da.cross(b) + a.cross(db),
            );
            let tr = trace(h);
            let j_minus_1 = tr + 0.5 * (tr * tr - trace(h * h)) + h.determinant();
            Some(
                (dh - dcof) * mu
                    + cof * (lambda_hat * ddot(cof, dh))
                    + dcof * (lambda_hat * j_minus_1),
            )
        }
        MaterialModel::Corotational => {
            let r = extract_rotation(f);
            let s = r.transpose() * f;
            let k = r.transpose() * dh - dh.transpose() * r;
            let axial = Vec3::new(k.y_axis.z, k.z_axis.x, k.x_axis.y);
            let m = Mat3::from_diagonal(Vec3::splat(trace(s))) - s;
            let w = m.inverse() * axial;
            let skew = Mat3::from_cols(
                Vec3::new(0.0, w.z, -w.y),
                Vec3::new(-w.z, 0.0, w.x),
                Vec3::new(w.y, -w.x, 0.0),
            );
            let dr = r * skew;
            Some(
                (dh - dr) * (2.0 * mu)
                    + r * (lambda * trace(r.transpose() * dh))
                    + dr * (lambda * (trace(s) - 3.0)),
            )
        }
        _ => None,
    }
}

// ---------------------------------------------------------------------------------------------
// Volume/shape split laws and Guccione (module docs: "Volume/shape split").
// ---------------------------------------------------------------------------------------------

/// J_min: below this volume ratio φ(J) and the logarithmic U(J) switch to their smooth
/// extensions (module docs), so that inverted tets get finite, restoring forces.
pub const VOLUME_RATIO_FLOOR: f32 = 0.1;

/// Poisson ratio from which [`HyperelasticParams::recommended_volume_term`] picks the
/// locking-free nodal average (κ ≥ 2μ(1 + ν)/(3(1 − 2ν)) ≈ 9.67 μ).
pub const NEARLY_INCOMPRESSIBLE_POISSON: f64 = 0.45;

/// The volume part U(J); the value is the `VOLUMETRIC` pipeline constant of
/// `fem_forces_split.wgsl` and `nodal_pressure.wgsl`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum VolumetricLaw {
    /// U = κ/2 (J − 1)², p = κ (J − 1).
    Quadratic = 0,
    /// U = κ/2 (ln J)², p = κ ln J / J.
    LogSquared = 1,
    /// U = κ/4 (J² − 1 − 2 ln J), p = κ/2 (J − 1/J).
    #[default]
    SimoTaylor = 2,
}

impl VolumetricLaw {
    /// All laws.
    pub const ALL: [VolumetricLaw; 3] = [
        VolumetricLaw::Quadratic,
        VolumetricLaw::LogSquared,
        VolumetricLaw::SimoTaylor,
    ];

    /// The scene-file name.
    pub fn name(self) -> &'static str {
        match self {
            VolumetricLaw::Quadratic => "quadratic",
            VolumetricLaw::LogSquared => "log_squared",
            VolumetricLaw::SimoTaylor => "simo_taylor",
        }
    }

    /// Parse a scene-file name.
    pub fn from_name(name: &str) -> Option<VolumetricLaw> {
        VolumetricLaw::ALL.into_iter().find(|m| m.name() == name)
    }
}

/// Where the volume term of a split law is evaluated; `NodalAverage` is the
/// `NODAL_PRESSURE` pipeline constant of `fem_forces_split.wgsl`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum VolumeTerm {
    /// Per tet: P_vol = U′(J_e) cof F_e. Locks as κ/μ grows.
    #[default]
    Element = 0,
    /// Average nodal Jacobian (Bonet & Burton 1998; NiftySim T4ANP): P_vol = p̄_e cof F_e.
    NodalAverage = 1,
}

impl VolumeTerm {
    /// The scene-file name.
    pub fn name(self) -> &'static str {
        match self {
            VolumeTerm::Element => "element",
            VolumeTerm::NodalAverage => "nodal_average",
        }
    }

    /// Parse a scene-file name.
    pub fn from_name(name: &str) -> Option<VolumeTerm> {
        [VolumeTerm::Element, VolumeTerm::NodalAverage]
            .into_iter()
            .find(|m| m.name() == name)
    }
}

/// Guccione's constants: C (Pa) and the dimensionless exponents b_f, b_t, b_fs.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct GuccioneParams {
    /// C, Pa.
    pub c: f64,
    /// b_f (fibre), dimensionless.
    pub bf: f64,
    /// b_t (transverse), dimensionless.
    pub bt: f64,
    /// b_fs (fibre–transverse shear), dimensionless.
    pub bfs: f64,
}

impl GuccioneParams {
    /// Transversely isotropic constants.
    pub fn new(c: f64, bf: f64, bt: f64, bfs: f64) -> GuccioneParams {
        GuccioneParams { c, bf, bt, bfs }
    }

    /// The isotropic case b_f = b_t = b_fs = b: Q = b Ē:Ē.
    pub fn isotropic(c: f64, b: f64) -> GuccioneParams {
        GuccioneParams::new(c, b, b, b)
    }

    /// True when b_f = b_t = b_fs (no fibre needed).
    pub fn is_isotropic(&self) -> bool {
        self.bf == self.bt && self.bt == self.bfs
    }

    /// Upper bound of the small-strain shear modulus, C·max(b_f, b_t, b_fs)/2, Pa
    /// (Q ≤ max(b) Ē:Ē and Ψ̄ ≈ C/2 Q).
    pub fn effective_shear_modulus(&self) -> f64 {
        0.5 * self.c * self.bf.max(self.bt).max(self.bfs)
    }
}

/// The constants of the split laws (what a scene gives beside λ, μ), SI units.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct HyperelasticParams {
    /// Bulk modulus κ, Pa (`bulk_modulus`).
    pub bulk_modulus: f64,
    /// U(J).
    pub volumetric: VolumetricLaw,
    /// Element or nodal-average volume term.
    pub volume_term: VolumeTerm,
    /// Guccione's constants (used by [`MaterialModel::Guccione`] only).
    pub guccione: GuccioneParams,
}

impl HyperelasticParams {
    /// A split-law material with bulk modulus κ (Pa), the default U(J) and the element
    /// volume term.
    pub fn new(bulk_modulus: f64) -> HyperelasticParams {
        HyperelasticParams {
            bulk_modulus,
            ..HyperelasticParams::default()
        }
    }

    /// Bulk modulus from the shear modulus and Poisson ratio: κ = 2μ(1 + ν) / (3(1 − 2ν)).
    pub fn bulk_modulus_from_poisson(mu: f64, poisson_ratio: f64) -> f64 {
        2.0 * mu * (1.0 + poisson_ratio) / (3.0 * (1.0 - 2.0 * poisson_ratio))
    }

    /// The nodal average when κ is at least that of ν = [`NEARLY_INCOMPRESSIBLE_POISSON`]
    /// for shear modulus μ (the default for nearly incompressible materials).
    pub fn recommended_volume_term(bulk_modulus: f64, mu: f64) -> VolumeTerm {
        let threshold =
            HyperelasticParams::bulk_modulus_from_poisson(mu, NEARLY_INCOMPRESSIBLE_POISSON);
        if bulk_modulus >= threshold {
            VolumeTerm::NodalAverage
        } else {
            VolumeTerm::Element
        }
    }

    /// Check the constants `model` uses; the message names the scene key (`material.…`)
    /// and what is wrong, in one line.
    pub fn validate(&self, model: MaterialModel) -> Result<(), String> {
        if !model.is_split() {
            return Ok(());
        }
        let k = self.bulk_modulus;
        if !(k.is_finite() && k > 0.0) {
            return Err(format!(
                "material.bulk_modulus must be a positive number of pascals (got {k})"
            ));
        }
        if model == MaterialModel::Guccione {
            let g = &self.guccione;
            if !(g.c.is_finite() && g.c > 0.0) {
                return Err(format!(
                    "material.guccione_c must be a positive number of pascals (got {})",
                    g.c
                ));
            }
            for (key, b) in [
                ("guccione_bf", g.bf),
                ("guccione_bt", g.bt),
                ("guccione_bfs", g.bfs),
            ] {
                if !(b.is_finite() && b >= 0.0) {
                    return Err(format!(
                        "material.{key} must be a finite exponent ≥ 0 (got {b})"
                    ));
                }
                if b > MAX_GUCCIONE_EXPONENT {
                    return Err(format!(
                        "material.{key} must be at most {MAX_GUCCIONE_EXPONENT} (got {}): e^Q, Q = b E², would overflow single precision below a strain of 0.3 (published values are 1 to 50)",
                        crate::scene::Num(b)
                    ));
                }
            }
            if g.bf.max(g.bt).max(g.bfs) <= 0.0 {
                return Err(
                    "material.guccione_bf/bt/bfs are all 0: the law has no stiffness".into(),
                );
            }
        }
        Ok(())
    }

    /// True when `model` reads a fibre per tet (Guccione with b_f, b_t, b_fs not all equal).
    pub fn needs_fibres(&self, model: MaterialModel) -> bool {
        model == MaterialModel::Guccione && !self.guccione.is_isotropic()
    }

    /// Check the per-tet fibres (packed xyz, as `Model::fibres`) for `model`: present for
    /// every tet when the law is fibred, each finite and non-zero. One-line message naming
    /// the key.
    pub fn check_fibres(
        &self,
        model: MaterialModel,
        fibres: &[f32],
        n_tets: usize,
    ) -> Result<(), String> {
        if !self.needs_fibres(model) {
            return Ok(());
        }
        if fibres.is_empty() {
            return Err(format!(
                "material.fibre: model \"{}\" with guccione_bf, guccione_bt, guccione_bfs not all equal needs a fibre per tet, and the mesh has none; give `fibre = [x, y, z]`",
                model.name()
            ));
        }
        if fibres.len() != 3 * n_tets {
            return Err(format!(
                "material.fibre: {} fibre components for {n_tets} tets",
                fibres.len()
            ));
        }
        for (e, f) in fibres.chunks_exact(3).enumerate() {
            let len2 = f.iter().map(|c| c * c).sum::<f32>();
            if !(len2.is_finite() && len2 > 1e-12) {
                return Err(format!(
                    "mesh.file: the fibre of tet {e} (tets counted from 0 in file order, other cells skipped) is zero or not finite, {f:?}: the fibred law needs one in every tet (or give material.fibre = [x, y, z])"
                ));
            }
        }
        Ok(())
    }

    /// Check a constant fibre (`fibre = [x, y, z]`): finite and non-zero.
    pub fn check_constant_fibre(fibre: [f64; 3]) -> Result<(), String> {
        if crate::scene::unit_direction(fibre).is_none() {
            return Err(format!(
                "material.fibre must be a finite non-zero vector (got {fibre:?})"
            ));
        }
        Ok(())
    }

    /// Small-strain shear modulus of `model` given the scene's μ: μ for the split laws,
    /// [`GuccioneParams::effective_shear_modulus`] for Guccione.
    pub fn shear_modulus(&self, model: MaterialModel, mu: f64) -> f64 {
        if model == MaterialModel::Guccione {
            self.guccione.effective_shear_modulus()
        } else {
            mu
        }
    }

    /// The modulus of the dilatational wave, c_p = sqrt(M/ρ), for the time step: λ + 2μ for
    /// the (λ, μ) laws, κ + 4/3 μ_eff for the split laws.
    pub fn p_wave_modulus(&self, model: MaterialModel, lambda: f64, mu: f64) -> f64 {
        if model.is_split() {
            self.bulk_modulus + 4.0 / 3.0 * self.shear_modulus(model, mu)
        } else {
            lambda + 2.0 * mu
        }
    }

    /// The uniform the split kernels read.
    pub fn constants(&self) -> MaterialConstants {
        let g = &self.guccione;
        MaterialConstants {
            bulk_modulus: self.bulk_modulus as f32,
            guccione_c: g.c as f32,
            guccione_bf: g.bf as f32,
            guccione_bt: g.bt as f32,
            guccione_bfs: g.bfs as f32,
            _pad0: 0,
            _pad1: 0,
            _pad2: 0,
        }
    }
}

/// The split laws' constants as the kernels read them (WGSL `MaterialConstants` in
/// `kernels/shared/hyperelastic.wgsl`, binding `material_constants`), 32 bytes; a test
/// checks the layout against naga's.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct MaterialConstants {
    /// Bulk modulus κ, Pa.
    pub bulk_modulus: f32,
    /// Guccione C, Pa.
    pub guccione_c: f32,
    /// Guccione b_f.
    pub guccione_bf: f32,
    /// Guccione b_t.
    pub guccione_bt: f32,
    /// Guccione b_fs.
    pub guccione_bfs: f32,
    /// Padding to 32 bytes.
    pub _pad0: u32,
    /// Padding.
    pub _pad1: u32,
    /// Padding.
    pub _pad2: u32,
}

impl MaterialConstants {
    /// True when Guccione's exponents differ, so the law reads the tet's fibre.
    pub fn is_fibred(&self) -> bool {
        self.guccione_bf != self.guccione_bt || self.guccione_bt != self.guccione_bfs
    }
}

/// Where the small-argument series take over from the library functions: |x| < 0.1.
pub const SERIES_RADIUS: f32 = 0.1;

/// ln(1 + d) in f32 without the rounding of 1 + d: Taylor series (Horner, 12 terms) for
/// |d| < 0.1, else ln(1 + d). Same algorithm as `log1p_f32` in `hyperelastic.wgsl`.
pub fn log1p_f32(d: f32) -> f32 {
    if d.abs() < SERIES_RADIUS {
        let mut acc = 1.0 / 12.0;
        for k in (1..12).rev() {
            acc = 1.0 / k as f32 - d * acc;
        }
        d * acc
    } else {
        (1.0 + d).ln()
    }
}

/// d − ln(1 + d) = d²/2 − d³/3 + … without cancellation: series (12 terms) for |d| < 0.1.
pub fn x_minus_log1p_f32(d: f32) -> f32 {
    if d.abs() < SERIES_RADIUS {
        let mut acc = 1.0 / 13.0;
        for k in (2..13).rev() {
            acc = 1.0 / k as f32 - d * acc;
        }
        d * d * acc
    } else {
        d - (1.0 + d).ln()
    }
}

/// eˣ − 1 without cancellation: series (10 terms) for |x| < 0.1, else eˣ − 1.
pub fn expm1_f32(x: f32) -> f32 {
    if x.abs() < SERIES_RADIUS {
        let mut acc = 1.0;
        for k in (2..=10).rev() {
            acc = 1.0 + x * acc / k as f32;
        }
        x * acc
    } else {
        x.exp() - 1.0
    }
}

/// (1 + d)^(−1/3) − 1 without cancellation: binomial series Σ_k c_k d^k,
/// c_k = c_{k−1} (−1/3 − k + 1)/k (10 terms) for |d| < 0.1, else (1 + d)^(−1/3) − 1.
pub fn inv_cbrt_minus_one_f32(d: f32) -> f32 {
    if d.abs() < SERIES_RADIUS {
        let mut term = 1.0f32;
        let mut sum = 0.0f32;
        for k in 1..=10 {
            term *= (-1.0 / 3.0 - (k - 1) as f32) / k as f32 * d;
            sum += term;
        }
        sum
    } else {
        (1.0 + d).powf(-1.0 / 3.0) - 1.0
    }
}

/// J − 1 = det(I + H) − 1 = tr H + ½((tr H)² − tr H²) + det H, without cancellation.
pub fn jacobian_minus_one(h: Mat3) -> f32 {
    let tr = trace(h);
    tr + 0.5 * (tr * tr - trace(h * h)) + h.determinant()
}

/// U(J) and p = U′(J) of `law` with bulk modulus κ, from d = J − 1 (module docs). Below
/// J_min the logarithmic laws continue as U(J_min) + U′ δ + ½ U″ δ², δ = J − J_min.
pub fn volumetric_energy_pressure(law: VolumetricLaw, kappa: f32, d: f32) -> (f32, f32) {
    match law {
        VolumetricLaw::Quadratic => (0.5 * kappa * d * d, kappa * d),
        VolumetricLaw::LogSquared | VolumetricLaw::SimoTaylor => {
            let j = 1.0 + d;
            if j >= VOLUME_RATIO_FLOOR {
                let (u, p, _) = log_law(law, kappa, d);
                (u, p)
            } else {
                let (u0, p0, k0) = log_law(law, kappa, VOLUME_RATIO_FLOOR - 1.0);
                let delta = j - VOLUME_RATIO_FLOOR;
                (u0 + p0 * delta + 0.5 * k0 * delta * delta, p0 + k0 * delta)
            }
        }
    }
}

/// (U, U′, U″) of the two logarithmic laws at J = 1 + d > 0.
fn log_law(law: VolumetricLaw, kappa: f32, d: f32) -> (f32, f32, f32) {
    let j = 1.0 + d;
    if law == VolumetricLaw::LogSquared {
        let l = log1p_f32(d);
        (
            0.5 * kappa * l * l,
            kappa * l / j,
            kappa * (1.0 - l) / (j * j),
        )
    } else {
        (
            0.25 * kappa * (d * d + 2.0 * x_minus_log1p_f32(d)),
            0.5 * kappa * d * (2.0 + d) / j,
            0.5 * kappa * (1.0 + 1.0 / (j * j)),
        )
    }
}

/// Outer product a ⊗ b (column j is a·b_j).
#[inline]
pub fn outer(a: Vec3, b: Vec3) -> Mat3 {
    Mat3::from_cols(a * b.x, a * b.y, a * b.z)
}

/// The kinematics of the split: J − 1, cof F, s = φ^(−1/3) − 1, r = φ′/φ and
/// H̄ = F̄ − I = (1 + s) H + s I (module docs; φ = J above [`VOLUME_RATIO_FLOOR`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SplitKinematics {
    /// J − 1.
    pub j_minus_1: f32,
    /// cof F = ∂J/∂F.
    pub cof_f: Mat3,
    /// s = φ(J)^(−1/3) − 1.
    pub s: f32,
    /// r = φ′(J)/φ(J) (1/J above the floor).
    pub r: f32,
    /// H̄ = F̄ − I.
    pub h_bar: Mat3,
}

/// [`SplitKinematics`] of the displacement gradient H.
pub fn split_kinematics(h: Mat3) -> SplitKinematics {
    let d = jacobian_minus_one(h);
    let j = 1.0 + d;
    let (s, r) = if j >= VOLUME_RATIO_FLOOR {
        (inv_cbrt_minus_one_f32(d), 1.0 / j)
    } else {
        let a = VOLUME_RATIO_FLOOR;
        (
            a.powf(-1.0 / 3.0) * (-(j - a) / (3.0 * a)).exp() - 1.0,
            1.0 / a,
        )
    };
    SplitKinematics {
        j_minus_1: d,
        cof_f: cofactor(Mat3::IDENTITY + h),
        s,
        r,
        h_bar: h * (1.0 + s) + Mat3::from_diagonal(Vec3::splat(s)),
    }
}

/// A stable orthonormal fibre frame (f, s, n): f normalised, s the coordinate axis least
/// aligned with f (lowest index on ties) made orthogonal to f, n = f × s. Only for reading
/// strain components; the Guccione law itself does not depend on the sheet choice.
pub fn fibre_frame(fibre: Vec3) -> (Vec3, Vec3, Vec3) {
    let f = fibre.normalize();
    let a = f.abs();
    let axis = if a.x <= a.y && a.x <= a.z {
        Vec3::X
    } else if a.y <= a.z {
        Vec3::Y
    } else {
        Vec3::Z
    };
    let s = (axis - f * f.dot(axis)).normalize();
    (f, s, f.cross(s))
}

/// Guccione's Q from the Green strain E and the unit fibre f in the invariant form
/// Q = b_f E_ff² + b_t (E:E − 2|E f|² + E_ff²) + 2 b_fs (|E f|² − E_ff²). With f = 0 it is
/// the isotropic b_t E:E.
pub fn guccione_q(e: Mat3, f: Vec3, bf: f32, bt: f32, bfs: f32) -> f32 {
    let ef = e * f;
    let eff = f.dot(ef);
    let efef = ef.dot(ef);
    bf * eff * eff + bt * (ddot(e, e) - 2.0 * efef + eff * eff) + 2.0 * bfs * (efef - eff * eff)
}

/// Guccione's Q from the components of E in the frame (f, s, n), exactly as the issue
/// writes it: b_f E_ff² + b_t (E_ss² + E_nn² + E_sn² + E_ns²) + b_fs (E_fs² + E_sf² + E_fn² + E_nf²).
pub fn guccione_q_in_frame(e: Mat3, frame: (Vec3, Vec3, Vec3), bf: f32, bt: f32, bfs: f32) -> f32 {
    let (f, s, n) = frame;
    let c = |a: Vec3, b: Vec3| a.dot(e * b);
    let (ff, ss, nn) = (c(f, f), c(s, s), c(n, n));
    let (sn, ns, fs, sf, fn_, nf) = (c(s, n), c(n, s), c(f, s), c(s, f), c(f, n), c(n, f));
    bf * ff * ff
        + bt * (ss * ss + nn * nn + sn * sn + ns * ns)
        + bfs * (fs * fs + sf * sf + fn_ * fn_ + nf * nf)
}

/// Q above which Guccione's e^Q continues as its second-order Taylor polynomial at Q_max
/// (e^40 ≈ 2e17: a strain no tissue survives, reached only by inverted or exploding tets),
/// so that P stays finite in f32 and still the derivative of Ψ.
pub const GUCCIONE_Q_MAX: f32 = 40.0;

/// (g(Q) − 1, g′(Q)) with g = e^Q up to [`GUCCIONE_Q_MAX`] and
/// g = e^Qmax (1 + δ + δ²/2), δ = Q − Q_max, above it (C²).
pub fn guccione_exp(q: f32) -> (f32, f32) {
    if q <= GUCCIONE_Q_MAX {
        (expm1_f32(q), q.exp())
    } else {
        let e = GUCCIONE_Q_MAX.exp();
        let delta = q - GUCCIONE_Q_MAX;
        (
            e * (1.0 + delta + 0.5 * delta * delta) - 1.0,
            e * (1.0 + delta),
        )
    }
}

/// Guccione's second Piola–Kirchhoff stress and energy density from the Green strain E
/// and the unit fibre f (f = 0 for the isotropic case):
/// S = C e^Q [b_t E + (b_f + b_t − 2b_fs) E_ff f⊗f + (b_fs − b_t)(E f⊗f + f⊗E f)],
/// W = C/2 (e^Q − 1) (e^Q as [`guccione_exp`] above Q_max).
pub fn guccione_second_piola(e: Mat3, f: Vec3, c: f32, bf: f32, bt: f32, bfs: f32) -> (Mat3, f32) {
    let ef = e * f;
    let eff = f.dot(ef);
    let (g_minus_1, g_prime) = guccione_exp(guccione_q(e, f, bf, bt, bfs));
    let s = (e * bt
        + outer(f, f) * ((bf + bt - 2.0 * bfs) * eff)
        + (outer(ef, f) + outer(f, ef)) * (bfs - bt))
        * (c * g_prime);
    (s, 0.5 * c * g_minus_1)
}

/// The shape law of a split model at H̄ = F̄ − I: (P̄ = ∂Ψ̄/∂F̄, Ψ̄) (module docs). `fibre` is
/// the unit fibre (Guccione, fibred) or zero. Legacy models give zero.
pub fn isochoric_law(
    model: MaterialModel,
    h_bar: Mat3,
    mu: f32,
    constants: &MaterialConstants,
    fibre: Vec3,
) -> (Mat3, f32) {
    let f_bar = Mat3::IDENTITY + h_bar;
    match model {
        MaterialModel::StvkSplit => {
            let e = green_strain_from_gradient(h_bar);
            (f_bar * (e * (2.0 * mu)), mu * ddot(e, e))
        }
        MaterialModel::StableNeohookeanSplit => {
            let tr = trace(h_bar);
            let p = (h_bar + h_bar.transpose()
                - Mat3::from_diagonal(Vec3::splat(tr))
                - cofactor(h_bar))
                * mu;
            let psi = 0.5 * mu * (ddot(h_bar, h_bar) - tr * tr + trace(h_bar * h_bar))
                - mu * h_bar.determinant();
            (p, psi)
        }
        MaterialModel::CorotationalSplit => {
            let f_minus_r = f_bar - extract_rotation(f_bar);
            (f_minus_r * (2.0 * mu), mu * ddot(f_minus_r, f_minus_r))
        }
        MaterialModel::Guccione => {
            let e = green_strain_from_gradient(h_bar);
            let c = constants;
            let (s, w) = guccione_second_piola(
                e,
                fibre,
                c.guccione_c,
                c.guccione_bf,
                c.guccione_bt,
                c.guccione_bfs,
            );
            (f_bar * s, w)
        }
        _ => (Mat3::ZERO, 0.0),
    }
}

/// Shape part of a split model from H: (P_iso, Ψ_iso) with
/// P_iso = φ^(−1/3) [P̄ − (φ′/(3φ)) (P̄:F) cof F], Ψ_iso = Ψ̄(F̄), and the kinematics (for
/// the volume term).
pub fn isochoric_stress_energy(
    model: MaterialModel,
    h: Mat3,
    mu: f32,
    constants: &MaterialConstants,
    fibre: Vec3,
) -> (Mat3, f32, SplitKinematics) {
    let k = split_kinematics(h);
    let (p_bar, psi) = isochoric_law(model, k.h_bar, mu, constants, fibre);
    let p_bar_f = trace(p_bar) + ddot(p_bar, h);
    let p = (p_bar - k.cof_f * (k.r / 3.0 * p_bar_f)) * (1.0 + k.s);
    (p, psi, k)
}

/// A split model with the element volume term: P = P_iso + U′(J) cof F, Ψ = Ψ_iso + U(J).
pub fn split_stress_energy(
    model: MaterialModel,
    h: Mat3,
    mu: f32,
    constants: &MaterialConstants,
    law: VolumetricLaw,
    fibre: Vec3,
) -> (Mat3, f32) {
    let (p, psi, k) = isochoric_stress_energy(model, h, mu, constants, fibre);
    let (u, pressure) = volumetric_energy_pressure(law, constants.bulk_modulus, k.j_minus_1);
    (p + k.cof_f * pressure, psi + u)
}

/// P and Ψ of any model with the element volume term: [`elastic_stress_energy`] for the
/// (λ, μ) models, [`split_stress_energy`] for the split ones.
pub fn hyperelastic_stress_energy(
    model: MaterialModel,
    h: Mat3,
    lambda: f32,
    mu: f32,
    constants: &MaterialConstants,
    law: VolumetricLaw,
    fibre: Vec3,
) -> (Mat3, f32) {
    if model.is_split() {
        split_stress_energy(model, h, mu, constants, law, fibre)
    } else {
        elastic_stress_energy(model, h, lambda, mu)
    }
}
