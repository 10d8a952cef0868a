//! The `palpate run` job: step a scene for a number of steps, a duration, or until static;
//! handle divergence; write `final.vtu`, `summary.json` and optional `series.pvd` frames.

use crate::error::{PalpateError, Result};
use crate::model::Model;
use crate::output::{self, vtu};
use crate::scene::Scene;
use crate::sim::{Advance, Backend, SimOptions, Simulation};
use crate::stepper::State;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Instant;

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

/// What to do when the state becomes non-finite.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum OnDiverge {
    /// Stop, keep and write the last finite state.
    Stop,
    /// Roll back and retry the remaining time at half the step (up to 10 times).
    HalveDt,
}

/// Options of a run.
#[derive(Clone)]
pub struct RunOptions {
    /// Backend.
    pub backend: Backend,
    /// Length.
    pub length: RunLength,
    /// dt override, s.
    pub dt: Option<f64>,
    /// Accept dt above the bound.
    pub allow_unstable: bool,
    /// Divergence policy.
    pub on_diverge: OnDiverge,
    /// Number of frames for `series.pvd` (0: none).
    pub frames: u32,
    /// Output directory.
    pub out: PathBuf,
    /// Show a progress bar (when stdout is a terminal and the run takes over a second).
    pub progress: bool,
    /// Steps per GPU batch (one command buffer, one readback).
    pub batch: u32,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            backend: Backend::Gpu,
            length: RunLength::Steps(100),
            dt: None,
            allow_unstable: false,
            on_diverge: OnDiverge::Stop,
            frames: 0,
            out: PathBuf::from("out"),
            progress: false,
            batch: 200,
        }
    }
}

/// Contents of `summary.json`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct RunSummary {
    /// Scene name.
    pub scene: String,
    /// `gpu` or `cpu`.
    pub backend: Backend,
    /// Adapter (GPU) or CPU description.
    pub adapter: String,
    /// Number of tets.
    pub tets: usize,
    /// Number of vertices.
    pub vertices: usize,
    /// Number of particles (0: this scene has none).
    pub particles: usize,
    /// Steps taken.
    pub steps: u64,
    /// Time step at the end of the run, s.
    pub dt: f64,
    /// Our stability bound, s.
    pub dt_bound: f64,
    /// The paper's eq. (14) bound, s.
    pub dt_paper_eq14: f64,
    /// How many times dt was halved after a divergence.
    pub dt_halvings: u32,
    /// Simulated time, s.
    pub sim_seconds: f64,
    /// Wall-clock time of the stepping, s.
    pub wall_seconds: f64,
    /// Steps per wall-clock second.
    pub steps_per_second: f64,
    /// Largest vertex displacement, m.
    pub max_displacement: f64,
    /// Kinetic energy at the end, J.
    pub kinetic_energy: f64,
    /// Elastic energy at the end, J.
    pub elastic_energy: f64,
    /// ‖residual force‖ / ‖external load‖ at the end (with `--until-static`).
    pub static_residual: Option<f64>,
    /// The tolerance `static_residual` was held to (with `--until-static`).
    pub static_tolerance: Option<f64>,
    /// `ok`, or why the run stopped.
    pub status: String,
}

/// Largest |u| over vertices, m.
pub fn max_displacement(displacements: &[f32]) -> f64 {
    displacements
        .chunks(3)
        .map(|u| u.iter().map(|&c| (c as f64).powi(2)).sum::<f64>().sqrt())
        .fold(0.0, f64::max)
}

/// The `.vtu` text of a state: points at rest, point data displacement and velocity, cell data material.
pub fn state_vtu(model: &Model, state: &State) -> String {
    let fixed: Vec<i32> = model.inv_mass.iter().map(|&w| (w == 0.0) as i32).collect();
    let material: Vec<i32> = model.regions.iter().map(|&r| r as i32).collect();
    let mut cell_data = vec![vtu::DataArray::I32("material", &material)];
    if !model.fibres.is_empty() {
        cell_data.push(vtu::DataArray::F32("fibres", 3, &model.fibres));
    }
    vtu::vtu(
        &model.rest,
        &model.tets,
        &[
            vtu::DataArray::F32("displacement", 3, &state.displacements),
            vtu::DataArray::F32("velocity", 3, &state.velocities),
            vtu::DataArray::I32("fixed", &fixed),
        ],
        &cell_data,
    )
}

