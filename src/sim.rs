//! The public simulation object: a scene's model on a backend, its time step, and `advance`
//! with divergence detection (the last finite state is kept and the failing step located),
//! plus the one place where the divergence policy (stop, or halve dt and retry) lives.

use crate::cpu::CpuStepper;
use crate::error::{PalpateError, Result};
use crate::gpu::{GpuContext, GpuStepper};
use crate::model::Model;
use crate::plan::Stage;
use crate::scene::Scene;
use crate::stepper::{BatchInput, BatchStats, State, Stepper, ToolReport};
use glam::DVec3;
use std::sync::Arc;

/// Which backend steps the model.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    /// A hardware GPU when there is one, else the CPU backend (a software adapter is slower
    /// than the CPU path on the same cores).
    Auto,
    /// WGSL compute kernels through wgpu, on any adapter (software ones included).
    Gpu,
    /// The CPU twins of the kernels, on all cores by default (one fewer for `haptic`; the
    /// reference path).
    Cpu,
}

/// The backend `auto` picks on this machine among the adapters `PALPATE_ADAPTER` allows,
/// with the reason in words, and the hardware adapter it found (None: the CPU backend).
/// A `PALPATE_BACKEND` that names no backend is an error, not a quiet fall back to the CPU.
pub fn pick_auto() -> Result<(Backend, String, Option<wgpu::Adapter>)> {
    let filter = crate::gpu::context::adapter_filter()
        .map(|a| format!(" matching PALPATE_ADAPTER='{a}'"))
        .unwrap_or_default();
    Ok(match crate::gpu::context::allowed_adapters() {
        Err(e @ PalpateError::Usage(_)) => return Err(e),
        Err(e) => (Backend::Cpu, format!("auto: {e}"), None),
        Ok(adapters) => {
            let hardware = adapters
                .iter()
                .position(|a| a.get_info().device_type != wgpu::DeviceType::Cpu);
            match hardware {
                Some(k) => {
                    let a = adapters.into_iter().nth(k).expect("index from position");
                    let i = a.get_info();
                    (
                        Backend::Gpu,
                        format!("auto: hardware GPU '{}' ({:?})", i.name, i.backend),
                        Some(a),
                    )
                }
                None => match adapters.first() {
                    Some(a) => {
                        let i = a.get_info();
                        (
                            Backend::Cpu,
                            format!(
                                "auto: no hardware GPU{filter}; the only adapter, '{}' ({:?}), is a software rasteriser, slower than the CPU path on the same cores",
                                i.name, i.backend
                            ),
                            None,
                        )
                    }
                    None => (
                        Backend::Cpu,
                        format!("auto: no GPU adapter{filter} found"),
                        None,
                    ),
                },
            }
        }
    })
}

/// Particle layers from which [`Simulation::new`] says that their setup takes a while.
pub const LARGE_PARTICLE_LAYER: f64 = 1e6;

/// The note [`Simulation::new`] prints on standard error before a particle layer of over
/// [`LARGE_PARTICLE_LAYER`] particles is built (sampling, neighbour lists and corrections:
/// about 8 s per million on 2 cores at kernel_radius 1.95 and 13 s at 2.4 on the CPU
/// backend, measured 2026-11-28), so a long silent setup is not taken for a hang.
pub fn large_particle_layer_note(scene: &Scene) -> Option<String> {
    let p = scene.particles.as_ref()?;
    let n = crate::scene::particles::estimated_count(&scene.mesh, p);
    (n > LARGE_PARTICLE_LAYER).then(|| {
        format!(
            "note: {}: building about {n:.2e} particles and their neighbour lists (seconds per million)",
            scene.origin
        )
    })
}

/// The error of `--threads` with `--backend gpu`.
fn threads_on_gpu() -> PalpateError {
    PalpateError::Usage(
        "--threads sets the CPU backend's threads; it does not apply to --backend gpu".into(),
    )
}

