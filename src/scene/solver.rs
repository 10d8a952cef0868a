//! `[solver]`: time step (auto or seconds), safety factor, damping, static tolerance, duration.

use super::{positive, Bad};
use crate::error::Result;
use serde::Deserialize;

/// `dt`: `"auto"` or seconds.
#[derive(Clone, Debug, Deserialize)]
#[serde(untagged, expecting = "dt must be \"auto\" or a time step in seconds")]
pub enum DtSpec {
    /// Seconds.
    Seconds(f64),
    /// Must be `"auto"`.
    Word(String),
}

/// `[solver]`.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SolverSpec {
    /// `"auto"` (safety × stability bound) or a step in seconds.
    pub dt: Option<DtSpec>,
    /// Safety factor for `dt = "auto"`, in (0, 1].
    pub safety: Option<f64>,
    /// Mass-proportional damping α, 1/s: v ← v / (1 + α dt) each step.
    pub damping: Option<f64>,
    /// `--until-static` stops when ‖residual force‖ ≤ tolerance · ‖external load‖.
    pub static_tolerance: Option<f64>,
    /// Simulated time `palpate run` uses when no length is given, s.
    pub duration: Option<f64>,
    /// Mass scaling s ≥ 1 (default 1): the inertia of every vertex and particle is s times
    /// the material's (gravity is divided by s, so the weight is unchanged). Explicit
    /// dynamics' standard way to a larger stable step (dt grows as √s): statics are exact,
    /// natural frequencies drop by √s.
    pub mass_scaling: Option<f64>,
}

/// Solver settings after validation.
#[derive(Clone, Debug, PartialEq)]
pub struct SolverSettings {
    /// A fixed step in seconds, or None for auto.
    pub dt: Option<f64>,
    /// Safety factor for auto dt.
    pub safety: f64,
    /// Mass-proportional damping α, 1/s.
    pub damping: f64,
    /// Relative residual tolerance for `--until-static`.
    pub static_tolerance: f64,
    /// Default run length, s.
    pub duration: Option<f64>,
    /// Mass scaling s ≥ 1 (see [`SolverSpec::mass_scaling`]).
    pub mass_scaling: f64,
}

pub(super) fn resolve_solver(s: &SolverSpec, bad: &Bad) -> Result<SolverSettings> {
    let dt = match &s.dt {
        None => None,
        Some(DtSpec::Word(w)) if w == "auto" => None,
        Some(DtSpec::Word(w)) => {
            return Err(bad(
                "solver.dt",
                format!("must be \"auto\" or seconds, got \"{w}\""),
            ))
        }
        Some(DtSpec::Seconds(v)) => Some(positive(bad, "solver.dt", *v, "s")?),
    };
    let safety = s.safety.unwrap_or(crate::timestep::DEFAULT_SAFETY);
    if !(safety > 0.0 && safety <= 1.0) {
        return Err(bad(
            "solver.safety",
            format!("must be in (0, 1], got {}", super::Num(safety)),
        ));
    }
    let damping = super::at_least(bad, "solver.damping", s.damping.unwrap_or(0.0), 0.0, "1/s")?;
    let static_tolerance = s.static_tolerance.unwrap_or(1e-3);
    positive(bad, "solver.static_tolerance", static_tolerance, "")?;
    let duration = match s.duration {
        Some(d) => Some(positive(bad, "solver.duration", d, "s")?),
        None => None,
    };
    let mass_scaling = s.mass_scaling.unwrap_or(1.0);
    if !(mass_scaling.is_finite() && (1.0..=1.0e6).contains(&mass_scaling)) {
        return Err(bad(
            "solver.mass_scaling",
            format!("must be in [1, 1e6], got {}", super::Num(mass_scaling)),
        ));
    }
    Ok(SolverSettings {
        mass_scaling,
        dt,
        safety,
        damping,
        static_tolerance,
        duration,
    })
}
