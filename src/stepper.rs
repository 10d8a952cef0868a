//! The interface both backends implement: queue batches of steps and collect their reports
//! without blocking, checkpoint and restore, read and write the state.
//!
//! A backend is `Send`, so a physics thread can own it while a 1 kHz servo thread runs
//! beside it. `submit` queues a batch; `poll` returns the report of the oldest finished
//! batch, if any, without waiting; `wait` blocks for it. Up to [`RING`] batches can be in
//! flight, so the next batch is queued before the last one is read back.

use crate::error::Result;
use crate::params::{stat, StepParams};

/// Batches that can be in flight at once (readback ring slots).
pub const RING: usize = 3;

/// Displacements and velocities, packed xyz, f32.
#[derive(Debug, Default, PartialEq)]
pub struct State {
    /// Displacements u = x − X from the rest positions, m.
    pub displacements: Vec<f32>,
    /// Velocities, m/s.
    pub velocities: Vec<f32>,
}

impl Clone for State {
    fn clone(&self) -> Self {
        State {
            displacements: self.displacements.clone(),
            velocities: self.velocities.clone(),
        }
    }

    /// Copies into the existing buffers (no allocation when the sizes match).
    fn clone_from(&mut self, source: &Self) {
        self.displacements.clone_from(&source.displacements);
        self.velocities.clone_from(&source.velocities);
    }
}

/// The particles' state as read back: displacements and velocities (embedded particles as of
/// their last `follow`), modes, and the blend offsets and timers of releasing particles.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ParticleSnapshot {
    /// Displacements u_p, packed xyz, m.
    pub displacements: Vec<f32>,
    /// Velocities, packed xyz, m/s: a dynamic particle's own; an embedded one's as `follow`
    /// last set it (its host's; particles of the force set, viscous material), else as it
    /// was when it last stopped being dynamic (zero if it never was).
    pub velocities: Vec<f32>,
    /// Mode bits ([`crate::particles::params::mode`]).
    pub modes: Vec<u32>,
    /// Blend offsets, packed xyz, m.
    pub offsets: Vec<f32>,
    /// Dwell or blend timers, s.
    pub timers: Vec<f32>,
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
    /// Lowest vertex whose position or velocity became non-finite or too fast, if any;
    /// n_vertices + p for particle p.
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

/// Per-batch input, separate from the per-run parameters ([`StepParams`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BatchInput {
    /// The tool's centre at the batch start and at its end, m (it moves linearly in
    /// between). None: it stays where the last batch left it.
    pub tool: Option<(glam::DVec3, glam::DVec3)>,
    /// `Some((first, of))`: the batch runs steps `first..first + steps` of a move of `of`
    /// steps from `tool.0` to `tool.1` (a diverged batch replayed one step at a time, with
    /// the batch's own tool positions and velocity, bit for bit). None: the whole move.
    pub tool_slice: Option<(u32, u32)>,
}

impl BatchInput {
    /// A batch that moves the tool from `from` to `to`.
    pub fn moving(from: glam::DVec3, to: glam::DVec3) -> BatchInput {
        BatchInput {
            tool: Some((from, to)),
            tool_slice: None,
        }
    }

    /// The tool's input and its state before the batch's first step, for a batch of `steps`
    /// steps, and where the tool is after it; `at` is where the last batch left it.
    pub fn tool_plan(
        &self,
        steps: u32,
        at: glam::DVec3,
    ) -> (
        crate::contact::ToolInput,
        crate::contact::ToolState,
        glam::DVec3,
    ) {
        let (from, to) = self.tool.unwrap_or((at, at));
        let (first, of) = self.tool_slice.unwrap_or((0, steps));
        let input = crate::contact::batch_input(from, to, of);
        // The position tool_motion gives step `first` (what the state holds before it runs).
        let state = crate::contact::ToolState {
            position: crate::cpu::tool_motion::tool_at_step(&input, first).to_array(),
            step: first,
        };
        let after = self.tool_after(steps).unwrap_or(at);
        (input, state, after)
    }

    /// Where the tool is after a batch of `steps` steps (None: it does not move).
    pub fn tool_after(&self, steps: u32) -> Option<glam::DVec3> {
        let (from, to) = self.tool?;
        Some(match self.tool_slice {
            Some((first, of)) if first + steps < of => {
                from + (to - from) * ((first + steps) as f64 / of as f64)
            }
            _ => to,
        })
    }
}

/// What the `tool_force` stage reports at the end of a batch.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ToolReport {
    /// The tool's centre at the batch end, m.
    pub position: glam::DVec3,
    /// Force the tissue exerts on the tool, N.
    pub force: glam::DVec3,
    /// Frozen-tissue stiffness ∂F/∂(tool position), N/m (see [`crate::contact`]).
    pub stiffness: glam::DMat3,
    /// Largest penetration of a surface vertex into the sphere, m.
    pub max_penetration: f64,
    /// Surface vertices in contact.
    pub contacts: u32,
    /// Their rest surface area, m².
    pub contact_area: f64,
}