/// Options for [`Simulation::new`].
#[derive(Clone, Default)]
pub struct SimOptions {
    /// A time step that overrides the scene's, s.
    pub dt: Option<f64>,
    /// Accept a dt above the stability bound.
    pub allow_unstable: bool,
    /// The command takes `--dt` and `--allow-unstable` (`palpate run`), which the advice of a
    /// dt above the bound then names; else it names only the scene's `solver.dt`.
    pub dt_flags: bool,
    /// A GPU context to reuse (else one is opened for the GPU backend).
    pub gpu: Option<Arc<GpuContext>>,
    /// CPU backend threads (None: all cores).
    pub threads: Option<usize>,
    /// With the CPU backend on one thread: run the stages on the thread that creates the
    /// simulation ([`crate::cpu::stepper::this_thread_pool`]), with no pool worker beside
    /// it, for a caller that also steps it there (a haptic session's physics thread, which
    /// then leaves the other core to the servo). Stepping from another thread still works.
    pub step_on_this_thread: bool,
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

/// What to do when a batch diverges.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum DivergencePolicy {
    /// Stop, keeping the last finite state.
    Stop,
    /// Roll back to the start of the batch and retry at half the step, at most 10 times over
    /// a run
    // (MAX_HALVINGS, Simulation::max_halvings: the line above is `run --help`'s, plain text.)
    HalveDt,
}

// `run --help` says 10 (DivergencePolicy::HalveDt's doc).
const _: () = assert!(MAX_HALVINGS == 10);

/// The most times `halve-dt` halves the step over one run.
pub const MAX_HALVINGS: u32 = 10;

/// Outcome of [`Simulation::advance_with`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Guarded {
    /// All steps ran.
    Done(BatchStats),
    /// The batch diverged; the state is back at the batch start and dt was halved to `dt`:
    /// advance again (the caller recomputes how many steps its remaining time needs).
    Retry {
        /// The new time step, s.
        dt: f64,
        /// Where the divergence was found.
        step: u64,
        /// The vertex that diverged.
        vertex: u32,
    },
    /// The batch diverged and the policy gives up; the state is the last finite one.
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
    /// The backend that runs (never `Auto`).
    pub backend: Backend,
    /// Why this backend was picked.
    pub backend_reason: String,
    /// CPU threads (1 for the GPU backend, whose host side is one thread).
    pub threads: usize,
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
    /// Times dt was halved by [`DivergencePolicy::HalveDt`].
    pub halvings: u32,
    /// The most halvings [`DivergencePolicy::HalveDt`] may make over the run (default
    /// [`MAX_HALVINGS`]).
    pub max_halvings: u32,
    /// The tool's centre now (after the last batch), m.
    pub tool_position: DVec3,
    /// Where the next batches move the tool (None: along the scene's path).
    pub tool_target: Option<DVec3>,
    /// The tool report of the last batch (scenes with a tool).
    pub last_tool: Option<ToolReport>,
    /// The particle report of the last batch (scenes with particles).
    pub last_particles: Option<crate::stepper::ParticleReport>,
    /// The most dynamic particles any batch ended with.
    pub active_particles_max: u32,
    /// The start of the batch that diverged in the last [`Simulation::advance`] (the
    /// stepper's checkpoint holds its state).
    checkpoint: Option<BatchStart>,
    /// The particle sub-step count, adapted to the layer's stiffening (None where the
    /// particles carry no stress of their own).
    substeps: Option<crate::substeps::SubstepControl>,
}

/// What [`Simulation`] tracks beside the stepper's state, as it was at a batch start.
#[derive(Clone, Copy, Debug)]
struct BatchStart {
    steps_done: u64,
    time: f64,
    tool_position: DVec3,
    last: BatchStats,
    last_tool: Option<ToolReport>,
    last_particles: Option<crate::stepper::ParticleReport>,
    active_particles_max: u32,
}

