//! The explicit time-step bound (paper eq. 14, corrected) and the automatic step.
//!
//! `h` is the smallest altitude over all tets, h = min_e 3V_e / A_e,max (the distance from a
//! vertex to the largest opposite face): the shortest length over which a tet can be
//! squashed, which is what limits an explicit step. The bound is the time a dilatational
//! wave, c_p = sqrt((λ + 2μ)/ρ), takes to cross h, reduced for viscosity:
//!
//!   dt_bound = (h / c_p) · (sqrt(1 + ζ²) − ζ),  ζ = (φ + 2ψ) · ω_max / (2(λ + 2μ)),  ω_max = 2 c_p / h,
//!
//! which is the symplectic-Euler limit 2/ω·(sqrt(1+ζ²) − ζ) of a damped oscillator with the
//! highest mesh frequency ω_max. The paper's eq. (14), h_edge·sqrt(ρ / (2λ + μ)), with
//! h_edge the shortest edge, uses a wave speed with λ and μ swapped; it is reported beside
//! ours. `dt = "auto"` takes `safety · dt_bound`.

use crate::material::MaterialParams;

/// Default safety factor applied to the bound by `dt = "auto"`.
pub const DEFAULT_SAFETY: f64 = 0.5;

/// The most the tool's contact springs may shorten the stable step: to 1/1000 of the
/// tissue's. A penalty contact is tuned to the tissue it touches; one a thousand times
/// stiffer is a mistake in the scene, and a run would take that many times the steps.
pub const MAX_CONTACT_STIFFENING: f64 = 1e3;

/// sqrt(1 + ζ²) − ζ, the factor by which damping ratio ζ shortens a symplectic-Euler step,
/// in the form 1/(sqrt(1 + ζ²) + ζ): no cancellation at large ζ, no overflow of ζ².
pub fn damped_step_factor(zeta: f64) -> f64 {
    1.0 / (zeta.hypot(1.0) + zeta)
}

/// The stability bounds of a mesh and material.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct TimeStepBounds {
    /// Smallest tet altitude, m (h of our bound).
    pub h_altitude: f64,
    /// Shortest edge, m (h of the paper's eq. 14).
    pub h_edge: f64,
    /// Dilatational wave speed sqrt((λ+2μ)/ρ), m/s.
    pub p_wave_speed: f64,
    /// The paper's "wave speed" sqrt((2λ+μ)/ρ), m/s.
    pub paper_wave_speed: f64,
    /// Our bound (see module docs), s.
    pub dt_bound: f64,
    /// The paper's eq. (14) bound h_edge·sqrt(ρ/(2λ+μ)), s (NaN where 2λ + μ ≤ 0, ν ≤ −0.5:
    /// the paper's speed is not real there; `summary.json` writes null).
    pub dt_paper_eq14: f64,
    /// The bound of the tissue alone (before the tool's contact springs), s.
    pub dt_elastic: f64,
    /// The bound of the tool's contact springs alone (∞ without a tool), s.
    pub dt_contact: f64,
    /// The particles' bound when they share the core's step (`particles.coupling =
    /// "exact"`; ∞ otherwise), s.
    pub dt_particles: f64,
}

impl TimeStepBounds {
    /// Bounds for a mesh with smallest altitude `h_altitude` and shortest edge `h_edge`.
    pub fn new(material: &MaterialParams, h_altitude: f64, h_edge: f64) -> Self {
        let m = material;
        let c = m.p_wave_speed();
        let omega = 2.0 * c / h_altitude;
        let zeta = (m.phi + 2.0 * m.psi) * omega / (2.0 * (m.lambda + 2.0 * m.mu));
        let dt_bound = h_altitude / c * damped_step_factor(zeta);
        let paper_c = ((2.0 * m.lambda + m.mu) / m.density).sqrt();
        TimeStepBounds {
            h_altitude,
            h_edge,
            p_wave_speed: c,
            paper_wave_speed: paper_c,
            dt_bound,
            dt_paper_eq14: h_edge / paper_c,
            dt_elastic: dt_bound,
            dt_contact: f64::INFINITY,
            dt_particles: f64::INFINITY,
        }
    }

    /// Take the particles' bound (which already holds their contact springs) as a floor of
    /// the step: dt_bound = min(dt_bound, dt_particles).
    pub fn with_particles(mut self, dt_particles: f64) -> Self {
        self.dt_particles = dt_particles;
        self.dt_bound = self.dt_bound.min(dt_particles);
        self
    }

    /// Combine with the contact springs' own bound: the highest frequencies add in
    /// quadrature, ω² = ω_e² + ω_c², so dt = 1 / sqrt(1/dt_e² + 1/dt_c²) (dt = 2/ω).
    pub fn with_contact(mut self, dt_contact: f64) -> Self {
        self.dt_contact = dt_contact;
        self.dt_bound = 1.0
            / (1.0 / (self.dt_elastic * self.dt_elastic) + 1.0 / (dt_contact * dt_contact)).sqrt();
        self
    }

    /// One line describing how the bound was obtained, for error messages.
    pub fn describe(&self) -> String {
        let contact = if self.dt_contact.is_finite() {
            format!(
                ", tool contact springs alone {:.3e} s (tissue alone {:.3e} s)",
                self.dt_contact, self.dt_elastic
            )
        } else {
            String::new()
        };
        let particles = if self.dt_particles.is_finite() {
            format!(
                ", particles at the core's step (coupling \"exact\") {:.3e} s",
                self.dt_particles
            )
        } else {
            String::new()
        };
        format!(
            "h = {:.3e} m smallest tet altitude, c_p = {:.3e} m/s; paper eq. 14 gives {:.3e} s{contact}{particles}",
            self.h_altitude, self.p_wave_speed, self.dt_paper_eq14
        )
    }
}
