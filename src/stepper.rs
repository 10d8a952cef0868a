//! The interface both backends implement: run a batch of steps, snapshot and restore, read
//! and write the state.

use crate::error::Result;
use crate::params::{stat, StepParams};

/// Positions and velocities, packed xyz, f32.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct State {
    /// Deformed positions, m.
    pub positions: Vec<f32>,
    /// Velocities, m/s.
    pub velocities: Vec<f32>,
}

/// What a batch reports: the `reduce` stats after its last step and the divergence flag.
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
    /// ‖m g‖₂ over free vertices, N.
    pub fn external_norm(&self) -> f64 {
        (self.stats[stat::EXTERNAL_SQ] as f64).sqrt()
    }
}

/// A backend that advances the model.
pub trait Stepper {
    /// Human-readable backend / adapter name.
    fn name(&self) -> String;
    /// Set the parameters used by the following batches.
    fn set_params(&mut self, params: &StepParams) -> Result<()>;
    /// Snapshot the state, run `steps` steps, reduce (after every step when kinetic damping
    /// is on, else after the last), and report.
    fn run(&mut self, steps: u32) -> Result<BatchStats>;
    /// Restore the state saved at the start of the last `run`.
    fn restore(&mut self) -> Result<()>;
    /// Read the current state.
    fn read_state(&mut self) -> Result<State>;
    /// Overwrite the current state (and reset the kinetic-damping memory).
    fn write_state(&mut self, state: &State) -> Result<()>;
}
