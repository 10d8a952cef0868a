//! `[material]`: the constitutive model, elastic constants (E, ν or λ, μ), density,
//! viscosity; for the volume/shape split laws (`stvk_split`, `stable_neohookean_split`,
//! `corotational_split`, `guccione`) also the bulk modulus, U(J), the volume term, Guccione's
//! constants and a constant fibre (docs/cardiac.md).

use super::{positive, Bad};
use crate::error::Result;
use crate::material::{
    GuccioneParams, HyperelasticParams, MaterialModel, MaterialParams, VolumeTerm, VolumetricLaw,
};
use serde::Deserialize;

/// `[material]`.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    /// Constitutive model: `"stvk"` (default), `"stable_neohookean"`, `"corotational"`, their
    /// deviatoric–volumetric splits `"stvk_split"`, `"stable_neohookean_split"`,
    /// `"corotational_split"`, or `"guccione"` ([`crate::material::MaterialModel::EVERY`]).
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
    #[serde(default, deserialize_with = "super::exact::option")]
    pub viscosity: Option<[f64; 2]>,
    /// Bulk modulus κ of a split law, Pa (default: from `poisson_ratio`, or λ + 2μ/3).
    pub bulk_modulus: Option<f64>,
    /// U(J) of a split law: `"quadratic"`, `"log_squared"` or `"simo_taylor"` (default).
    pub volumetric: Option<String>,
    /// Volume term of a split law: `"element"` or `"nodal_average"` (default: nodal
    /// average for κ ≥ κ(ν = 0.45), else element).
    pub volume_term: Option<String>,
    /// Guccione's C, Pa.
    pub guccione_c: Option<f64>,
    /// Guccione's b_f (default 1).
    pub guccione_bf: Option<f64>,
    /// Guccione's b_t (default 1).
    pub guccione_bt: Option<f64>,
    /// Guccione's b_fs (default 1).
    pub guccione_bfs: Option<f64>,
    /// A constant fibre direction for every tet (overrides the mesh's fibres).
    #[serde(default, deserialize_with = "super::exact::option")]
    pub fibre: Option<[f64; 3]>,
}

/// What `[material]` resolves to.
#[derive(Clone, Copy, Debug)]
pub(super) struct ResolvedMaterial {
    /// λ, μ, ρ, viscosity, model. For a split law μ is its small-strain shear modulus and
    /// λ = κ − 2μ/3, so every λ + 2μ user (time step, wave speed, relaxation) sees κ + 4μ/3.
    pub params: MaterialParams,
    /// The split law's constants.
    pub hyperelastic: Option<HyperelasticParams>,
    /// A constant fibre.
    pub fibre: Option<[f64; 3]>,
}

/// Split the one-line message of [`HyperelasticParams::validate`] ("material.key …") into
/// the key and the rest.
fn bad_of(bad: &Bad, message: String) -> crate::error::PalpateError {
    match message.split_once(' ') {
        Some((key, rest)) if key.starts_with("material.") => {
            bad(key.trim_end_matches(':'), rest.to_string())
        }
        _ => bad("material", message),
    }
}

/// The split-law part of `[material]`: (μ, κ, constants) for split model `model`.
fn resolve_split(
    m: &MaterialSpec,
    model: MaterialModel,
    bad: &Bad,
) -> Result<(f64, HyperelasticParams)> {
    let volumetric = match m.volumetric.as_deref() {
        None => VolumetricLaw::default(),
        Some(name) => VolumetricLaw::from_name(name).ok_or_else(|| {
            bad(
                "material.volumetric",
                format!("unknown law '{name}' (known: quadratic, log_squared, simo_taylor)"),
            )
        })?,
    };
    let mut guccione = GuccioneParams::default();
    let mu = if model == MaterialModel::Guccione {
        for (key, v) in [
            ("material.youngs_modulus", m.youngs_modulus),
            ("material.lambda", m.lambda),
            ("material.mu", m.mu),
        ] {
            if v.is_some() {
                return Err(bad(
                    key,
                    "is not used by model 'guccione' (give guccione_c, guccione_bf, guccione_bt, guccione_bfs)".into(),
                ));
            }
        }
        fits_f32(
            bad,
            &[
                ("material.guccione_c", m.guccione_c),
                ("material.guccione_bf", m.guccione_bf),
                ("material.guccione_bt", m.guccione_bt),
                ("material.guccione_bfs", m.guccione_bfs),
            ],
        )?;
        let c = m.guccione_c.ok_or_else(|| {
            bad(
                "material.guccione_c",
                "is required for model 'guccione' (Pa)".into(),
            )
        })?;
        guccione = GuccioneParams::new(
            c,
            m.guccione_bf.unwrap_or(1.0),
            m.guccione_bt.unwrap_or(1.0),
            m.guccione_bfs.unwrap_or(1.0),
        );
        let probe = HyperelasticParams {
            bulk_modulus: 1.0,
            guccione,
            ..HyperelasticParams::default()
        };
        probe.validate(model).map_err(|e| bad_of(bad, e))?;
        guccione.effective_shear_modulus()
    } else {
        for (key, v) in [
            ("material.guccione_c", m.guccione_c),
            ("material.guccione_bf", m.guccione_bf),
            ("material.guccione_bt", m.guccione_bt),
            ("material.guccione_bfs", m.guccione_bfs),
        ] {
            if v.is_some() {
                return Err(bad(
                    key,
                    format!("applies to model 'guccione' only, not '{}'", model.name()),
                ));
            }
        }
        match (m.youngs_modulus, m.lambda, m.mu) {
            (Some(e), None, None) => {
                positive(bad, "material.youngs_modulus", e, "Pa")?;
                let nu = m.poisson_ratio.ok_or_else(|| {
                    bad("material.poisson_ratio", "is required with youngs_modulus".into())
                })?;
                check_nu(bad, nu)?;
                MaterialParams::lame_from_young(e, nu).1
            }
            (None, Some(l), Some(mu)) => {
                positive(bad, "material.mu", mu, "Pa")?;
                if m.bulk_modulus.is_none() && !(l.is_finite() && l + 2.0 * mu / 3.0 > 0.0) {
                    return Err(bad(
                        "material.lambda",
                        format!("must give a positive bulk modulus λ + 2μ/3, got λ = {l}"),
                    ));
                }
                mu
            }
            (None, None, Some(mu)) => positive(bad, "material.mu", mu, "Pa")?,
            _ => {
                return Err(bad(
                    "material",
                    "give youngs_modulus and poisson_ratio, or mu (with bulk_modulus or poisson_ratio), or lambda and mu".into(),
                ))
            }
        }
    };
    fits_f32(bad, &[("material.bulk_modulus", m.bulk_modulus)])?;
    let bulk_modulus = match (m.bulk_modulus, m.poisson_ratio, m.lambda) {
        (Some(k), _, _) => {
            if m.lambda.is_some() {
                return Err(bad(
                    "material.bulk_modulus",
                    "give either bulk_modulus or lambda, not both".into(),
                ));
            }
            k
        }
        (None, Some(nu), _) => {
            check_nu(bad, nu)?;
            HyperelasticParams::bulk_modulus_from_poisson(mu, nu)
        }
        (None, None, Some(l)) => l + 2.0 * mu / 3.0,
        (None, None, None) => {
            return Err(bad(
                "material.bulk_modulus",
                format!(
                    "is required for model '{}' (Pa; or give poisson_ratio)",
                    model.name()
                ),
            ))
        }
    };
    let volume_term = match m.volume_term.as_deref() {
        None => HyperelasticParams::recommended_volume_term(bulk_modulus, mu),
        Some(name) => VolumeTerm::from_name(name).ok_or_else(|| {
            bad(
                "material.volume_term",
                format!("unknown volume term '{name}' (known: element, nodal_average)"),
            )
        })?,
    };
    let h = HyperelasticParams {
        bulk_modulus,
        volumetric,
        volume_term,
        guccione,
    };
    h.validate(model).map_err(|e| bad_of(bad, e))?;
    if let Some(f) = m.fibre {
        HyperelasticParams::check_constant_fibre(f).map_err(|e| bad_of(bad, e))?;
    }
    Ok((mu, h))
}

