//! The `palpate run` job: step a scene for a number of steps, a duration, or until static,
//! under a divergence policy, and write `final.vtu`, `summary.json` and optional
//! `series.pvd` frames (the pieces live in [`crate::output`]).

use crate::error::{PalpateError, Result};
use crate::output::series::FrameSeries;
use crate::output::state::state_vtu;
pub use crate::output::summary::{RunStatus, RunSummary};
use crate::output::write_atomic;
use crate::scene::{Num, Scene};
use crate::sim::{Backend, DivergencePolicy, Guarded, SimOptions, Simulation};
use crate::stepper::BatchStats;
use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::Instant;

/// What to do when the state diverges (`--on-diverge`): non-finite, or faster than 10× the
/// P-wave speed.
pub type OnDiverge = DivergencePolicy;

/// How long to run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RunLength {
    /// Exactly this many steps (0 writes the initial state).
    Steps(u64),
    /// This much simulated time, s.
    Duration(f64),
    /// Until the residual is below the scene's static tolerance, at most this many steps.
    UntilStatic {
        /// Step cap.
        max_steps: u64,
    },
}

/// Options of a run.
#[derive(Clone)]
pub struct RunOptions {
    /// Backend (`auto` picks a hardware GPU, else the CPU).
    pub backend: Backend,
    /// CPU backend threads (None: all cores).
    pub threads: Option<usize>,
    /// Length.
    pub length: RunLength,
    /// dt override, s.
    pub dt: Option<f64>,
    /// Accept dt above the bound.
    pub allow_unstable: bool,
    /// Divergence policy.
    pub on_diverge: DivergencePolicy,
    /// Number of frames for `series.pvd` (0: none).
    pub frames: u32,
    /// Output directory.
    pub out: PathBuf,
    /// Show a progress bar (when stdout is a terminal and the run takes over a second).
    pub progress: bool,
    /// Steps per batch (one command buffer, one readback).
    pub batch: u32,
    /// Print a first line naming the scene, its size, the backend and why it was picked.
    pub announce: bool,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            backend: Backend::Auto,
            threads: None,
            length: RunLength::Steps(100),
            dt: None,
            allow_unstable: false,
            on_diverge: DivergencePolicy::Stop,
            frames: 0,
            out: PathBuf::from("out"),
            progress: false,
            batch: 200,
            announce: false,
        }
    }
}

/// Largest |u| over vertices, m.
pub fn max_displacement(displacements: &[f32]) -> f64 {
    displacements
        .chunks(3)
        .map(|u| u.iter().map(|&c| (c as f64).powi(2)).sum::<f64>().sqrt())
        .fold(0.0, f64::max)
}

struct Progress {
    bar: Option<indicatif::ProgressBar>,
    start: Instant,
}

impl Progress {
    fn new(enabled: bool, total: Option<u64>) -> Progress {
        let bar = enabled.then(|| {
            let b = indicatif::ProgressBar::with_draw_target(
                total,
                indicatif::ProgressDrawTarget::hidden(),
            );
            let style = indicatif::ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {wide_bar} {pos}/{len} steps {msg}",
            )
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar());
            b.set_style(style);
            b
        });
        Progress {
            bar,
            start: Instant::now(),
        }
    }
    fn update(&mut self, steps: u64, msg: String) {
        if let Some(b) = &self.bar {
            if b.is_hidden() && self.start.elapsed().as_secs_f64() > 1.0 {
                b.set_draw_target(indicatif::ProgressDrawTarget::stderr());
            }
            b.set_position(steps);
            b.set_message(msg);
        }
    }
    fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

/// The most steps one run may take (a guard against a dt that is absurdly small for the
/// requested duration).
pub const MAX_RUN_STEPS: u64 = 1 << 40;

/// Damping ratio that `--until-static` gives the highest mesh frequency through added
/// shear viscosity (see [`relaxation_scene`]).
pub const RELAXATION_HIGH_MODE_DAMPING: f64 = 0.6;

