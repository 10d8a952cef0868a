//! `summary.json`: what a run did and how it ended (DESIGN.md §4), and the run's status.

use super::write_atomic;
use crate::error::{PalpateError, Result};
use crate::sim::Backend;
use std::fmt;
use std::path::Path;

/// How a run ended. Serialised in `summary.json` as its one-line text (`ok`, or why not).
#[derive(Clone, Debug, PartialEq)]
pub enum RunStatus {
    /// Completed as asked.
    Ok,
    /// A vertex became non-finite or too fast; the last finite state was written.
    Diverged {
        /// Step that diverged (1-based over the run).
        step: u64,
        /// Lowest vertex that diverged; n_vertices + p for particle p.
        vertex: u32,
        /// Vertices in the mesh (to tell a particle's index from a vertex's).
        n_vertices: u32,
        /// Speed limit, m/s.
        speed_limit: f64,
        /// Speed limit in P-wave speeds.
        wave_speeds: f64,
        /// Time step, s.
        dt: f64,
        /// The stability bound, s.
        dt_bound: f64,
        /// Where a haptic session ended while still recovering (dt being halved): the state
        /// written is the one rolled back to, after this step, to be retried at this dt (s).
        rolled_back_to: Option<(u64, f64)>,
    },
    /// Design 8 (`coupling = "exact"`): the body's strain energy went below zero, which no
    /// state of an elastic body reaches: each particle's remainder
    /// Ψ(F̄ + D) − Ψ(F̄) − P(F̄):D is ≥ 0 only where the law is convex, and past that the
    /// motion runs away down it (seen on a coarse layer under gravity alone). The state at
    /// that batch's end was written.
    EnergyBelowZero {
        /// The last step of the batch that found it (1-based over the run).
        step: u64,
        /// The body's strain energy there, J.
        elastic: f64,
    },
    /// Stopped by Ctrl-C or SIGTERM ([`crate::interrupt`]) after a batch; outputs written.
    Interrupted {
        /// Simulated time reached, s.
        at_seconds: f64,
    },
    /// `--until-static` reached its step cap above the tolerance.
    NotStatic {
        /// Steps taken.
        steps: u64,
        /// Residual reached (relative).
        residual: f64,
        /// Tolerance asked for.
        tolerance: f64,
        /// When the run ended before its loads settled (the tool's path or a follower
        /// pressure's ramp still going): (the time they settle at, the time reached), s.
        loads_still_changing: Option<(f64, f64)>,
    },
}

/// A divergence flag's index in words: `vertex i`, or `particle p` for n_vertices + p.
pub fn flagged_point(index: u32, n_vertices: u32) -> String {
    match index.checked_sub(n_vertices) {
        Some(p) => format!("particle {p}"),
        None => format!("vertex {index}"),
    }
}

impl RunStatus {
    /// True for [`RunStatus::Ok`].
    pub fn is_ok(&self) -> bool {
        *self == RunStatus::Ok
    }

    /// The divergence as a warning (without the "last finite state" tail).
    pub fn divergence(&self) -> Option<String> {
        match self {
            RunStatus::Diverged {
                step,
                vertex,
                n_vertices,
                speed_limit,
                wave_speeds,
                dt,
                dt_bound,
                ..
            } => {
                let at = flagged_point(*vertex, *n_vertices);
                Some(format!(
                    "diverged: non-finite or faster than {speed_limit:.3e} m/s ({wave_speeds} x P-wave speed) at step {step}, {at} (dt = {dt:.3e} s, bound {dt_bound:.3e} s)"
                ))
            }
            RunStatus::EnergyBelowZero { step, elastic } => Some(format!(
                "diverged: the strain energy went below zero ({elastic:.3e} J at step {step}), which no elastic body does: coupling = \"exact\" adds each particle's remainder of its host tet's energy, which is not bounded below where the material law is not convex, and the motion ran away down it (a smaller dt does not help; a finer particle spacing or coupling = \"blend\" does)"
            )),
            _ => None,
        }
    }
}

impl fmt::Display for RunStatus {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RunStatus::Ok => write!(f, "ok"),
            RunStatus::Diverged {
                rolled_back_to: Some((step, dt)),
                ..
            } => write!(
                f,
                "{}; the session ended while it recovered: rolled back to step {step}, to retry at dt = {dt:.3e} s; that state written",
                self.divergence().unwrap_or_default()
            ),
            RunStatus::Diverged { .. } => write!(
                f,
                "{}; last finite state written",
                self.divergence().unwrap_or_default()
            ),
            RunStatus::EnergyBelowZero { .. } => write!(
                f,
                "{}; that state written",
                self.divergence().unwrap_or_default()
            ),
            RunStatus::Interrupted { at_seconds } => {
                write!(f, "interrupted at t = {at_seconds:.4e} s (Ctrl-C or SIGTERM)")
            }
            RunStatus::NotStatic {
                steps,
                residual,
                tolerance,
                loads_still_changing: Some((settle, reached)),
            } => write!(
                f,
                "not static after {steps} steps: the loads change until t = {settle:.3e} s (the tool's path or a pressure ramp) and the run reached {reached:.3e} s; residual {residual:.3e}, tolerance {tolerance:.1e}"
            ),
            RunStatus::NotStatic {
                steps,
                residual,
                tolerance,
                loads_still_changing: None,
            } => write!(
                f,
                "not static after {steps} steps: residual {residual:.3e} > tolerance {tolerance:.1e}"
            ),
        }
    }
}

/// A status equals the text it is written as (`status == "ok"`).
impl PartialEq<&str> for RunStatus {
    fn eq(&self, other: &&str) -> bool {
        let text: &str = other;
        match self {
            RunStatus::Ok => text == "ok",
            _ => self.to_string().as_str() == text,
        }
    }
}