/// The time step a scene runs at: `override_dt`, else the scene's dt, else safety × bound.
/// A given dt above the bound is refused unless `allow_unstable`, with advice that names
/// `--dt` and `--allow-unstable` where the command has them (`dt_flags`).
pub fn choose_dt(
    scene: &Scene,
    model: &Model,
    override_dt: Option<f64>,
    allow_unstable: bool,
    dt_flags: bool,
) -> Result<f64> {
    let bound = model.bounds.dt_bound;
    match override_dt.or(scene.solver.dt) {
        None => Ok(scene.solver.safety * bound),
        Some(dt) if !(dt.is_finite() && dt > 0.0) => Err(PalpateError::Usage(format!(
            "{} must be > 0 s, got {}",
            dt_source(scene, override_dt),
            crate::scene::Num(dt)
        ))),
        Some(dt) if dt > bound && !allow_unstable => Err(PalpateError::UnstableTimeStep {
            given: match override_dt {
                Some(_) => format!("{}: --dt", scene.origin),
                None => format!("{}: solver.dt", scene.origin),
            },
            dt,
            bound,
            detail: model.bounds.describe(),
            advice: if dt_flags {
                "use a smaller --dt or dt = \"auto\" (`palpate run --allow-unstable` runs it anyway)"
            } else {
                "use a smaller solver.dt or dt = \"auto\" in the scene"
            },
        }),
        Some(dt) => Ok(dt),
    }
}

/// The lowest real stability limit `palpate bench stability` measured, as a fraction of the
/// bound (the built-in beam's mesh: 0.8945 × `dt_bound`; the LV's 1.16–1.28).
pub const MEASURED_LIMIT_FRACTION: f64 = 0.89;

/// A warning for a dt above [`MEASURED_LIMIT_FRACTION`] × `bound` (accepted up to the bound,
/// or above it with `--allow-unstable`): such a step diverged on the built-in beam.
pub fn near_bound_warning(
    scene: &Scene,
    dt: f64,
    bound: f64,
    override_dt: Option<f64>,
) -> Option<String> {
    (dt > MEASURED_LIMIT_FRACTION * bound).then(|| {
        format!(
            "{} = {dt:.4e} s is {:.3} × the stability bound {bound:.4e} s; `palpate bench stability` measured the real limit as low as {MEASURED_LIMIT_FRACTION} × it (on the built-in beam), so the run may diverge (solver.safety = 0.5, the default, keeps a margin)",
            dt_source(scene, override_dt),
            dt / bound
        )
    })
}

/// Where a run's dt comes from, as the user wrote it: `--dt`, `solver.dt`, or the automatic
/// step (`solver.safety` × the stable bound of the material and mesh).
fn dt_source(scene: &Scene, override_dt: Option<f64>) -> &'static str {
    if override_dt.is_some() {
        "--dt"
    } else if scene.solver.dt.is_some() {
        "solver.dt"
    } else {
        "the automatic dt (solver.safety × the stable bound of the material's density and moduli and the mesh)"
    }
}