/// The scene used by `--until-static` (dynamic relaxation): the same scene with shear
/// viscosity raised to at least ψ_r = ζ(λ + 2μ)/ω_max, ω_max = 2c_p/h, so that the highest
/// mesh modes are damped at ζ = 0.6 (ζ = (φ + 2ψ)ω/(2(λ + 2μ)), see [`crate::timestep`]) and
/// f32 round-off cannot keep them ringing. Viscous
/// stress vanishes at rest, so the static solution is unchanged; the auto dt accounts for it.
pub fn relaxation_scene(scene: &Scene) -> Scene {
    let mut s = scene.clone();
    let m = &scene.material;
    let bounds =
        crate::timestep::TimeStepBounds::new(m, scene.mesh.min_altitude(), scene.mesh.min_edge());
    let omega_max = 2.0 * bounds.p_wave_speed / bounds.h_altitude;
    let psi = RELAXATION_HIGH_MODE_DAMPING * (m.lambda + 2.0 * m.mu) / omega_max;
    s.material.psi = m.psi.max(psi);
    s
}

/// `--duration t`: finite and ≥ 0, else a one-line usage error.
pub fn check_duration(t: f64) -> Result<()> {
    if t.is_finite() && t >= 0.0 {
        return Ok(());
    }
    let what = if t.is_infinite() { "finite and " } else { "" };
    Err(PalpateError::Usage(format!(
        "--duration must be {what}>= 0 s, got {}",
        crate::scene::Num(t)
    )))
}

/// Steps a run of `length` takes at time step `dt` (the step cap for `--until-static`); a
/// duration too long is named as `scene`'s `solver.duration` when it is that value, else as
/// `--duration`.
fn steps_for(length: RunLength, dt: f64, scene: &Scene) -> Result<u64> {
    let duration_named = |t: f64| match scene.solver.duration {
        Some(d) if d == t => format!("{}: solver.duration = {} s", scene.origin, Num(t)),
        _ => format!("--duration {}", Num(t)),
    };
    let n = match length {
        RunLength::Steps(n) => n,
        RunLength::Duration(t) => {
            check_duration(t)?;
            // Round up, but not past a whole number that f64 division missed by an ulp.
            let x = t / dt;
            if x > MAX_RUN_STEPS as f64 {
                return Err(PalpateError::Usage(format!(
                    "{} would take {x:.3e} steps of {dt:.3e} s (more than {MAX_RUN_STEPS}); use a larger --dt or a shorter run",
                    duration_named(t)
                )));
            }
            let n = if (x - x.round()).abs() < 1e-9 * x.max(1.0) {
                x.round() as u64
            } else {
                x.ceil() as u64
            };
            // A positive duration is at least one step, however short.
            if t > 0.0 {
                n.max(1)
            } else {
                n
            }
        }
        RunLength::UntilStatic { max_steps } => max_steps,
    };
    if n > MAX_RUN_STEPS {
        return Err(PalpateError::Usage(match length {
            RunLength::UntilStatic { .. } => {
                format!("--max-steps {n}: at most {MAX_RUN_STEPS} (2^40) steps")
            }
            RunLength::Steps(_) => format!("--steps {n}: at most {MAX_RUN_STEPS} (2^40) steps"),
            RunLength::Duration(t) => format!(
                "{} would take {n} steps of {dt:.3e} s (more than {MAX_RUN_STEPS}); use a larger --dt or a shorter run",
                duration_named(t)
            ),
        }));
    }
    Ok(n)
}

/// Dynamic relaxation for `--until-static`: after each batch, critical mass damping α = 2ω at
/// the Rayleigh-quotient frequency of the current displacement shape (unconditionally stable
/// in the v/(1 + α dt) form, when the scene sets no damping of its own), and the relative
/// residual ‖f‖/‖load‖.
struct Relaxation {
    adaptive: bool,
}