fn check_nu(bad: &Bad, nu: f64) -> Result<()> {
    if nu > -1.0 && nu < 0.5 {
        Ok(())
    } else {
        Err(bad(
            "material.poisson_ratio",
            format!("must be in (-1, 0.5), got {}", super::Num(nu)),
        ))
    }
}

pub(super) fn resolve_material(m: &MaterialSpec, bad: &Bad) -> Result<ResolvedMaterial> {
    let name = m.model.as_deref().unwrap_or("stvk");
    let model = MaterialModel::from_any_name(name).ok_or_else(|| {
        let known: Vec<&str> = MaterialModel::EVERY.iter().map(|m| m.name()).collect();
        bad(
            "material.model",
            format!("unknown model '{name}' (known: {})", known.join(", ")),
        )
    })?;
    let mut hyperelastic = None;
    let (lambda, mu) = if model.is_split() {
        let (mu, h) = resolve_split(m, model, bad)?;
        hyperelastic = Some(h);
        (h.bulk_modulus - 2.0 * mu / 3.0, mu)
    } else {
        for (key, set) in [
            ("material.bulk_modulus", m.bulk_modulus.is_some()),
            ("material.volumetric", m.volumetric.is_some()),
            ("material.volume_term", m.volume_term.is_some()),
            ("material.guccione_c", m.guccione_c.is_some()),
            ("material.guccione_bf", m.guccione_bf.is_some()),
            ("material.guccione_bt", m.guccione_bt.is_some()),
            ("material.guccione_bfs", m.guccione_bfs.is_some()),
            ("material.fibre", m.fibre.is_some()),
        ] {
            if set {
                return Err(bad(
                    key,
                    format!(
                        "applies to the split laws only (stvk_split, stable_neohookean_split, corotational_split, guccione), not '{name}'"
                    ),
                ));
            }
        }
        resolve_lame(m, bad)?
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
    Ok(ResolvedMaterial {
        params: MaterialParams {
            lambda,
            mu,
            phi,
            psi,
            density,
            model,
        },
        hyperelastic,
        fibre: m.fibre,
    })
}

/// (λ, μ) of the (λ, μ) laws.
fn resolve_lame(m: &MaterialSpec, bad: &Bad) -> Result<(f64, f64)> {
    Ok(match (m.youngs_modulus, m.poisson_ratio, m.lambda, m.mu) {
        (Some(e), Some(nu), None, None) => {
            positive(bad, "material.youngs_modulus", e, "Pa")?;
            if !(nu > -1.0 && nu < 0.5) {
                return Err(bad(
                    "material.poisson_ratio",
                    format!("must be in (-1, 0.5), got {}", super::Num(nu)),
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
    })
}

/// Refuse a given key whose value single precision cannot hold (the kernels compute in f32;
/// a derived modulus would otherwise be blamed instead of the key written).
fn fits_f32(bad: &Bad, keys: &[(&str, Option<f64>)]) -> Result<()> {
    for &(key, v) in keys {
        if let Some(v) = v.filter(|v| v.is_finite() && v.abs() > f32::MAX as f64) {
            return Err(bad(
                key,
                format!(
                    "{} does not fit single precision (f32, |v| <= 3.4e38); rescale the units",
                    super::Num(v)
                ),
            ));
        }
    }
    Ok(())
}
