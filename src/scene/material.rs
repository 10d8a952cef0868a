//! `[material]`: the constitutive model, elastic constants (E, ν or λ, μ), density, viscosity.

use super::{positive, Bad};
use crate::error::Result;
use crate::material::{MaterialModel, MaterialParams};
use serde::Deserialize;

/// `[material]`.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    /// Constitutive model: `"stvk"`, `"stable_neohookean"` or `"corotational"`.
    pub model: Option<String>,
    /// Young's modulus E, Pa.
    pub youngs_modulus: Option<f64>,
    /// Poisson ratio ν, in (−1, 0.5).
    pub poisson_ratio: Option<f64>,
    /// First Lamé parameter λ, Pa (instead of E, ν).
    pub lambda: Option<f64>,
    /// Shear modulus μ, Pa (instead of E, ν).
    pub mu: Option<f64>,
    /// Rest density ρ, kg/m³.
    pub density: Option<f64>,
    /// Viscosity [φ, ψ] of paper eq. (4), Pa·s.
    pub viscosity: Option<[f64; 2]>,
}

pub(super) fn resolve_material(m: &MaterialSpec, bad: &Bad) -> Result<MaterialParams> {
    let name = m.model.as_deref().unwrap_or("stvk");
    let model = MaterialModel::from_name(name).ok_or_else(|| {
        bad(
            "material.model",
            format!("unknown model '{name}' (known: stvk, stable_neohookean, corotational)"),
        )
    })?;
    let (lambda, mu) = match (m.youngs_modulus, m.poisson_ratio, m.lambda, m.mu) {
        (Some(e), Some(nu), None, None) => {
            positive(bad, "material.youngs_modulus", e, "Pa")?;
            if !(nu > -1.0 && nu < 0.5) {
                return Err(bad(
                    "material.poisson_ratio",
                    format!("must be in (-1, 0.5), got {nu}"),
                ));
            }
            MaterialParams::lame_from_young(e, nu)
        }
        (None, None, Some(l), Some(mu)) => {
            positive(bad, "material.mu", mu, "Pa")?;
            // λ may be negative down to the limit of positive bulk modulus K = λ + 2μ/3 > 0.
            if !l.is_finite() || l + 2.0 * mu / 3.0 <= 0.0 {
                return Err(bad(
                    "material.lambda",
                    format!("must give a positive bulk modulus λ + 2μ/3, got λ = {l}"),
                ));
            }
            (l, mu)
        }
        _ => {
            return Err(bad(
                "material",
                "give either youngs_modulus and poisson_ratio, or lambda and mu".into(),
            ))
        }
    };
    let density = positive(
        bad,
        "material.density",
        m.density
            .ok_or_else(|| bad("material.density", "is required (kg/m³)".into()))?,
        "kg/m³",
    )?;
    let [phi, psi] = m.viscosity.unwrap_or([0.0, 0.0]);
    if !(phi.is_finite() && psi.is_finite() && psi >= 0.0 && phi + 2.0 * psi / 3.0 >= 0.0) {
        return Err(bad(
            "material.viscosity",
            format!("[phi, psi] must have psi >= 0 and phi + 2 psi/3 >= 0, got [{phi}, {psi}]"),
        ));
    }
    Ok(MaterialParams {
        lambda,
        mu,
        phi,
        psi,
        density,
        model,
    })
}