impl Relaxation {
    /// The relative residual after a batch, counting dynamic particles with the vertices
    /// (their residual force, their weight and the tool's contact force as load, their
    /// energy and Σ m|u|² in the Rayleigh quotient).
    fn after_batch(&self, sim: &mut Simulation, s: &BatchStats) -> Result<f64> {
        let mut mu2 = s.stats[crate::params::stat::MASS_DISPLACEMENT_SQ] as f64;
        if let (Some(p), Some(_)) = (sim.last_particles, sim.model.particles.as_ref()) {
            mu2 += p.mass_displacement_sq;
        }
        if self.adaptive && mu2 > 0.0 {
            let elastic = BodyEnergy::of(sim, s).elastic;
            sim.set_damping(2.0 * (2.0 * elastic / mu2).sqrt())?;
        }
        Ok(relative_residual(sim, s))
    }
}

/// The residual of the last batch `s` of `sim` relative to its load:
/// ‖f‖ / ‖m g + f_ext‖ over the free vertices and the dynamic particles (whose load also
/// counts the tool's force: without gravity or pressure it is the whole load). The
/// `--until-static` test; 0 for a body at rest under no load, and +∞-like (÷ the smallest
/// positive float) for a body moving under none.
pub fn relative_residual(sim: &Simulation, s: &BatchStats) -> f64 {
    let f = ResidualAndLoad::of(sim, s);
    f.residual / f.load.max(f64::MIN_POSITIVE)
}

/// The residual force of a batch and the load it is measured against, N.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ResidualAndLoad {
    /// ‖f‖₂ over the free vertices and the dynamic particles.
    pub residual: f64,
    /// ‖m g + f_ext‖₂ over the same, with the tool's force when there are particles.
    pub load: f64,
}

impl ResidualAndLoad {
    /// The residual and load of `sim`'s last batch `s`.
    pub fn of(sim: &Simulation, s: &BatchStats) -> ResidualAndLoad {
        let (mut residual2, mut load2) = (s.residual_norm().powi(2), s.external_norm().powi(2));
        if let (Some(p), Some(pd)) = (sim.last_particles, sim.model.particles.as_ref()) {
            residual2 += p.residual_norm.powi(2);
            let g = glam::DVec3::from_array(sim.model.gravity.map(|x| x as f64));
            load2 += p.dynamic as f64 * (pd.mass as f64 * g.length()).powi(2);
            // The tool's contact forces on particles are load too (the tets' reduction
            // counts those on vertices only): without gravity or pressure they are the
            // whole load, and the relative residual would divide by zero. The tool's total
            // force is their scale.
            if let Some(t) = sim.last_tool {
                load2 += t.force.length_squared();
            }
        }
        ResidualAndLoad {
            residual: residual2.sqrt(),
            load: load2.sqrt(),
        }
    }
}

/// The body's kinetic and elastic energy after a batch (vertices and dynamic particles), J.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BodyEnergy {
    /// ½ Σ m|v|², J.
    pub kinetic: f64,
    /// Strain energy (tets and SPH), J.
    pub elastic: f64,
}

impl BodyEnergy {
    /// The energies of `sim`'s last batch `s`.
    pub fn of(sim: &Simulation, s: &BatchStats) -> BodyEnergy {
        let (mut kinetic, mut elastic) = (s.kinetic_energy(), s.elastic_energy());
        if let (Some(p), Some(_)) = (sim.last_particles, sim.model.particles.as_ref()) {
            kinetic += p.kinetic_energy;
            elastic += p.elastic_energy;
        }
        BodyEnergy { kinetic, elastic }
    }
}

/// Run `scene` as `opts` says and write the outputs. Returns the summary (also written).
pub fn run(scene: &Scene, opts: &RunOptions) -> Result<RunSummary> {
    run_with_state(scene, opts).map(|(summary, _)| summary)
}

