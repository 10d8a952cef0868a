//! The interface both backends implement: run a batch of steps, snapshot and restore, read
//! and write the state.

use crate::error::Result;
use crate::params::{stat, StepParams};

/// Displacements and velocities, packed xyz, f32.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct State {
    /// Displacements u = x − X from the rest positions, m.
    pub displacements: Vec<f32>,
    /// Velocities, m/s.
    pub velocities: Vec<f32>,
}

/// What a batch reports: the `reduce` stats after its last step and the divergence flag.
///
/// Time levels: kinetic energy, max speed and Σ m|u|² are of the state after the last step;
/// elastic energy and the residual force were computed by that step's `fem_forces`/`gather`,
/// i.e. for the state one step earlier. At the step sizes used this is a difference of
/// O(dt·v); summaries report them as "at the end".
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BatchStats {
    /// The stats buffer (see [`crate::params::stat`]).
    pub stats: [f32; stat::LEN],
    /// Lowest vertex whose position or velocity became non-finite, if any.
    pub non_finite_vertex: Option<u32>,
}

impl BatchStats {
    /// Kinetic energy, J.
    pub fn kinetic_energy(&self) -> f64 {
        self.stats[stat::KINETIC] as f64
    }
    /// Elastic energy, J.
    pub fn elastic_energy(&self) -> f64 {
        self.stats[stat::ELASTIC] as f64
    }
    /// Largest vertex speed, m/s.
    pub fn max_speed(&self) -> f64 {
        self.stats[stat::MAX_SPEED] as f64
    }
    /// ‖f‖₂ over free vertices, N.
    pub fn residual_norm(&self) -> f64 {
        (self.stats[stat::RESIDUAL_SQ] as f64).sqrt()
    }
    /// ‖m g + f_ext‖₂ over free vertices (gravity and surface pressures), N.
    pub fn external_norm(&self) -> f64 {
        (self.stats[stat::EXTERNAL_SQ] as f64).sqrt()
    }
    /// Rayleigh-quotient estimate of the frequency of the current displacement shape,
    /// ω = sqrt(2·elastic / Σ m|u|²), rad/s; None at rest.
    pub fn displacement_frequency(&self) -> Option<f64> {
        let m = self.stats[stat::MASS_DISPLACEMENT_SQ] as f64;
        (m > 0.0).then(|| (2.0 * self.elastic_energy() / m).sqrt())
    }
}

/// A backend that advances the model.
pub trait Stepper {
    /// Human-readable backend / adapter name.
    fn name(&self) -> String;
    /// Set the parameters used by the following batches.
    fn set_params(&mut self, params: &StepParams) -> Result<()>;
    /// Snapshot the state, run `steps` steps, reduce after the last, and report.
    fn run(&mut self, steps: u32) -> Result<BatchStats>;
    /// Restore the state saved at the start of the last `run`.
    fn restore(&mut self) -> Result<()>;
    /// Read the current state.
    fn read_state(&mut self) -> Result<State>;
    /// Overwrite the current state.
    fn write_state(&mut self, state: &State) -> Result<()>;
}