impl Simulation {
    /// Build a simulation of `scene` on `backend`.
    pub fn new(scene: &Scene, backend: Backend, opts: SimOptions) -> Result<Simulation> {
        // A mesh too big for this machine's memory to build and step is refused before the
        // model is built (an allocation failure aborts with nothing written).
        if let Some(why) = crate::cpu::memory::tets_over_available_memory(
            scene.mesh.tets.len() as f64,
            // The mesh is in memory already: what building and running adds.
            crate::cpu::memory::RUN_BYTES_PER_TET - crate::cpu::memory::MESH_BYTES_PER_TET,
            "build and run",
        ) {
            return Err(PalpateError::SceneValue {
                origin: scene.origin.clone(),
                item: "mesh".into(),
                message: why,
            });
        }
        // On the CPU backend, a particle layer too big for this machine is refused from the
        // scene's estimate before minutes of sampling (and after it, from the count).
        if let (Backend::Cpu, Some(p), Some(free)) = (
            backend,
            scene.particles.as_ref(),
            crate::cpu::memory::available_memory(),
        ) {
            let n = crate::scene::particles::estimated_count(&scene.mesh, p);
            crate::cpu::memory::check_particles_fit(n, true, p, free, &scene.origin)?;
        }
        // On --backend gpu, one far too big for the adapter likewise (its context opened here
        // and handed on; `auto` choosing a GPU is checked only after sampling, exactly).
        if backend == Backend::Gpu && opts.threads.is_some() {
            return Err(threads_on_gpu());
        }
        let mut opts = opts;
        if let (Backend::Gpu, Some(p)) = (backend, scene.particles.as_ref()) {
            let ctx = match opts.gpu.take() {
                Some(c) => c,
                None => Arc::new(GpuContext::new()?),
            };
            let n = crate::scene::particles::estimated_count(&scene.mesh, p);
            crate::gpu::buffers::check_particle_estimate(&ctx, n, p)?;
            opts.gpu = Some(ctx);
        }
        if let Some(note) = large_particle_layer_note(scene) {
            crate::say_err!("{note}");
        }
        let model = Arc::new(Model::try_from_scene(scene)?);
        model
            .check_f32()
            .map_err(|e| PalpateError::Usage(format!("{}: {e}", scene.origin)))?;
        let dt = choose_dt(scene, &model, opts.dt, opts.allow_unstable, opts.dt_flags)?;
        if !is_normal_f32_step(dt) {
            return Err(PalpateError::Usage(format!(
                "{}: {} = {dt:e} s {}",
                scene.origin,
                dt_source(scene, opts.dt),
                f32_step_problem(dt)
            )));
        }
        if let Some(w) = near_bound_warning(scene, dt, model.bounds.dt_bound, opts.dt) {
            crate::say_err!("warning: {}: {w}", scene.origin);
        }
        Simulation::from_model_of(
            model,
            backend,
            dt,
            scene.solver.damping,
            opts,
            &scene.origin,
        )
    }

    /// Build from a prepared model and a time step.
    pub fn from_model(
        model: Arc<Model>,
        backend: Backend,
        dt: f64,
        damping: f64,
        opts: SimOptions,
    ) -> Result<Simulation> {
        Simulation::from_model_of(model, backend, dt, damping, opts, "the model")
    }

    /// [`Simulation::from_model`], its errors naming `origin` (the scene).
    fn from_model_of(
        model: Arc<Model>,
        backend: Backend,
        dt: f64,
        damping: f64,
        opts: SimOptions,
        origin: &str,
    ) -> Result<Simulation> {
        model.check_f32()?;
        if !is_normal_f32_step(dt) {
            return Err(PalpateError::Usage(format!(
                "dt = {dt:e} s {}",
                f32_step_problem(dt)
            )));
        }
        let params = model.step_params(dt, damping);
        if backend == Backend::Gpu && opts.threads.is_some() {
            return Err(threads_on_gpu());
        }
        let (backend, backend_reason, adapter) = match backend {
            Backend::Auto if crate::gpu::stepper::exact_activates_on_cpu(&model) => (
                Backend::Cpu,
                "auto: particles.coupling = \"exact\" under the tool re-slaves on the CPU at every activation (--backend gpu runs its steps on the GPU with that round trip)".to_string(),
                None,
            ),
            Backend::Auto if opts.gpu.is_some() => (
                Backend::Gpu,
                "auto: the GPU context given".to_string(),
                None,
            ),
            Backend::Auto => pick_auto()?,
            Backend::Gpu => (Backend::Gpu, "--backend gpu".to_string(), None),
            Backend::Cpu => (Backend::Cpu, "--backend cpu".to_string(), None),
        };
        // Refused above with --backend gpu; `auto` choosing a GPU says it goes unused.
        let backend_reason = match (backend, opts.threads) {
            (Backend::Gpu, Some(t)) => {
                format!("{backend_reason}; --threads {t} is for the CPU backend: unused")
            }
            _ => backend_reason,
        };
        let (stepper, threads): (Box<dyn Stepper>, usize) = match backend {
            Backend::Gpu => {
                let ctx = match (opts.gpu, adapter) {
                    (Some(c), _) => c,
                    (None, Some(a)) => Arc::new(GpuContext::from_adapter(a)?),
                    (None, None) => Arc::new(GpuContext::new()?),
                };
                (Box::new(GpuStepper::new(ctx, &model, params)?), 1)
            }
            _ => {
                if let (Some(p), Some(free)) = (
                    model.particles.as_ref(),
                    crate::cpu::memory::available_memory(),
                ) {
                    let n = (p.rest.len() / 3) as f64;
                    crate::cpu::memory::check_particles_fit(n, false, &p.settings, free, origin)?;
                }
                let threads = opts
                    .threads
                    .unwrap_or_else(crate::cpu::stepper::available_cores);
                let stepper = if threads == 1 && opts.step_on_this_thread {
                    CpuStepper::on_this_thread(model.clone(), params)?
                } else {
                    CpuStepper::with_threads(model.clone(), params, threads)?
                };
                (Box::new(stepper), threads)
            }
        };
        Ok(Simulation {
            model: model.clone(),
            stepper,
            backend,
            backend_reason,
            threads,
            dt,
            damping,
            steps_done: 0,
            time: 0.0,
            last: BatchStats::default(),
            halvings: 0,
            max_halvings: MAX_HALVINGS,
            tool_position: model
                .tool
                .as_ref()
                .map_or(DVec3::ZERO, |t| t.tool.position_at(0.0)),
            tool_target: None,
            last_tool: None,
            last_particles: None,
            active_particles_max: 0,
            checkpoint: None,
            substeps: crate::substeps::SubstepControl::new(&model, model.particle_substeps(dt)),
        })
    }