/// As [`run`], also returning the final state (benchmarks that read monitored points).
pub fn run_with_state(
    scene: &Scene,
    opts: &RunOptions,
) -> Result<(RunSummary, crate::stepper::State)> {
    crate::output::prepare_out_dir(&opts.out)?;
    crate::output::check_inputs_are_not_outputs(&opts.out, &scene.inputs().collect::<Vec<_>>())?;
    let until_static = matches!(opts.length, RunLength::UntilStatic { .. });
    let relaxed;
    let scene = if until_static {
        relaxed = relaxation_scene(scene);
        &relaxed
    } else {
        scene
    };
    let mut sim = Simulation::new(
        scene,
        opts.backend,
        SimOptions {
            dt: opts.dt,
            allow_unstable: opts.allow_unstable,
            dt_flags: true,
            gpu: None,
            threads: opts.threads,
            step_on_this_thread: false,
        },
    )?;
    let model = sim.model.clone();
    let dt0 = sim.dt;
    // Every refusal before an earlier run's outputs are removed: a run refused keeps them.
    let max_steps = steps_for(opts.length, dt0, scene)?;
    // Held until the outputs are written: a second job into this folder is refused.
    let _lock = crate::output::lock::OutLock::claim(&opts.out, "the run started")?;
    // Set up: a signal from now on stops after a batch and writes the outputs (before, it
    // ends the process with nothing written: no "stopping after the batch" note followed by
    // a refusal to start).
    crate::interrupt::setup_done();
    let removed = crate::output::remove_earlier_outputs(&opts.out)?;
    if opts.announce && removed > 0 {
        crate::say_err!(
            "note: removed {removed} output files of an earlier run from {}",
            opts.out.display()
        );
    }
    if opts.announce {
        crate::say!(
            "{}: {} tets, {} vertices{}; backend {} on {} ({})",
            scene.name,
            model.n_tets(),
            model.n_vertices(),
            model
                .particles
                .as_ref()
                .map(|p| format!(", {} particles", p.len()))
                .unwrap_or_default(),
            if sim.backend == Backend::Gpu {
                "gpu"
            } else {
                "cpu"
            },
            sim.backend_name(),
            sim.backend_reason
        );
    }
    if let (true, Some(t)) = (opts.announce, &model.tool) {
        let warning =
            crate::scene::longest_step_leg(t.tool.path.iter().copied(), dt0).and_then(|leg| {
                crate::scene::tunnelling_warning(
                    "tool.path moves the tool",
                    leg,
                    dt0,
                    t.tool.radius,
                )
            });
        if let Some(w) = warning {
            crate::say_err!("warning: {}: {w}", scene.origin);
        }
        let pressing = t.tool.fastest_pressing_leg(&scene.mesh);
        // Particles woken around the tool: its path's travel between two updates, on its
        // fastest leg into or within the tissue (in free space nothing needs waking).
        if let Some(ps) = scene.particles.as_ref().filter(|p| !p.all_active) {
            let interval = ps.activation_interval as f64 * dt0;
            let lag = pressing.and_then(|(speed, from, to)| {
                crate::scene::activation_lag_warning(
                    "tool.path presses the tool into the tissue",
                    speed,
                    speed * interval.min(to - from),
                    ps.activation_interval,
                    ps.activation_radius,
                )
            });
            if let Some(w) = lag {
                crate::say_err!("warning: {}: {w}", scene.origin);
            }
        }
        if let Some((speed, from, to)) = pressing {
            if speed > model.max_tool_speed() {
                crate::say_err!(
                    "warning: {}: tool.path moves the tool into or along the tissue at {speed:.3e} m/s from t = {} to {} s, faster than the {:.3e} m/s it can follow (half its shear wave speed, {:.3e} m/s at mass scaling {}): the tissue cannot move out of the tool's way and the layer under it can be crushed until the run diverges (a haptic session holds the tool to that speed); slow the press down",
                    scene.origin,
                    crate::scene::short_time(from),
                    crate::scene::short_time(to),
                    model.max_tool_speed(),
                    model.shear_wave_speed(),
                    scene.solver.mass_scaling,
                );
            }
        }
    }
    let mut target_steps = max_steps;
    // The run's simulated length; halve-dt keeps it (so --steps N may take more than N steps
    // after a halving), and frames are spaced evenly over it.
    let mut target_time = target_steps as f64 * dt0;
    let frame_dt = if opts.frames >= 2 {
        max_steps as f64 * dt0 / (opts.frames - 1) as f64
    } else {
        f64::INFINITY
    };
    if opts.announce && opts.frames as u64 > max_steps + 1 && opts.frames >= 2 {
        crate::say_err!(
            "warning: --frames {} is more than the run's {max_steps} steps make: a frame after each step ({} in all)",
            opts.frames,
            max_steps + 1
        );
    }
    let mut frames = FrameSeries::new(&opts.out);
    let mut output_errors = crate::output::OutputErrors::default();
    if opts.frames >= 2 {
        // The first frame too: one that cannot be written ends the series, not the run.
        let particles = sim.particle_state()?;
        output_errors.keep(frames.write(&model, &sim.state()?, particles.as_ref(), 0.0));
        if opts.announce {
            let count = (opts.frames as u64).min(max_steps + 1);
            if let Some(w) = series_size_warning(&opts.out, count) {
                crate::say_err!("{w}");
            }
        }
    }
    let show = opts.progress && std::io::stdout().is_terminal();
    let mut progress = Progress::new(show, (!until_static).then_some(target_steps));
    let tolerance = scene.solver.static_tolerance;
    let relaxation = Relaxation {
        adaptive: until_static && scene.solver.damping == 0.0,
    };
    // A moving tool keeps the body loaded in a changing way: static only after its path ends.
    // A ramped follower pressure likewise: static only once the ramp is complete.
    let loads_settle_at = model
        .tool
        .as_ref()
        .map_or(0.0, |t| t.tool.path_end())
        .max(model.follower.as_ref().map_or(0.0, |f| f.ramp_seconds));
    let is_static =
        |r: Option<f64>, time: f64| time >= loads_settle_at && r.is_some_and(|r| r <= tolerance);
    if opts.announce && until_static && (max_steps as f64) * dt0 < loads_settle_at {
        crate::say_err!(
            "warning: --max-steps {max_steps} at dt = {dt0:.3e} s ends at t = {:.3e} s, before the loads settle at t = {loads_settle_at:.3e} s (the tool's path or a pressure ramp): the run cannot become static; raise --max-steps",
            max_steps as f64 * dt0,
        );
    }
    let mut status = RunStatus::Ok;
    let energy_floor = energy_floor(&model);
    let mut residual = None;
    let start = Instant::now();
    let mut next_frame_time = frame_dt;
    let mut long_run_noted = false;
    if until_static && target_steps > 0 {
        // Residual of the initial state: a body already in equilibrium stops at once.
        if let Guarded::Done(s) = sim.advance_with(1, DivergencePolicy::Stop)? {
            residual = Some(relaxation.after_batch(&mut sim, &s)?);
        }
    }
    while sim.steps_done < target_steps {
        if until_static && is_static(residual, sim.time) {
            break;
        }
        if crate::interrupt::requested() {
            status = RunStatus::Interrupted {
                at_seconds: sim.time,
            };
            break;
        }
        let mut batch = (target_steps - sim.steps_done).min(opts.batch.max(1) as u64);
        // Batches end at frame times, except under --until-static, whose relaxation acts
        // after each batch: there frames go at the batch ends they fall in, so that writing
        // them leaves the physics as it is without.
        if next_frame_time.is_finite() && !until_static {
            let to_frame = ((next_frame_time - sim.time) / sim.dt - 1e-6)
                .ceil()
                .max(1.0);
            batch = batch.min(to_frame as u64);
        }
        // And at the next check of the particle sub-steps, while particles are dynamic
        // (not under --until-static, whose relaxation acts per batch: its count is checked
        // at each batch's end).
        if let Some(check) = sim.substep_batch_limit().filter(|_| !until_static) {
            batch = batch.min(check as u64);
        }
        match sim.advance_with(batch as u32, opts.on_diverge)? {
            Guarded::Done(s) => {
                if let Some(floor) = energy_floor {
                    let elastic = BodyEnergy::of(&sim, &s).elastic;
                    if elastic < floor {
                        status = RunStatus::EnergyBelowZero {
                            step: sim.steps_done,
                            elastic,
                        };
                        break;
                    }
                }
                if until_static {
                    residual = Some(relaxation.after_batch(&mut sim, &s)?);
                }
            }
            Guarded::Retry { dt, step, vertex } => {
                let remaining = (target_time - sim.time).max(0.0);
                target_steps = sim.steps_done + (remaining / dt).ceil() as u64;
                target_time = sim.time + remaining;
                let what = diverged_status(&sim, step, vertex, 2.0 * dt);
                crate::say_err!(
                    "warning: {}; retrying from step {} at dt = {dt:.3e} s",
                    what.divergence().unwrap_or_default(),
                    sim.steps_done
                );
                continue;
            }
            Guarded::Diverged { step, vertex } => {
                status = diverged_status(&sim, step, vertex, sim.dt);
                break;
            }
        }
        if sim.time >= next_frame_time - 0.5 * sim.dt {
            // A frame that cannot be written ends the series, not the run: its final state
            // and summary are still written, then the error is returned.
            if output_errors.is_empty() {
                let particles = sim.particle_state()?;
                output_errors.keep(frames.write(
                    &model,
                    &sim.state()?,
                    particles.as_ref(),
                    sim.time,
                ));
            }
            while next_frame_time <= sim.time + 0.5 * sim.dt {
                next_frame_time += frame_dt;
            }
        }
        if opts.announce && !long_run_noted && !until_static {
            long_run_noted =
                note_a_long_run(start.elapsed().as_secs_f64(), sim.steps_done, target_steps);
        }
        progress.update(
            sim.steps_done,
            residual
                .map(|r| format!("residual {r:.2e}"))
                .unwrap_or_default(),
        );
    }
    progress.finish();
    let wall = start.elapsed().as_secs_f64();
    if until_static && status.is_ok() && !is_static(residual, sim.time) {
        status = RunStatus::NotStatic {
            steps: sim.steps_done,
            residual: residual.unwrap_or(f64::NAN),
            tolerance,
            loads_still_changing: (sim.time < loads_settle_at)
                .then_some((loads_settle_at, sim.time)),
        };
    }
    let state = sim.state()?;
    let particles = sim.particle_state()?;
    // The final state closes the series (with --frames 1 it is the only frame).
    let final_missing = frames.last_time().is_none_or(|t| t < sim.time);
    // Every output is tried even after one fails (a full disk may still take the small
    // summary.json, which lists the failures); the run's error names them all.
    let series_ok = output_errors.is_empty();
    let mut keep = |r| output_errors.keep(r);
    if series_ok && (opts.frames == 1 || (opts.frames >= 2 && final_missing)) {
        keep(frames.write(&model, &state, particles.as_ref(), sim.time));
    }
    keep(write_atomic(
        &opts.out.join("final.vtu"),
        state_vtu(&model, &state).as_bytes(),
    ));
    if let Some(snap) = &particles {
        keep(write_atomic(
            &opts.out.join("particles_final.vtu"),
            crate::output::particles::particles_vtu(&model, &state, snap).as_bytes(),
        ));
    }
    keep(frames.finish());
    // (A frame that could not be written ended the series: that error says so.)
    if opts.announce
        && until_static
        && series_ok
        && opts.frames >= 2
        && frames.len() < opts.frames as usize
    {
        crate::say_err!(
            "warning: --frames {} wrote {}: under --until-static a frame goes at the end of the relaxation batch (up to {} steps) its time falls in, so frames closer than a batch share one{}",
            opts.frames,
            frames.len(),
            opts.batch.max(1),
            if sim.steps_done < max_steps {
                format!(
                    ", and the run ended after {} of its --max-steps {max_steps} steps",
                    sim.steps_done
                )
            } else {
                String::new()
            }
        );
    }
    let mut summary = summarize(
        scene,
        &sim,
        &state,
        particles.as_ref(),
        wall,
        status,
        until_static.then_some((residual, tolerance)),
    );
    summary.output_errors = output_errors.messages();
    output_errors.keep(summary.write(&opts.out));
    output_errors.into_result().map(|()| (summary, state))
}