struct Progress {
    bar: Option<indicatif::ProgressBar>,
    start: Instant,
    enabled: bool,
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
            enabled,
        }
    }
    fn update(&mut self, steps: u64, msg: String) {
        if let Some(b) = &self.bar {
            if self.enabled && b.is_hidden() && self.start.elapsed().as_secs_f64() > 1.0 {
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

/// Write the next frame (`frame_NNNN.vtu`, N = frames written so far) and list it for the PVD.
fn write_frame(
    dir: &Path,
    model: &Model,
    state: &State,
    time: f64,
    frames: &mut Vec<(f64, String)>,
) -> Result<()> {
    let name = format!("frame_{:04}.vtu", frames.len());
    output::write_atomic(&dir.join(&name), state_vtu(model, state).as_bytes())?;
    frames.push((time, name));
    Ok(())
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

/// Run `scene` as `opts` says and write the outputs. Returns the summary (also written).
pub fn run(scene: &Scene, opts: &RunOptions) -> Result<RunSummary> {
    std::fs::create_dir_all(&opts.out).map_err(|source| PalpateError::OutputIo {
        path: opts.out.clone(),
        source,
    })?;
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
            gpu: None,
        },
    )?;
    let model = sim.model.clone();
    let dt0 = sim.dt;
    let (mut target_steps, max_steps) = match opts.length {
        RunLength::Steps(n) => (n, n),
        RunLength::Duration(t) => {
            if !(t.is_finite() && t >= 0.0) {
                return Err(PalpateError::Usage(format!(
                    "--duration must be >= 0 s, got {t}"
                )));
            }
            // Round up, but not past a whole number that f64 division missed by an ulp.
            let x = t / dt0;
            let n = if (x - x.round()).abs() < 1e-9 * x.max(1.0) {
                x.round()
            } else {
                x.ceil()
            };
            (n as u64, n as u64)
        }
        RunLength::UntilStatic { max_steps } => (max_steps, max_steps),
    };
    if target_steps > MAX_RUN_STEPS {
        return Err(PalpateError::Usage(format!(
            "the run would take {target_steps} steps of {dt0:.3e} s (more than {MAX_RUN_STEPS}); use a larger --dt or a shorter run"
        )));
    }
    // The run's simulated length; --on-diverge halve-dt keeps it (so --steps N may take more
    // than N steps after a halving), and frames are spaced evenly over it.
    let mut target_time = target_steps as f64 * dt0;
    let frame_dt = if opts.frames >= 2 {
        max_steps as f64 * dt0 / (opts.frames - 1) as f64
    } else {
        f64::INFINITY
    };
    let mut frames = Vec::new();
    let mut state = sim.state()?;
    if opts.frames >= 2 {
        write_frame(&opts.out, &model, &state, 0.0, &mut frames)?;
    }
    let show = opts.progress && std::io::stdout().is_terminal();
    let mut progress = Progress::new(show, (!until_static).then_some(target_steps));
    let tolerance = scene.solver.static_tolerance;
    let mut status = "ok".to_string();
    let mut halvings = 0u32;
    let mut residual = None;
    let start = Instant::now();
    let mut next_frame_time = frame_dt;
    let adaptive = until_static && scene.solver.damping == 0.0;
    let relax = |sim: &mut Simulation, s: &crate::stepper::BatchStats| -> Result<f64> {
        // Adaptive viscous relaxation: critical damping α = 2ω of the current displacement
        // shape (Rayleigh quotient), unconditionally stable in the v/(1 + α dt) form.
        if adaptive {
            if let Some(omega) = s.displacement_frequency() {
                sim.set_damping(2.0 * omega)?;
            }
        }
        Ok(s.residual_norm() / s.external_norm().max(f64::MIN_POSITIVE))
    };
    if until_static && target_steps > 0 {
        // Residual of the initial state: a body already in equilibrium stops at once.
        if let Advance::Done(s) = sim.advance(1)? {
            residual = Some(relax(&mut sim, &s)?);
        }
    }
    while sim.steps_done < target_steps {
        if until_static && residual.is_some_and(|r| r <= tolerance) {
            break;
        }
        let mut batch = (target_steps - sim.steps_done).min(opts.batch.max(1) as u64);
        if next_frame_time.is_finite() {
            let to_frame = ((next_frame_time - sim.time) / sim.dt - 1e-6)
                .ceil()
                .max(1.0);
            batch = batch.min(to_frame as u64);
        }
        match sim.advance(batch as u32)? {
            Advance::Done(s) => {
                if until_static {
                    residual = Some(relax(&mut sim, &s)?);
                }
            }
            Advance::Diverged { step, vertex } => {
                let what = format!(
                    "diverged: non-finite or faster than {:.3e} m/s ({} x P-wave speed) at step {step}, vertex {vertex} (dt = {:.3e} s, bound {:.3e} s)",
                    crate::model::SPEED_LIMIT_WAVE_SPEEDS * model.material.p_wave_speed(),
                    crate::model::SPEED_LIMIT_WAVE_SPEEDS,
                    sim.dt,
                    model.bounds.dt_bound
                );
                if opts.on_diverge == OnDiverge::HalveDt && halvings < 10 {
                    halvings += 1;
                    sim.rollback_to_checkpoint()?;
                    let dt = sim.dt / 2.0;
                    sim.set_dt(dt)?;
                    let remaining = (target_time - sim.time).max(0.0);
                    target_steps = sim.steps_done + (remaining / dt).ceil() as u64;
                    target_time = sim.time + remaining;
                    eprintln!(
                        "warning: {what}; retrying from step {} at dt = {dt:.3e} s",
                        sim.steps_done
                    );
                    continue;
                }
                status = format!("{what}; last finite state written");
                break;
            }
        }
        if sim.time >= next_frame_time - 0.5 * sim.dt {
            state = sim.state()?;
            write_frame(&opts.out, &model, &state, sim.time, &mut frames)?;
            next_frame_time += frame_dt;
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
    if until_static && status == "ok" && !residual.is_some_and(|r| r <= tolerance) {
        status = format!(
            "not static after {} steps: residual {:.3e} > tolerance {tolerance:.1e}",
            sim.steps_done,
            residual.unwrap_or(f64::NAN)
        );
    }
    state = sim.state()?;
    // The final state closes the series (with --frames 1 it is the only frame).
    let final_missing = frames.last().is_none_or(|(t, _)| *t < sim.time);
    if opts.frames == 1 || (opts.frames >= 2 && final_missing) {
        write_frame(&opts.out, &model, &state, sim.time, &mut frames)?;
    }
    output::write_atomic(
        &opts.out.join("final.vtu"),
        state_vtu(&model, &state).as_bytes(),
    )?;
    if !frames.is_empty() {
        output::write_atomic(
            &opts.out.join("series.pvd"),
            output::pvd(&frames).as_bytes(),
        )?;
    }
    let summary = RunSummary {
        scene: scene.name.clone(),
        backend: opts.backend,
        adapter: sim.backend_name(),
        tets: model.n_tets(),
        vertices: model.n_vertices(),
        particles: 0,
        steps: sim.steps_done,
        dt: sim.dt,
        dt_bound: model.bounds.dt_bound,
        dt_paper_eq14: model.bounds.dt_paper_eq14,
        dt_halvings: halvings,
        sim_seconds: sim.time,
        wall_seconds: wall,
        steps_per_second: sim.steps_done as f64 / wall.max(1e-9),
        max_displacement: max_displacement(&state.displacements),
        kinetic_energy: sim.last.kinetic_energy(),
        elastic_energy: sim.last.elastic_energy(),
        static_residual: if until_static { residual } else { None },
        static_tolerance: until_static.then_some(tolerance),
        status,
    };
    let json =
        serde_json::to_string_pretty(&summary).map_err(|e| PalpateError::Gpu(e.to_string()))?;
    output::write_atomic(&opts.out.join("summary.json"), json.as_bytes())?;
    Ok(summary)
}
