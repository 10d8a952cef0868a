//! The public simulation object: a scene's model on a backend, its time step, and `advance`
//! with divergence detection (the last finite state is kept and the failing step located).

use crate::cpu::CpuStepper;
use crate::error::{PalpateError, Result};
use crate::gpu::{GpuContext, GpuStepper};
use crate::model::Model;
use crate::scene::Scene;
use crate::stepper::{BatchStats, State, Stepper};
use std::sync::Arc;

/// Which backend steps the model.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    /// WGSL compute kernels through wgpu.
    Gpu,
    /// The CPU reference twins.
    Cpu,
}

/// Options for [`Simulation::new`].
#[derive(Clone, Default)]
pub struct SimOptions {
    /// A time step that overrides the scene's, s.
    pub dt: Option<f64>,
    /// Accept a dt above the stability bound.
    pub allow_unstable: bool,
    /// A GPU context to reuse (else one is opened for the GPU backend).
    pub gpu: Option<Arc<GpuContext>>,
}

/// Outcome of [`Simulation::advance`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Advance {
    /// All steps ran; the stats after the last one.
    Done(BatchStats),
    /// A non-finite value appeared at `step` (1-based, counted from the start of the run) at
    /// `vertex`; the state is the last finite one, after step − 1.
    Diverged {
        /// The step that produced the non-finite value.
        step: u64,
        /// Lowest vertex index that became non-finite.
        vertex: u32,
    },
}

/// A running simulation.
pub struct Simulation {
    /// The model being stepped.
    pub model: Arc<Model>,
    stepper: Box<dyn Stepper>,
    /// Time step, s.
    pub dt: f64,
    /// Mass-proportional damping α, 1/s.
    pub damping: f64,
    /// Steps taken so far.
    pub steps_done: u64,
    /// Simulated time so far, s.
    pub time: f64,
    /// Stats of the last batch.
    pub last: BatchStats,
    /// State, step count and time at the start of the batch that last diverged.
    checkpoint: Option<(State, u64, f64)>,
}

/// The time step a scene runs at: `override_dt`, else the scene's dt, else safety × bound.
/// A given dt above the bound is refused unless `allow_unstable`.
pub fn choose_dt(
    scene: &Scene,
    model: &Model,
    override_dt: Option<f64>,
    allow_unstable: bool,
) -> Result<f64> {
    let bound = model.bounds.dt_bound;
    match override_dt.or(scene.solver.dt) {
        None => Ok(scene.solver.safety * bound),
        Some(dt) if !(dt.is_finite() && dt > 0.0) => {
            Err(PalpateError::Usage(format!("--dt must be > 0 s, got {dt}")))
        }
        Some(dt) if dt > bound && !allow_unstable => Err(PalpateError::UnstableTimeStep {
            dt,
            bound,
            detail: model.bounds.describe(),
        }),
        Some(dt) => Ok(dt),
    }
}

impl Simulation {
    /// Build a simulation of `scene` on `backend`.
    pub fn new(scene: &Scene, backend: Backend, opts: SimOptions) -> Result<Simulation> {
        let model = Arc::new(Model::from_scene(scene));
        model
            .check_f32()
            .map_err(|e| PalpateError::Usage(format!("{}: {e}", scene.origin)))?;
        let dt = choose_dt(scene, &model, opts.dt, opts.allow_unstable)?;
        Simulation::from_model(model, backend, dt, scene.solver.damping, opts)
    }

    /// Build from a prepared model and a time step.
    pub fn from_model(
        model: Arc<Model>,
        backend: Backend,
        dt: f64,
        damping: f64,
        opts: SimOptions,
    ) -> Result<Simulation> {
        model.check_f32()?;
        if !(dt as f32 > 0.0 && (dt as f32).is_finite()) {
            return Err(PalpateError::Usage(format!(
                "dt = {dt:e} s is not a positive single-precision number"
            )));
        }
        let params = model.step_params(dt, damping);
        let stepper: Box<dyn Stepper> = match backend {
            Backend::Cpu => Box::new(CpuStepper::new(model.clone(), params)),
            Backend::Gpu => {
                let ctx = match opts.gpu {
                    Some(c) => c,
                    None => Arc::new(GpuContext::new()?),
                };
                Box::new(GpuStepper::new(ctx, &model, params)?)
            }
        };
        Ok(Simulation {
            model,
            stepper,
            dt,
            damping,
            steps_done: 0,
            time: 0.0,
            last: BatchStats::default(),
            checkpoint: None,
        })
    }

    /// Backend / adapter name.
    pub fn backend_name(&self) -> String {
        self.stepper.name()
    }

    /// Change the time step (e.g. after a divergence).
    pub fn set_dt(&mut self, dt: f64) -> Result<()> {
        self.dt = dt;
        self.stepper
            .set_params(&self.model.step_params(dt, self.damping))
    }

    /// Change the mass-proportional damping α, 1/s.
    pub fn set_damping(&mut self, damping: f64) -> Result<()> {
        self.damping = damping;
        self.stepper
            .set_params(&self.model.step_params(self.dt, damping))
    }

    /// Run `steps` steps in one batch. When a vertex becomes non-finite or exceeds the speed
    /// limit, roll back to the batch start (kept as a checkpoint, see
    /// [`Simulation::rollback_to_checkpoint`]) and replay one step at a time to find the
    /// failing step; the state is left at the last step before it.
    pub fn advance(&mut self, steps: u32) -> Result<Advance> {
        if steps == 0 {
            return Ok(Advance::Done(self.last));
        }
        let stats = self.stepper.run(steps)?;
        if stats.non_finite_vertex.is_none() {
            self.steps_done += steps as u64;
            self.time += steps as f64 * self.dt;
            self.last = stats;
            return Ok(Advance::Done(stats));
        }
        self.stepper.restore()?;
        self.checkpoint = Some((self.stepper.read_state()?, self.steps_done, self.time));
        for _ in 0..steps {
            let one = self.stepper.run(1)?;
            if let Some(vertex) = one.non_finite_vertex {
                self.stepper.restore()?;
                return Ok(Advance::Diverged {
                    step: self.steps_done + 1,
                    vertex,
                });
            }
            self.steps_done += 1;
            self.time += self.dt;
            self.last = one;
        }
        // The replay did not diverge (cannot happen on a deterministic backend).
        Ok(Advance::Done(self.last))
    }

    /// Go back to the start of the batch that last diverged (before the instability grew).
    /// Returns false when there is no checkpoint.
    pub fn rollback_to_checkpoint(&mut self) -> Result<bool> {
        match self.checkpoint.take() {
            Some((state, steps, time)) => {
                self.stepper.write_state(&state)?;
                self.steps_done = steps;
                self.time = time;
                Ok(true)
            }
            None => Ok(false),
        }
    }

    /// Current displacements and velocities.
    pub fn state(&mut self) -> Result<State> {
        self.stepper.read_state()
    }

    /// Overwrite displacements and velocities.
    pub fn set_state(&mut self, state: &State) -> Result<()> {
        self.stepper.write_state(state)
    }
}