/// The summary of a finished run of `sim` (its final `state` and `particles`, `wall`
/// seconds); `statics` is (residual, tolerance) for `--until-static`.
pub fn summarize(
    scene: &Scene,
    sim: &Simulation,
    state: &crate::stepper::State,
    particles: Option<&crate::stepper::ParticleSnapshot>,
    wall: f64,
    status: RunStatus,
    statics: Option<(Option<f64>, f64)>,
) -> RunSummary {
    let model = &sim.model;
    let inverted = crate::inversion::inverted(model, state, particles);
    RunSummary {
        scene: scene.name.clone(),
        backend: sim.backend,
        backend_reason: sim.backend_reason.clone(),
        adapter: sim.backend_name(),
        threads: sim.threads,
        tets: model.n_tets(),
        vertices: model.n_vertices(),
        particles: model.particles.as_ref().map_or(0, |p| p.len()),
        steps: sim.steps_done,
        dt: sim.dt,
        dt_bound: model.bounds.dt_bound,
        dt_paper_eq14: model.bounds.dt_paper_eq14,
        dt_halvings: sim.halvings,
        particle_substeps: model
            .particles
            .as_ref()
            .map(|_| model.particle_substeps(sim.dt)),
        particle_substeps_max: sim.particle_substeps().map(|(_, most)| most),
        max_particle_stiffening: sim.max_particle_stiffening(),
        mass_scaling: scene.solver.mass_scaling,
        sim_seconds: sim.time,
        wall_seconds: wall,
        steps_per_second: sim.steps_done as f64 / wall.max(1e-9),
        realtime_factor: sim.time / wall.max(1e-9),
        max_displacement: max_displacement(&state.displacements),
        // Every particle's, an embedded one's as its host moves it (its own stored state is
        // current only while it is dynamic), as particles_final.vtu has it.
        max_particle_displacement: particles.map(|p| {
            max_displacement(&crate::output::particles::particle_displacements(
                model, state, p,
            ))
        }),
        kinetic_energy: sim.last.kinetic_energy()
            + sim.last_particles.map_or(0.0, |p| p.kinetic_energy),
        elastic_energy: sim.last.elastic_energy()
            + sim.last_particles.map_or(0.0, |p| p.elastic_energy),
        static_residual: statics.and_then(|(r, _)| r),
        static_tolerance: statics.map(|(_, t)| t),
        active_particles: model
            .particles
            .as_ref()
            .map(|_| sim.last_particles.map_or(0, |p| p.dynamic)),
        active_particles_max: model.particles.as_ref().map(|_| sim.active_particles_max),
        inverted_tets: inverted.tets,
        inverted_particles: model.particles.as_ref().map(|_| inverted.particles),
        tool_position: model.tool.as_ref().map(|_| sim.tool_position.to_array()),
        tool_force: model
            .tool
            .as_ref()
            .map(|_| sim.last_tool.map_or([0.0; 3], |t| t.force.to_array())),
        status,
        output_errors: Vec::new(),
    }
}