impl serde::Serialize for RunStatus {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.serialize_str(&self.to_string())
    }
}

/// Contents of `summary.json`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct RunSummary {
    /// Scene name.
    pub scene: String,
    /// `gpu` or `cpu` (the backend that ran; `auto` is resolved).
    pub backend: Backend,
    /// Why that backend (`--backend auto` says which adapter it found).
    pub backend_reason: String,
    /// Adapter (GPU) or CPU description.
    pub adapter: String,
    /// CPU threads of the CPU backend (1 for the GPU backend's host thread).
    pub threads: usize,
    /// Number of tets.
    pub tets: usize,
    /// Number of vertices.
    pub vertices: usize,
    /// Number of particles (0: this scene has none).
    pub particles: usize,
    /// Steps taken (in a haptic session that slept at rest, fewer than sim_seconds / dt: see
    /// `haptic.physics.slept_seconds`).
    pub steps: u64,
    /// Time step at the end of the run, s.
    pub dt: f64,
    /// Our stability bound, s.
    pub dt_bound: f64,
    /// The paper's eq. (14) bound, s; null where 2λ + μ ≤ 0 (ν ≤ −0.5, e.g. a split law
    /// with a bulk modulus below μ/6), whose "wave speed" sqrt((2λ+μ)/ρ) is not real.
    pub dt_paper_eq14: f64,
    /// How many times dt was halved after a divergence.
    pub dt_halvings: u32,
    /// Particle sub-steps per core step at the final dt: ⌈dt / (safety · particle bound)⌉
    /// (scenes with particles).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub particle_substeps: Option<u32>,
    /// The most particle sub-steps per core step the run used: above `particle_substeps`
    /// where the layer stiffened under the tool and the count was raised
    /// ([`crate::substeps`]), or where dt was halved since the start (`particle_substeps`
    /// is at the final dt); scenes whose particles carry stress.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub particle_substeps_max: Option<u32>,
    /// The largest stiffening κ = max(‖F‖², ‖cof F‖²)/3 of a stressed particle the run
    /// measured (1 at rest; [`crate::substeps::stiffening`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_particle_stiffening: Option<f32>,
    /// Mass scaling of the scene's `[solver]` (1: none).
    pub mass_scaling: f64,
    /// Simulated time, s.
    pub sim_seconds: f64,
    /// Wall-clock time of the stepping, s.
    pub wall_seconds: f64,
    /// Steps per wall-clock second.
    pub steps_per_second: f64,
    /// Simulated seconds per wall-clock second (≥ 1: faster than real time).
    pub realtime_factor: f64,
    /// Largest vertex displacement, m (the tet mesh's vertices).
    pub max_displacement: f64,
    /// Largest particle displacement, m (scenes with particles; under the tool it can be
    /// several times the vertices' largest).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_particle_displacement: Option<f64>,
    /// Kinetic energy at the end, J.
    pub kinetic_energy: f64,
    /// Elastic energy at the end, J.
    pub elastic_energy: f64,
    /// ‖residual force‖ / ‖external load‖ at the end (with `--until-static`; absent without).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub static_residual: Option<f64>,
    /// The tolerance `static_residual` was held to (with `--until-static`; absent without).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub static_tolerance: Option<f64>,
    /// Dynamic particles at the end (scenes with particles).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub active_particles: Option<u32>,
    /// The most dynamic particles at any batch end (scenes with particles).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub active_particles_max: Option<u32>,
    /// Tets that carry strain energy and are inverted (det F ≤ 0) at the end
    /// ([`crate::inversion`]).
    pub inverted_tets: usize,
    /// Particles that carry SPH stress and are inverted (det F ≤ 0) at the end (scenes with
    /// particles).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub inverted_particles: Option<usize>,
    /// The tool's centre at the end, m (scenes with a tool).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tool_position: Option<[f64; 3]>,
    /// The force the tissue exerts on the tool at the end, N (scenes with a tool).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tool_force: Option<[f64; 3]>,
    /// `ok`, or why the run stopped.
    pub status: RunStatus,
    /// The outputs that could not be written, each as its one-line error (empty when every
    /// one was; the run then fails naming them).
    pub output_errors: Vec<String>,
}

impl RunSummary {
    /// Write as pretty JSON to `dir/summary.json` (atomically).
    pub fn write(&self, dir: &Path) -> Result<()> {
        let json = serde_json::to_string_pretty(self)
            .map_err(|e| PalpateError::Usage(format!("summary.json: {e}")))?;
        write_atomic(&dir.join("summary.json"), json.as_bytes())
    }
}

#[cfg(test)]
mod tests {
    use super::RunStatus;

    /// A haptic session that ends while it still halves dt says that the state written is
    /// the one rolled back to (its step and the dt of the retry: summary.json's `steps` and
    /// `dt`), not the step that diverged.
    #[test]
    fn a_session_ended_while_recovering_names_the_state_it_wrote() {
        let diverged = |rolled_back_to| RunStatus::Diverged {
            step: 463,
            vertex: 12,
            n_vertices: 100,
            speed_limit: 3.2,
            wave_speeds: 10.0,
            dt: 1.441e-6,
            dt_bound: 1.476e-3,
            rolled_back_to,
        };
        let plain = diverged(None).to_string();
        assert!(
            plain.contains("at step 463, vertex 12 (dt = 1.441e-6 s")
                && plain.ends_with("; last finite state written"),
            "{plain}"
        );
        let ended = diverged(Some((246, 7.205e-7))).to_string();
        assert!(
            ended.contains("at step 463, vertex 12 (dt = 1.441e-6 s")
                && ended.ends_with(
                    "rolled back to step 246, to retry at dt = 7.205e-7 s; that state written"
                ),
            "{ended}"
        );
    }
}