impl ToolReport {
    /// Parse the `tool_report` floats (see [`crate::contact::report`]).
    pub fn from_floats(position: glam::DVec3, r: &[f32]) -> ToolReport {
        use crate::contact::report::*;
        let v = |k: usize| glam::DVec3::new(r[k] as f64, r[k + 1] as f64, r[k + 2] as f64);
        ToolReport {
            position,
            force: v(FORCE),
            stiffness: glam::DMat3::from_cols(v(STIFFNESS), v(STIFFNESS + 3), v(STIFFNESS + 6)),
            max_penetration: r[MAX_PENETRATION] as f64,
            contacts: r[CONTACTS] as u32,
            contact_area: r[AREA] as f64,
        }
    }
}

/// What the particle stages report at the end of a batch.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ParticleReport {
    /// Dynamic particles (as of the last activation update).
    pub dynamic: u32,
    /// Particles carrying SPH stress.
    pub stress: u32,
    /// Particles receiving SPH force.
    pub force: u32,
    /// Kinetic energy of the dynamic particles, J.
    pub kinetic_energy: f64,
    /// SPH strain energy, J.
    pub elastic_energy: f64,
    /// Largest dynamic-particle speed, m/s.
    pub max_speed: f64,
    /// ‖f‖₂ over dynamic particles, N.
    pub residual_norm: f64,
    /// Σ m|u|² over dynamic particles, kg·m².
    pub mass_displacement_sq: f64,
    /// The largest stiffening κ of a particle carrying stress
    /// ([`crate::substeps::stiffening`]; 1 where none does).
    pub max_stiffening: f64,
}

impl ParticleReport {
    /// From `particle_counts` (4 u32) and `particle_stats` (6 f32 used).
    pub fn from_parts(counts: &[u32], stats: &[f32]) -> ParticleReport {
        ParticleReport {
            dynamic: counts[0],
            stress: counts[1],
            force: counts[2],
            kinetic_energy: stats[0] as f64,
            elastic_energy: stats[1] as f64,
            max_speed: stats[2] as f64,
            residual_norm: (stats[3] as f64).sqrt(),
            mass_displacement_sq: stats[4] as f64,
            max_stiffening: (stats[5] as f64).max(1.0),
        }
    }
}

/// The report of one finished batch.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BatchReport {
    /// Steps the batch ran.
    pub steps: u32,
    /// Reduction stats and divergence flag after its last step.
    pub stats: BatchStats,
    /// The tool's force and stiffness (scenes with a tool).
    pub tool: Option<ToolReport>,
    /// The particles' counts and diagnostics (scenes with particles).
    pub particles: Option<ParticleReport>,
}

/// A backend that advances the model.
pub trait Stepper: Send {
    /// Human-readable backend / adapter name.
    fn name(&self) -> String;
    /// Set the per-run parameters used by the following batches.
    fn set_params(&mut self, params: &StepParams) -> Result<()>;
    /// Set the follower pressures' ramp factor s ∈ [0, 1] used by the following batches
    /// (the steppers start at the model's value at t = 0; no-op without follower pressures).
    fn set_load_factor(&mut self, _load_factor: f32) -> Result<()> {
        Ok(())
    }
    /// Queue a batch of `steps` steps (reduce after the last) with this batch's input.
    /// At most [`RING`] batches may be in flight; a further submit is an error.
    fn submit(&mut self, steps: u32, input: &BatchInput) -> Result<()>;
    /// The report of the oldest finished batch, without waiting; None when none is ready.
    fn poll(&mut self) -> Result<Option<BatchReport>>;
    /// Wait for the oldest batch in flight and return its report (an error when none is).
    fn wait(&mut self) -> Result<BatchReport>;
    /// Batches submitted and not yet returned by `poll`/`wait`.
    fn in_flight(&self) -> usize;
    /// Save the current state (after every batch in flight) as the checkpoint: the vertices'
    /// and particles' state, what the last activation left (lists, weights, flags), the step
    /// count and where the tool is. Not the parameters (dt) or the follower load factor.
    fn checkpoint(&mut self) -> Result<()>;
    /// Go back to the last checkpoint (before the first, the state at rest the stepper was
    /// built with: step 0, the tool at its start). Drops the batches in flight and zeroes the
    /// stats. With the same inputs, the run from there repeats the saved run bit for bit.
    fn restore(&mut self) -> Result<()>;
    /// Read the current state (waits for the batches in flight).
    fn read_state(&mut self) -> Result<State>;
    /// Overwrite the current state (and reset the stats).
    fn write_state(&mut self, state: &State) -> Result<()>;
    /// Per stage, how many times it ran in the last batch (the executed step plan).
    fn stage_counts(&self) -> Vec<(crate::plan::Stage, u32)>;
    /// The particles' state (see [`ParticleSnapshot`]), or None without particles; waits
    /// for the batches in flight.
    fn read_particle_state(&mut self) -> Result<Option<ParticleSnapshot>> {
        Ok(None)
    }

    /// Run the particle stages `substeps` times per core step from the next batch on, each
    /// a sub-step of dt/substeps ([`crate::substeps`]); nothing to do without particles.
    /// Batches already submitted keep the count they were recorded with.
    fn set_particle_substeps(&mut self, _substeps: u32) -> Result<()> {
        Ok(())
    }

    /// Run `steps` steps with no per-batch input and wait for the stats.
    fn run(&mut self, steps: u32) -> Result<BatchStats> {
        self.submit(steps, &BatchInput::default())?;
        Ok(self.wait()?.stats)
    }
}