/// Bytes of frames above which a run with `--frames` says how much it will write.
const LARGE_SERIES_BYTES: f64 = 1.0e9;

/// A warning when `count` frames the size of the first one written in `dir`
/// (`frame_0000.vtu` and, with particles, `particles_frame_0000.vtu`) would come to more than
/// [`LARGE_SERIES_BYTES`]: a million frames of a small scene filled 1.3 GB in 5 s unannounced.
fn series_size_warning(dir: &std::path::Path, count: u64) -> Option<String> {
    let size = |name: &str| std::fs::metadata(dir.join(name)).map_or(0, |m| m.len());
    let frame = size("frame_0000.vtu") + size("particles_frame_0000.vtu");
    let total = frame as f64 * count as f64;
    (total > LARGE_SERIES_BYTES).then(|| {
        format!(
            "warning: --frames {count} will write about {:.1} GB to {} ({:.0} kB a frame; fewer frames write less)",
            total / 1e9,
            dir.display(),
            frame as f64 / 1e3
        )
    })
}

/// Under design 8 (`coupling = "exact"`), the strain energy below which a run stops as
/// [`RunStatus::EnergyBelowZero`]: minus that of a uniform strain of 1e-4 over the body,
/// ½ (λ + 2μ) ε² V, far beyond rounding at rest yet far above a runaway (−5e-2 J on a 2 cm box
/// whose threshold is −2.6e-8 J). None for other scenes, whose energies are sums of Ψ ≥ 0.
pub(crate) fn energy_floor(model: &crate::model::Model) -> Option<f64> {
    let exact = model
        .particles
        .as_ref()
        .is_some_and(|p| p.settings.exact_coupling);
    exact.then(|| {
        let volume: f64 = model.rest_volume.iter().map(|&v| v as f64).sum();
        let modulus = model.material.lambda + 2.0 * model.material.mu;
        -0.5 * modulus.abs() * 1e-8 * volume
    })
}