    /// Backend / adapter name.
    pub fn backend_name(&self) -> String {
        self.stepper.name()
    }

    /// Per stage, how many times it ran in the last batch.
    pub fn stage_counts(&self) -> Vec<(Stage, u32)> {
        self.stepper.stage_counts()
    }

    /// Change the time step (e.g. after a divergence).
    pub fn set_dt(&mut self, dt: f64) -> Result<()> {
        if !is_normal_f32_step(dt) {
            return Err(PalpateError::Usage(format!(
                "dt = {dt:e} s {}",
                f32_step_problem(dt)
            )));
        }
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

    /// The input of a batch of `steps` steps from now: the tool moves from where it is to
    /// the target, or along the scene's path.
    fn batch_input(&self, steps: u32) -> BatchInput {
        match &self.model.tool {
            None => BatchInput::default(),
            Some(t) => {
                let to = self
                    .tool_target
                    .unwrap_or_else(|| t.tool.position_at(self.time + steps as f64 * self.dt));
                BatchInput::moving(self.tool_position, to)
            }
        }
    }

    /// Run one batch with this input and the follower ramp at `load_time` (the batch's
    /// mid-time: constant over the batch), and wait for its report.
    fn run_batch_with(
        &mut self,
        steps: u32,
        input: &BatchInput,
        load_time: f64,
    ) -> Result<crate::stepper::BatchReport> {
        if let Some(f) = &self.model.follower {
            self.stepper.set_load_factor(f.load_factor(load_time))?;
        }
        self.stepper.submit(steps, input)?;
        let report = self.stepper.wait()?;
        if report.stats.non_finite_vertex.is_none() {
            if let Some(to) = input.tool_after(steps) {
                self.tool_position = to;
            }
            if report.tool.is_some() {
                self.last_tool = report.tool;
            }
            if let Some(p) = report.particles {
                self.active_particles_max = self.active_particles_max.max(p.dynamic);
                self.last_particles = Some(p);
            }
        }
        Ok(report)
    }

    /// Run `steps` steps in one batch. The state at the batch start is checkpointed; when a
    /// vertex becomes non-finite or exceeds the speed limit, go back to it and replay the
    /// batch one step at a time (the batch's own tool positions and velocity, and its follower
    /// load) to find
    /// the failing step, then go back again and redo the steps before it (the backends are
    /// deterministic): the state is left at the last step before it, and the batch start
    /// stays the checkpoint for [`Simulation::rollback_to_checkpoint`] until the next advance.
    /// A batch that crosses a keyframe of the scene's tool path runs in parts that end at
    /// it (the tool moves linearly within a batch); the checkpoint is then the start of the
    /// part that diverged.
    /// A restore brings back the particles, their activation's lists and the step count with
    /// the vertices, so the replay activates on the same steps as the batch.
    pub fn advance(&mut self, steps: u32) -> Result<Advance> {
        self.advance_inner(steps, true)
    }

    fn batch_start(&self) -> BatchStart {
        BatchStart {
            steps_done: self.steps_done,
            time: self.time,
            tool_position: self.tool_position,
            last: self.last,
            last_tool: self.last_tool,
            last_particles: self.last_particles,
            active_particles_max: self.active_particles_max,
        }
    }

    fn go_back_to(&mut self, start: BatchStart) -> Result<()> {
        self.stepper.restore()?;
        self.steps_done = start.steps_done;
        self.time = start.time;
        self.tool_position = start.tool_position;
        self.last = start.last;
        self.last_tool = start.last_tool;
        self.last_particles = start.last_particles;
        self.active_particles_max = start.active_particles_max;
        Ok(())
    }

    /// [`Simulation::advance`]; without `redo` a divergence leaves the state at the batch
    /// start (for a caller that rolls back at once). A batch moves the tool linearly, so one
    /// that would cross a corner of the scene's tool path (a keyframe) runs in parts that
    /// end at it ([`Simulation::steps_to_path_corner`]); a divergence in a later part leaves
    /// that part's start as the checkpoint.
    fn advance_inner(&mut self, steps: u32, redo: bool) -> Result<Advance> {
        let mut left = steps;
        loop {
            let part = self.steps_to_path_corner(left);
            left -= part;
            match self.advance_piece(part, redo)? {
                Advance::Done(_) if left > 0 => continue,
                outcome => return Ok(outcome),
            }
        }
    }

    /// Steps from now to the first of the scene tool path's keyframes strictly inside the
    /// next `steps` steps (by more than 1e-6 step: `time`'s rounding drift is no corner; to
    /// the last step boundary at or before it; 1 when it falls inside the next step, which
    /// then runs alone), else `steps`; always `steps` while
    /// [`Simulation::tool_target`] drives the tool. Every batch then starts and ends on the
    /// path, and the tool moves between steps as one-step batches move it.
    fn steps_to_path_corner(&self, steps: u32) -> u32 {
        let Some(t) = self
            .model
            .tool
            .as_ref()
            .filter(|_| self.tool_target.is_none())
        else {
            return steps;
        };
        let end = self.time + steps as f64 * self.dt;
        t.tool
            .path
            .iter()
            .map(|(tk, _)| *tk)
            .find(|tk| *tk > self.time + 1e-6 * self.dt && *tk < end - 1e-6 * self.dt)
            .map_or(steps, |tk| {
                (((tk - self.time) / self.dt + 1e-6).floor() as u32).clamp(1, steps)
            })
    }

    /// One batch of [`Simulation::advance_inner`], the tool moving linearly over it.
    fn advance_piece(&mut self, steps: u32, redo: bool) -> Result<Advance> {
        self.checkpoint = None;
        if steps == 0 {
            return Ok(Advance::Done(self.last));
        }
        self.stepper.checkpoint()?;
        let start = self.batch_start();
        let input = self.batch_input(steps);
        let load_time = self.time + 0.5 * steps as f64 * self.dt;
        let stats = self.run_batch_with(steps, &input, load_time)?.stats;
        if stats.non_finite_vertex.is_none() {
            self.steps_done += steps as u64;
            self.time += steps as f64 * self.dt;
            self.last = stats;
            self.adapt_particle_substeps(steps)?;
            return Ok(Advance::Done(stats));
        }
        // Step k of the batch alone: the batch's own tool input, from its step k.
        let one = |k: u32| BatchInput {
            tool_slice: input.tool.map(|_| (k, steps)),
            ..input
        };
        self.go_back_to(start)?;
        let mut good = 0;
        let vertex = loop {
            if good == steps {
                // The replay did not diverge (it repeats the batch's inputs exactly, so only a
                // backend that does not repeat itself gets here): its state is finite.
                return Ok(Advance::Done(self.last));
            }
            let stats = self.run_batch_with(1, &one(good), load_time)?.stats;
            if let Some(vertex) = stats.non_finite_vertex {
                break vertex;
            }
            self.steps_done += 1;
            self.time += self.dt;
            self.last = stats;
            good += 1;
        };
        self.go_back_to(start)?;
        self.checkpoint = Some(start);
        if redo {
            for k in 0..good {
                let stats = self.run_batch_with(1, &one(k), load_time)?.stats;
                if let Some(vertex) = stats.non_finite_vertex {
                    // The backend did not repeat itself (a bug: both are deterministic). No
                    // state after step start + k is kept, so this is not a divergence report.
                    self.go_back_to(start)?;
                    return Err(PalpateError::Internal(format!(
                        "redoing step {} of a diverged batch diverged (at {}) where its replay had not: the backend did not repeat itself; the state is back at step {}",
                        start.steps_done + k as u64 + 1,
                        crate::output::summary::flagged_point(
                            vertex,
                            self.model.n_vertices() as u32
                        ),
                        start.steps_done
                    )));
                }
                self.steps_done += 1;
                self.time += self.dt;
                self.last = stats;
            }
        }
        Ok(Advance::Diverged {
            step: start.steps_done + good as u64 + 1,
            vertex,
        })
    }

    /// [`Simulation::advance`] under a divergence policy: with `HalveDt` (and fewer than
    /// `max_halvings` halvings so far) a divergence rolls back to the batch start and
    /// halves dt, and the caller advances again.
    pub fn advance_with(&mut self, steps: u32, policy: DivergencePolicy) -> Result<Guarded> {
        let will_halve = policy == DivergencePolicy::HalveDt && self.halvings < self.max_halvings;
        match self.advance_inner(steps, !will_halve)? {
            Advance::Done(s) => Ok(Guarded::Done(s)),
            Advance::Diverged { step, vertex } => {
                if policy == DivergencePolicy::HalveDt && self.halvings < self.max_halvings {
                    self.halvings += 1;
                    self.rollback_to_checkpoint()?;
                    let dt = self.dt / 2.0;
                    self.set_dt(dt)?;
                    Ok(Guarded::Retry { dt, step, vertex })
                } else {
                    Ok(Guarded::Diverged { step, vertex })
                }
            }
        }
    }

    /// Whether the last batch ended with any particle dynamic (before the first batch:
    /// perhaps, as a tool may start in the activation radius).
    fn any_dynamic(&self) -> bool {
        self.last_particles.is_none_or(|p| p.dynamic > 0)
    }

    /// After `steps` finite steps: when a check is due ([`crate::substeps`]), measure the
    /// stressed particles' stiffening κ and set the particle sub-steps the stiffened bound
    /// asks for (at once when more; after a calm spell when fewer).
    fn adapt_particle_substeps(&mut self, steps: u32) -> Result<()> {
        let dynamic = self.any_dynamic();
        let stiffening = match dynamic {
            true => self.particle_stiffening() as f32,
            false => 1.0,
        };
        let Some(c) = &mut self.substeps else {
            return Ok(());
        };
        if !c.step(steps, dynamic, c.needed(self.dt, 1.0)) {
            return Ok(());
        }
        let needed = c.needed(self.dt, stiffening as f64);
        if let Some(n) = c.decide(needed, stiffening) {
            self.stepper.set_particle_substeps(n)?;
        }
        Ok(())
    }

    /// The longest batch to take so that the particle sub-step count follows the layer's
    /// stiffening (a check runs at the end of a batch, however long): while the count is
    /// watched, [`crate::substeps::CHECK_STEPS`]; before, what keeps the
    /// scene's tool path from carrying the tool far past the particles it wakes; None
    /// without a limit. A driver that runs long batches ends one there.
    pub fn substep_batch_limit(&self) -> Option<u32> {
        let c = self.substeps.as_ref()?;
        if c.watching(self.any_dynamic(), c.needed(self.dt, 1.0)) {
            return Some(crate::substeps::CHECK_STEPS);
        }
        // Not watched: while no particle is dynamic, a batch on the scene's path moves the
        // tool at most half the activation radius, so that the first particles it wakes are
        // still that far from it at the batch's end, where the watch begins (a 200-step
        // batch pressed up to 19 mm past them at 95 mm/s on lv_touch, and diverged). At the
        // speed of the path's leg now, to the leg's end (the next batch takes the next's).
        let p = self.model.particles.as_ref()?;
        let t = self
            .model
            .tool
            .as_ref()
            .filter(|_| self.tool_target.is_none())?;
        let speed = t.tool.leg_speed_at(self.time + 1e-6 * self.dt);
        let on_leg = match speed > 0.0 {
            true => (0.5 * p.settings.activation_radius / (speed * self.dt))
                .floor()
                .clamp(1.0, u32::MAX as f64) as u32,
            false => u32::MAX,
        };
        let limit = on_leg.min(self.steps_to_path_corner(u32::MAX));
        (limit < u32::MAX).then_some(limit)
    }

    /// Run the particle stages `substeps` times per core step from now on (at least 1, at
    /// most [`crate::model::MAX_PARTICLE_SUBSTEPS`]) and stop adapting the count to the
    /// layer's stiffening: for comparisons and tests (what a fixed count does).
    pub fn fix_particle_substeps(&mut self, substeps: u32) -> Result<()> {
        self.substeps = None;
        self.stepper.set_particle_substeps(substeps)
    }

    /// The largest stiffening κ of the particles that carried stress at the end of the last
    /// batch (its [`crate::stepper::ParticleReport::max_stiffening`]; 1 without particles).
    pub fn particle_stiffening(&self) -> f64 {
        self.last_particles.map_or(1.0, |p| p.max_stiffening)
    }

    /// The particle sub-steps per core step now, and the most the run has used (None
    /// without a particle layer that carries stress).
    pub fn particle_substeps(&self) -> Option<(u32, u32)> {
        self.substeps.as_ref().map(|c| (c.current, c.most))
    }

    /// The largest stiffening κ of the stressed particles measured so far (1 at rest;
    /// None without a particle layer that carries stress).
    pub fn max_particle_stiffening(&self) -> Option<f32> {
        self.substeps.as_ref().map(|c| c.max_stiffening)
    }

    /// Go back to the start of the batch that diverged in the last [`Simulation::advance`]
    /// (before the instability grew): vertices, particles, the step count and the last
    /// reports. Returns false when the last advance did not diverge.
    pub fn rollback_to_checkpoint(&mut self) -> Result<bool> {
        match self.checkpoint.take() {
            Some(start) => {
                self.go_back_to(start)?;
                Ok(true)
            }
            None => Ok(false),
        }
    }

    /// The particles' state (None without particles).
    pub fn particle_state(&mut self) -> Result<Option<crate::stepper::ParticleSnapshot>> {
        self.stepper.read_particle_state()
    }

    /// The tool's contact after the last batch: the force of the tissue on the tool, its
    /// frozen stiffness, penetration and contact count (None without a tool or before the
    /// first batch).
    pub fn contact(&self) -> Option<ToolReport> {
        self.last_tool
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

/// What is wrong with a step `dt` that [`is_normal_f32_step`] refuses: too large for f32, or
/// not a positive normal f32.
fn f32_step_problem(dt: f64) -> &'static str {
    if dt.is_finite() && dt > f32::MAX as f64 {
        "does not fit single precision (at most 3.4e38)"
    } else {
        "is not a positive single-precision number (at least 1.18e-38: GPUs flush smaller ones to zero)"
    }
}

/// Whether `dt` is a positive, finite, normal single-precision number (a subnormal step
/// is flushed to zero by GPUs and slows every CPU multiply that meets it).
fn is_normal_f32_step(dt: f64) -> bool {
    let d = dt as f32;
    d.is_finite() && d >= f32::MIN_POSITIVE
}