pub(crate) fn diverged_status(sim: &Simulation, step: u64, vertex: u32, dt: f64) -> RunStatus {
    let m = &sim.model;
    RunStatus::Diverged {
        step,
        vertex,
        n_vertices: m.n_vertices() as u32,
        speed_limit: crate::model::SPEED_LIMIT_WAVE_SPEEDS * m.material.p_wave_speed(),
        wave_speeds: crate::model::SPEED_LIMIT_WAVE_SPEEDS,
        dt,
        dt_bound: m.bounds.dt_bound,
        rolled_back_to: None,
    }
}

/// Wall seconds after which a run estimates how long it will take.
const ESTIMATE_AFTER_SECONDS: f64 = 1.0;

/// Estimated run lengths, s, from which a run says how long it will take.
const LONG_RUN_SECONDS: f64 = 600.0;

/// Once `wall` s of stepping have done `done` of `target` steps (at least
/// [`ESTIMATE_AFTER_SECONDS`]), say on standard error how long the rest will take when that
/// is over [`LONG_RUN_SECONDS`] (a `--steps 1e12` typo runs for years, silently where stdout
/// is no terminal). True once the estimate has been made, said or not.
fn note_a_long_run(wall: f64, done: u64, target: u64) -> bool {
    if wall < ESTIMATE_AFTER_SECONDS || done == 0 {
        return false;
    }
    let rate = done as f64 / wall;
    let rest = target.saturating_sub(done) as f64 / rate;
    if rest > LONG_RUN_SECONDS {
        crate::say_err!(
            "note: at {rate:.0} steps/s the {target} steps will take about {} more; Ctrl-C stops the run and writes its outputs",
            human_duration(rest)
        );
    }
    true
}

/// `seconds` in the largest fitting unit, e.g. "2.3 h" or "3.2e4 years".
fn human_duration(seconds: f64) -> String {
    const UNITS: [(f64, &str); 4] = [
        (86400.0 * 365.25, "years"),
        (86400.0, "days"),
        (3600.0, "h"),
        (60.0, "min"),
    ];
    match UNITS.iter().find(|(s, _)| seconds >= *s) {
        Some((s, unit)) if seconds / s < 1e4 => format!("{:.1} {unit}", seconds / s),
        Some((s, unit)) => format!("{:.1e} {unit}", seconds / s),
        None => format!("{seconds:.0} s"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A series whose frames add up to more than a gigabyte is announced with its size; a
    /// smaller one, or a folder with no first frame, is not.
    #[test]
    fn a_large_frame_series_says_how_much_it_will_write() {
        let dir = std::env::temp_dir().join(format!("palpate-series-size-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        assert_eq!(series_size_warning(&dir, 1_000_000), None);
        std::fs::write(dir.join("frame_0000.vtu"), vec![b' '; 100_000]).unwrap();
        std::fs::write(dir.join("particles_frame_0000.vtu"), vec![b' '; 50_000]).unwrap();
        let w = series_size_warning(&dir, 10_000).unwrap();
        assert!(
            w.starts_with("warning: --frames 10000 will write about 1.5 GB to ")
                && w.contains("(150 kB a frame"),
            "{w}"
        );
        assert_eq!(series_size_warning(&dir, 6_000), None);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn durations_read_in_the_largest_unit() {
        assert_eq!(human_duration(30.0), "30 s");
        assert_eq!(human_duration(5400.0), "1.5 h");
        assert_eq!(human_duration(3.0 * 86400.0), "3.0 days");
        assert_eq!(human_duration(1e12), "3.2e4 years");
    }
}
