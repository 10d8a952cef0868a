//! The `palpate` command line (DESIGN.md §4). User errors print one `error: …` line and exit 1.

use clap::{Parser, Subcommand};
use palpate::error::{PalpateError, Result};
use palpate::run::{OnDiverge, RunLength, RunOptions, RunStatus};
use palpate::scene::{self, Scene};
use palpate::sim::Backend;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "palpate",
    version,
    about = "GPU soft-tissue simulation for haptic interaction"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Simulate a scene and write final.vtu, summary.json (and series.pvd with --frames).
    Run {
        /// Built-in scene name or path to a scene TOML file.
        #[arg(default_value = scene::DEFAULT_SCENE)]
        scene: String,
        /// Backend that steps the model (auto: a hardware GPU, else the CPU).
        #[arg(long, value_enum, default_value = "auto")]
        backend: Backend,
        /// CPU backend threads (default: all cores; refused with --backend gpu). Results do
        /// not depend on it.
        #[arg(long, allow_negative_numbers = true)]
        threads: Option<usize>,
        /// Number of steps (0 writes the initial state).
        #[arg(long, allow_negative_numbers = true, conflicts_with_all = ["duration", "until_static"])]
        steps: Option<u64>,
        /// Simulated time, s (rounded up to whole steps: summary.json's sim_seconds may be a
        /// fraction of a step longer).
        #[arg(long, allow_hyphen_values = true, conflicts_with = "until_static")]
        duration: Option<f64>,
        /// Run with critical viscous damping until the residual force is below the scene's tolerance.
        #[arg(long)]
        until_static: bool,
        /// Step cap for --until-static (at least 1; default 200000).
        #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
        max_steps: Option<u64>,
        /// Time step, s (overrides the scene).
        #[arg(long, allow_hyphen_values = true)]
        dt: Option<f64>,
        /// Accept a dt (--dt or the scene's) above the stability bound.
        #[arg(long)]
        allow_unstable: bool,
        /// What to do when the state diverges (non-finite, or faster than 10x the P-wave speed).
        #[arg(long, value_enum, default_value = "stop")]
        on_diverge: OnDiverge,
        /// Write K frames to series.pvd, evenly over the run's length and the final state last
        /// (with --until-static the length is --max-steps: a run that settles sooner has fewer,
        /// and frames closer than a relaxation batch share one; the run says so).
        #[arg(long, default_value_t = 0)]
        frames: u32,
        /// Output directory.
        #[arg(long, default_value = "out")]
        out: PathBuf,
    },
    /// Touch a scene through a haptic device: the simulation and the 1 kHz servo loop
    /// together; writes haptic.csv, final.vtu and summary.json (with the loop statistics).
    Haptic {
        /// Built-in scene name or path to a scene TOML file with a [tool].
        #[arg(default_value = palpate::haptic_run::DEFAULT_HAPTIC_SCENE)]
        scene: String,
        /// The device: null, scripted:FILE (CSV t,x,y,z in s and m, offsets from the tool's
        /// home) or udp:ADDR (see docs/haptic-protocol.md).
        #[arg(long)]
        device: String,
        /// Device specification: touch (the default), omni, desktop, omega3 or falcon.
        #[arg(long)]
        device_spec: Option<String>,
        /// Run length, s (default: the scripted trajectory's length, else 10 s).
        #[arg(long, allow_hyphen_values = true)]
        seconds: Option<f64>,
        /// Backend that steps the model (auto: a hardware GPU, else the CPU).
        #[arg(long, value_enum, default_value = "auto")]
        backend: Backend,
        /// CPU backend threads (default: one fewer than the cores, at least one; refused with
        /// --backend gpu).
        #[arg(long, allow_negative_numbers = true)]
        threads: Option<usize>,
        /// Keep stepping while the body is at rest and the tool clear of it (by default the
        /// physics then sleeps, and wakes as the tool approaches).
        #[arg(long)]
        no_sleep: bool,
        /// Output directory.
        #[arg(long, default_value = "out")]
        out: PathBuf,
    },
    /// Mesh statistics and quality of a scene; optionally export the mesh (.vtu or .msh).
    Mesh {
        /// Built-in scene name or path to a scene TOML file.
        scene: String,
        /// Write the mesh to this file: .vtu (VTK XML, opens in ParaView) or .msh (Gmsh 4.1),
        /// the extension picks the format.
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Benchmark studies that write tables and plots (default into docs/).
    Bench {
        #[command(subcommand)]
        study: BenchStudy,
    },
    /// List the built-in scenes.
    Scenes,
    /// List GPU adapters, the one chosen, and its limits.
    Info,
}

#[derive(Subcommand)]
enum BenchStudy {
    /// Largest stable dt per material and mesh, and stress cases: stability.csv, stability.md.
    Stability {
        /// Backend.
        #[arg(long, value_enum, default_value = "cpu")]
        backend: Backend,
        /// CI-sized run.
        #[arg(long)]
        quick: bool,
        /// Steps of the long ED0 run (1 to 10^9; default 1000000, 20000 with --quick).
        #[arg(long, value_parser = clap::value_parser!(u64).range(1..=1_000_000_000))]
        ed0_steps: Option<u64>,
        /// Output directory.
        #[arg(long, default_value = "docs")]
        out: PathBuf,
    },
    /// The tool's contact force against Hertz's solution: contact.csv, contact.md.
    Contact {
        /// Backend.
        #[arg(long, value_enum, default_value = "auto")]
        backend: Backend,
        /// CI-sized run.
        #[arg(long)]
        quick: bool,
        /// Output directory.
        #[arg(long, default_value = "docs")]
        out: PathBuf,
    },
    /// The 1 kHz servo loop with the physics thread on lv, ed0 and lv_touch, per backend:
    /// haptic_bench.csv, haptic_bench.md.
    Haptic {
        /// Seconds per session (1 to 3600).
        #[arg(long, default_value_t = 10.0)]
        seconds: f64,
        /// Output directory.
        #[arg(long, default_value = "docs")]
        out: PathBuf,
    },
    /// The Land et al. 2015 cardiac benchmark, problems 1 and 2, solved to a static state
    /// over a mesh-refinement series: land.csv, land.md, land.png, land_pareto.png.
    Land {
        /// Backend.
        #[arg(long, value_enum, default_value = "cpu")]
        backend: Backend,
        /// CI-sized run (the two coarsest meshes).
        #[arg(long)]
        quick: bool,
        /// Output directory.
        #[arg(long, default_value = "docs")]
        out: PathBuf,
    },
    /// Error against a converged reference versus run time: accuracy.csv, accuracy.png.
    Accuracy {
        /// Backend whose run time is measured (auto: a hardware GPU, else the CPU, as `run`
        /// picks; a software adapter only when asked for with `gpu`).
        #[arg(long, value_enum, default_value = "auto")]
        backend: Backend,
        /// CI-sized run.
        #[arg(long)]
        quick: bool,
        /// Output directory.
        #[arg(long, default_value = "docs")]
        out: PathBuf,
    },
}

/// Set when a run or session ended early on Ctrl-C / SIGTERM (exit status 130, not 0).
static STOPPED_BY_SIGNAL: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

fn main() -> ExitCode {
    // Mesa's Vulkan WSI probes Wayland and prints a spurious "XDG_RUNTIME_DIR is invalid"
    // line when the variable is unset (headless machines); point it at the temp dir.
    if std::env::var_os("XDG_RUNTIME_DIR").is_none() {
        std::env::set_var("XDG_RUNTIME_DIR", std::env::temp_dir());
    }
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => return command_line_error(e),
    };
    let result = execute(cli);
    // Output files are written by now; a standard output that could not be written (not a
    // closed pipe) is the run's error when it had none of its own.
    let stopped = STOPPED_BY_SIGNAL.load(std::sync::atomic::Ordering::SeqCst);
    let result = match (result, palpate::console::stdout_failure()) {
        (Ok(()), Some(why)) if !stopped => Err(PalpateError::Usage(format!(
            "could not write to standard output: {why}"
        ))),
        (r, _) => r,
    };
    match result {
        Ok(()) if stopped => ExitCode::from(palpate::interrupt::EXIT_STATUS),
        Ok(()) => ExitCode::SUCCESS,
        Err(e @ PalpateError::StoppedBeforeStart(_)) => {
            palpate::say_err!("error: {e}");
            ExitCode::from(palpate::interrupt::EXIT_STATUS)
        }
        Err(e) => {
            // One line of bounded length whatever input an error quotes.
            palpate::say_err!(
                "error: {}",
                palpate::input::clip_middle(&e.to_string(), 2000)
            );
            ExitCode::FAILURE
        }
    }
}

/// A warning when the servo loop fell short of its rate (below 95 % of it, or over 1 % of its
/// deadlines skipped after overruns) over a session of at least 100 ticks: the device's
/// force then came late or not at all, and the passivity control's stiffness bound assumes
/// the target period.
fn servo_rate_warning(servo: &palpate::haptics::servo::ServoStats) -> Option<String> {
    let deadlines = servo.ticks + servo.missed_deadlines;
    let short =
        servo.rate_hz < 0.95 * servo.target_rate_hz || servo.missed_deadlines * 100 > deadlines;
    (servo.ticks >= 100 && short).then(|| {
        format!(
            "warning: the servo loop ran at {:.1} Hz against its {:.0} Hz, {} of its {deadlines} deadlines skipped after overruns (lateness p99 {:.0} us): the device's force came late or was held, which a stiff contact can feel as buzz or give; leave the cores to palpate (the servo shares them with the physics thread)",
            servo.rate_hz, servo.target_rate_hz, servo.missed_deadlines, servo.lateness_us.p99
        )
    })
}

/// Help and version go out as clap writes them; a command-line error becomes one line,
/// `error: …` with clap's details and usage folded in, and exit status 1 like every other
/// error of user input.
fn command_line_error(e: clap::Error) -> ExitCode {
    use clap::error::ErrorKind;
    match e.kind() {
        ErrorKind::DisplayHelp | ErrorKind::DisplayVersion => {
            let _ = e.print();
            return ExitCode::SUCCESS;
        }
        ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand => {
            let _ = e.print();
            return ExitCode::FAILURE;
        }
        _ => {}
    }
    let mut rendered = e.render().to_string();
    if let Some(tip) = option_of_another_command(&e) {
        // clap's tip ("to pass '--steps' as a value, use '-- --steps'") misleads here.
        rendered = rendered
            .lines()
            .filter(|l| !l.trim_start().starts_with("tip:"))
            .chain(std::iter::once(tip.as_str()))
            .collect::<Vec<_>>()
            .join("\n");
    }
    palpate::say_err!("error: {}", one_line(&rendered));
    ExitCode::FAILURE
}

/// For an unknown `--option` that other subcommands take (`palpate haptic --steps`), a tip
/// naming them: "tip: --steps is an option of `palpate run`, not of `palpate haptic`".
fn option_of_another_command(e: &clap::Error) -> Option<String> {
    use clap::error::{ContextKind, ContextValue, ErrorKind};
    use clap::CommandFactory;
    if e.kind() != ErrorKind::UnknownArgument {
        return None;
    }
    let Some(ContextValue::String(arg)) = e.get(ContextKind::InvalidArg) else {
        return None;
    };
    let long = arg.strip_prefix("--")?.split('=').next()?.to_string();
    // The subcommand path the user typed: the leading words that name subcommands.
    let root = Cli::command();
    let mut typed = Vec::new();
    let mut at = &root;
    for word in std::env::args_os().skip(1) {
        match word.to_str().and_then(|w| at.find_subcommand(w)) {
            Some(sub) => {
                typed.push(sub.get_name().to_string());
                at = sub;
            }
            None => break,
        }
    }
    let mut takers = Vec::new();
    let mut visit = vec![(String::new(), &root)];
    while let Some((path, command)) = visit.pop() {
        for sub in command.get_subcommands() {
            let name = format!("{path} {}", sub.get_name()).trim().to_string();
            if sub
                .get_arguments()
                .any(|a| a.get_long() == Some(long.as_str()))
            {
                takers.push(name.clone());
            }
            visit.push((name, sub));
        }
    }
    takers.retain(|t| *t != typed.join(" "));
    takers.sort();
    if takers.is_empty() {
        return None;
    }
    let mut takers: Vec<String> = takers.iter().map(|t| format!("`palpate {t}`")).collect();
    let last = takers.pop()?;
    let takers = match takers.is_empty() {
        true => last,
        false => format!("{} and {last}", takers.join(", ")),
    };
    Some(match typed.is_empty() {
        true => format!("tip: --{long} is an option of {takers}, after its command name"),
        false => format!(
            "tip: --{long} is an option of {takers}, not of `palpate {}`",
            typed.join(" ")
        ),
    })
}

/// clap's rendered error on one line: the message, its detail lines after ": " or "; ",
/// and its usage in parentheses; the "For more information" line left out.
fn one_line(rendered: &str) -> String {
    let mut message = String::new();
    let mut usage = None;
    for line in rendered.lines().map(str::trim).filter(|l| !l.is_empty()) {
        if line.starts_with("For more information") {
            continue;
        }
        if let Some(u) = line.strip_prefix("Usage: ") {
            usage = Some(u.to_string());
        } else if message.is_empty() {
            message = line.strip_prefix("error: ").unwrap_or(line).to_string();
        } else {
            message.push_str(if message.ends_with(':') { " " } else { "; " });
            message.push_str(line);
        }
    }
    match usage {
        Some(u) => format!("{message} (usage: {u}; see --help)"),
        None => format!("{message} (see --help)"),
    }
}

fn execute(cli: Cli) -> Result<()> {
    // The GPU stepper's switches are read when a GPU stepper is built; a typo in one is an
    // error whichever backend this command ends up on.
    palpate::plan::Fusions::from_env()?;
    palpate::gpu::stepper::prerecord_from_env()?;
    palpate::cpu::memory::memory_from_env()?;
    match cli.command {
        Command::Run {
            scene,
            backend,
            threads,
            steps,
            duration,
            until_static,
            max_steps,
            dt,
            allow_unstable,
            on_diverge,
            frames,
            out,
        } => {
            let scene = Scene::load(&scene)?;
            palpate::interrupt::install();
            warn_scene(
                &scene,
                scene
                    .tool
                    .as_ref()
                    .map(|t| (t.position_at(0.0), "at t = 0")),
            );
            if !scene.fixed.is_empty() && scene.fixed.iter().all(|&f| f) {
                palpate::say_err!(
                    "warning: {}: [[fixed]] holds every vertex: nothing can move (fix a tag, box or plane of the boundary)",
                    scene.origin
                );
            } else {
                let mut loaded = scene
                    .external_forces
                    .iter()
                    .zip(&scene.fixed)
                    .filter(|(f, _)| **f != glam::DVec3::ZERO)
                    .peekable();
                if loaded.peek().is_some() && loaded.all(|(_, &fixed)| fixed) {
                    palpate::say_err!(
                        "warning: {}: [[loads.pressure]] acts only on fixed vertices: it moves nothing",
                        scene.origin
                    );
                }
                if scene.follower.as_ref().is_some_and(|f| {
                    f.faces
                        .iter()
                        .flatten()
                        .all(|&v| scene.fixed.get(v as usize).copied().unwrap_or(false))
                }) {
                    palpate::say_err!(
                        "warning: {}: [[loads.follower_pressure]] acts only on fixed vertices: it moves nothing",
                        scene.origin
                    );
                }
            }
            if scene
                .particles
                .as_ref()
                .is_some_and(|p| !p.all_active && scene.tool.is_none())
            {
                palpate::say_err!(
                    "warning: {}: [particles] without a [tool]: no particle becomes dynamic (they wake around the tool), so the tets carry the particle zone and the particle stages do not run; add a [tool], or set particles.activation = \"all\"",
                    scene.origin
                );
            }
            if max_steps.is_some() && !until_static {
                return Err(PalpateError::Usage(
                    "--max-steps caps --until-static; without it use --steps or --duration".into(),
                ));
            }
            if let Some(t) = duration {
                // Before the run's banner (the run checks it again for library callers).
                palpate::run::check_duration(t)?;
            }
            let length = match (steps, duration, until_static) {
                (Some(n), _, _) => RunLength::Steps(n),
                (_, Some(t), _) => RunLength::Duration(t),
                (_, _, true) => RunLength::UntilStatic {
                    max_steps: max_steps.unwrap_or(200_000),
                },
                _ => scene
                    .solver
                    .duration
                    .map(RunLength::Duration)
                    .unwrap_or(RunLength::Steps(1000)),
            };
            let opts = RunOptions {
                backend,
                threads,
                length,
                dt,
                allow_unstable,
                on_diverge,
                frames,
                out: out.clone(),
                progress: true,
                announce: true,
                ..Default::default()
            };
            let s = palpate::run::run(&scene, &opts)?;
            warn_inverted(&scene, &s);
            if let Some(note) = paper_divergence_note(&scene, &s.status) {
                palpate::say_err!("{note}");
            }
            if let Some(note) = raised_substeps_note(&s) {
                palpate::say_err!("{note}");
            }
            palpate::say!(
                "{} steps of {:.3e} s ({:.3e} s simulated) in {:.2} s = {:.0} steps/s",
                s.steps,
                s.dt,
                s.sim_seconds,
                s.wall_seconds,
                s.steps_per_second
            );
            palpate::say!(
                "max displacement {:.4e} m, kinetic {:.3e} J, elastic {:.3e} J{}; status: {}",
                s.max_displacement,
                s.kinetic_energy,
                s.elastic_energy,
                s.static_residual
                    .map(|r| format!(", residual {r:.2e}"))
                    .unwrap_or_default(),
                s.status
            );
            let mut wrote = vec!["final.vtu"];
            if s.particles > 0 {
                wrote.push("particles_final.vtu");
            }
            if frames > 0 {
                wrote.push("series.pvd (with its frames)");
                if s.particles > 0 {
                    wrote.push("particles_series.pvd (with its frames)");
                }
            }
            wrote.push("summary.json");
            let wrote: Vec<String> = wrote
                .iter()
                .map(|f| format!("{}/{f}", out.display()))
                .collect();
            palpate::say!(
                "wrote {}; realtime factor {:.3} (simulated / wall seconds)",
                wrote.join(", "),
                s.realtime_factor
            );
            if let RunStatus::Interrupted { .. } = s.status {
                STOPPED_BY_SIGNAL.store(true, std::sync::atomic::Ordering::SeqCst);
                palpate::say_err!("{}; outputs written", s.status);
            } else if !s.status.is_ok() {
                return Err(PalpateError::Usage(format!(
                    "{}: run did not finish cleanly: {}",
                    scene.origin, s.status
                )));
            }
            Ok(())
        }
        Command::Haptic {
            scene,
            device,
            device_spec,
            seconds,
            backend,
            threads,
            no_sleep,
            out,
        } => {
            let scene = Scene::load(&scene)?;
            palpate::interrupt::install();
            warn_scene(&scene, scene.tool.as_ref().map(|t| (t.home, "at home")));
            let opts = palpate::haptic_run::HapticOptions {
                backend,
                threads,
                device,
                device_spec,
                seconds,
                out: out.clone(),
                announce: true,
                sleep_at_rest: !no_sleep,
                ..Default::default()
            };
            let s = palpate::haptic_run::run_haptic(&scene, &opts)?;
            let h = &s.haptic;
            let l = &h.servo.lateness_us;
            let a = &h.servo.model_age_ms;
            palpate::say!(
                "servo: {} ticks at {:.1} Hz; lateness p50 {:.1} / p99 {:.1} / p99.9 {:.1} / max {:.1} us; {} missed deadlines",
                h.servo.ticks, h.servo.rate_hz, l.p50, l.p99, l.p99_9, l.max, h.servo.missed_deadlines
            );
            palpate::say!(
                "model age p50 {:.2} / p99 {:.2} / max {:.2} ms; {} force clamps; passivity observer min {:.2e} J; max force {:.3} N",
                a.p50, a.p99, a.max, h.servo.force_clamps, h.servo.passivity_min_energy_j, h.servo.max_force_n
            );
            palpate::say!(
                "physics: {} steps ({:.3} s simulated, {:.3} s of it asleep at rest) in {:.2} s = {:.0} steps/s, realtime factor {:.3}; stiffness {}",
                s.run.steps,
                s.run.sim_seconds,
                h.physics.slept_seconds,
                s.run.wall_seconds,
                s.run.steps_per_second,
                s.run.realtime_factor,
                h.physics.stiffness_model
            );
            if h.servo.unlogged_ticks > 0 {
                palpate::say_err!(
                    "warning: haptic.csv holds the session's first {} ticks; the {} after them were not logged (the log holds at most {} ticks)",
                    h.servo.ticks.saturating_sub(h.servo.unlogged_ticks),
                    h.servo.unlogged_ticks,
                    palpate::haptics::servo::MAX_LOG_TICKS
                );
            }
            warn_inverted(&scene, &s.run);
            warn_inverted_in_contact(&scene, h);
            if let Some(note) = paper_divergence_note(&scene, &s.run.status) {
                palpate::say_err!("{note}");
            }
            if let Some(note) = raised_substeps_note(&s.run) {
                palpate::say_err!("{note}");
            }
            if h.physics.workspace_clamps > 0 {
                palpate::say_err!(
                    "warning: the device left its workspace (radius {} m) in {} physics batches: the tool was held at its edge there (haptic.csv's proxy columns give where the device asked for)",
                    h.device_spec.workspace_radius,
                    h.physics.workspace_clamps
                );
            }
            if h.servo.held_poses > 0 {
                palpate::say_err!(
                    "warning: in {} servo tick{} the device's reading jumped farther than a hand moves ({} m/s), up to {:.3e} m from the last good pose, and was held back, the pose used following no faster than that (a glitching device or network; haptic.csv's flags bit 8 marks those ticks and the ones catching up)",
                    h.servo.held_poses,
                    if h.servo.held_poses == 1 { "" } else { "s" },
                    h.servo.max_hand_speed,
                    h.servo.largest_pose_jump_m,
                );
            }
            if let Some(fast) = h.physics.hand_too_fast {
                palpate::say_err!(
                    "warning: the hand pressed or slid the tool into the tissue at up to {:.3e} m/s, faster than the {:.3e} m/s it can follow (half its shear wave speed at mass scaling {}), in {} physics batch{} from t = {:.3} s: the simulated tool lagged the hand there, the force felt coming from the tissue's static stiffness at the hand's pose (until that stiffness is known at a first contact, or with none, from the lagging tool's force alone); a smaller [solver] mass_scaling raises the limit, at a cost in realtime capacity",
                    fast.max_hand_speed,
                    h.physics.max_tool_speed,
                    scene.solver.mass_scaling,
                    fast.batches,
                    if fast.batches == 1 { "" } else { "es" },
                    fast.from_seconds
                );
            }
            if let Some(w) = servo_rate_warning(&h.servo) {
                palpate::say_err!("{w}");
            }
            // After a divergence the physics stopped: its rate says nothing about the machine.
            if h.physics.realtime_capacity < 0.95 && s.run.status.divergence().is_none() {
                palpate::say_err!(
                    "warning: the physics kept up with only {:.2}x real time: the simulated tissue lags the hand, and contact can chatter (make and break) instead of settling; use a coarser mesh, a larger [solver] mass_scaling (statics unchanged) or a GPU",
                    h.physics.realtime_capacity
                );
            }
            palpate::say!(
                "wrote {0}/haptic.csv, {0}/final.vtu, {1}{0}/summary.json; status: {2}",
                out.display(),
                if s.run.particles > 0 {
                    format!("{}/particles_final.vtu, ", out.display())
                } else {
                    String::new()
                },
                s.run.status
            );
            if let RunStatus::Interrupted { .. } = s.run.status {
                STOPPED_BY_SIGNAL.store(true, std::sync::atomic::Ordering::SeqCst);
                palpate::say_err!("{}; outputs written", s.run.status);
            } else if !s.run.status.is_ok() {
                return Err(PalpateError::Usage(format!(
                    "{}: haptic session did not finish cleanly: {}",
                    scene.origin, s.run.status
                )));
            }
            Ok(())
        }
        Command::Mesh { scene, out } => {
            if let Some(path) = &out {
                palpate::mesh::io::check_writable(path)?;
            }
            let scene = Scene::load(&scene)?;
            warn_reoriented(&scene);
            let report = palpate::mesh::quality::report(&scene);
            palpate::console::write_out(format_args!("{report}"));
            if let Some(path) = out {
                palpate::mesh::io::write(&path, &scene.mesh)?;
                palpate::say!("wrote {}", path.display());
            }
            Ok(())
        }
        Command::Bench { study } => {
            // Options checked before the output folder is made.
            if let BenchStudy::Haptic { seconds, .. } = &study {
                if !(1.0..=3600.0).contains(seconds) {
                    return Err(PalpateError::Usage(format!(
                        "bench haptic: --seconds {} must be between 1 and 3600 s",
                        palpate::scene::Num(*seconds)
                    )));
                }
            }
            palpate::output::prepare_out_dir(study.out())?;
            bench(study)
        }
        Command::Scenes => {
            for (name, desc) in scene::builtin_list() {
                palpate::say!("{name:<10} {desc}");
            }
            Ok(())
        }
        Command::Info => {
            let adapters = palpate::gpu::context::list_adapters()?;
            if adapters.is_empty() {
                palpate::say!("no compute-capable adapter found");
            }
            for a in &adapters {
                let i = a.get_info();
                palpate::say!(
                    "adapter: {} ({:?}, {:?}, driver {} {})",
                    i.name,
                    i.backend,
                    i.device_type,
                    i.driver,
                    i.driver_info
                );
            }
            let (auto, reason, _) = palpate::sim::pick_auto()?;
            palpate::say!(
                "--backend auto picks: {} ({reason})",
                if auto == Backend::Gpu { "gpu" } else { "cpu" }
            );
            palpate::say!(
                "cpu backend: {} cores (--threads defaults to all of them for run, one fewer for haptic)",
                palpate::cpu::stepper::available_cores()
            );
            let allowed = palpate::gpu::context::allowed_adapters()?;
            if !adapters.is_empty() && allowed.is_empty() {
                palpate::say!(
                    "--backend gpu: none of the adapters above matches PALPATE_ADAPTER='{}' (a part of the adapter's name)",
                    palpate::gpu::context::adapter_filter().unwrap_or_default()
                );
            } else if !adapters.is_empty() {
                let ctx = palpate::gpu::GpuContext::new()?;
                let l = &ctx.limits;
                palpate::say!("--backend gpu takes: {}", ctx.describe());
                palpate::say!(
                    "timestamp queries: {}",
                    if ctx
                        .device
                        .features()
                        .contains(wgpu::Features::TIMESTAMP_QUERY)
                    {
                        "yes"
                    } else {
                        "no"
                    }
                );
                palpate::say!(
                    "limits: max_buffer_size {} B, max_storage_buffer_binding_size {} B, storage buffers per stage {}, workgroups per dimension {}",
                    l.max_buffer_size, l.max_storage_buffer_binding_size, l.max_storage_buffers_per_shader_stage, l.max_compute_workgroups_per_dimension
                );
            }
            let scene = Scene::load(scene::DEFAULT_SCENE)?;
            let model = palpate::model::Model::from_scene(&scene);
            palpate::say!("step plan of the default scene '{}':", scene.name);
            for line in palpate::plan::StepPlan::for_model(&model).describe() {
                palpate::say!("  {line}");
            }
            Ok(())
        }
    }
}

impl BenchStudy {
    /// The study's output directory.
    fn out(&self) -> &std::path::Path {
        match self {
            BenchStudy::Stability { out, .. }
            | BenchStudy::Contact { out, .. }
            | BenchStudy::Haptic { out, .. }
            | BenchStudy::Land { out, .. }
            | BenchStudy::Accuracy { out, .. } => out,
        }
    }
}

/// Run a benchmark study and write its tables and plots.
fn bench(study: BenchStudy) -> Result<()> {
    match study {
        BenchStudy::Stability {
            backend,
            quick,
            ed0_steps,
            out,
        } => {
            use palpate::bench::stability;
            let given = ed0_steps;
            let ed0_steps = given.unwrap_or(if quick {
                stability::QUICK_ED0_STEPS
            } else {
                stability::ED0_STEPS
            });
            let opts = stability::StabilityOptions {
                backend,
                quick,
                ed0_steps,
            };
            let rows = stability::study(&opts, &mut |s| palpate::say_err!("bench stability: {s}"))?;
            let header = format!(
                "Written by `palpate bench stability --backend {}{}{}` on {}. Case letters follow issue 4: (a) critical dt, (b) squash to 10 % and release, (c) random inversion, (d) probe at 10x a {} N device, (e) long ED0 run, (f) Table 1 scenes at the paper's dt.",
                clap::ValueEnum::to_possible_value(&backend)
                    .map_or_else(String::new, |v| v.get_name().to_string()),
                match given {
                    Some(n) => format!(" --ed0-steps {n}"),
                    None => String::new(),
                },
                if quick { " --quick" } else { "" },
                adapter_name(backend),
                stability::DEVICE_MAX_FORCE
            );
            stability::write(&out, &rows, &header)?;
            for r in &rows {
                palpate::say!(
                    "({}) {:<18} {:<18} {:<60} {:>12.4} {}",
                    r.case,
                    r.material,
                    r.mesh,
                    r.quantity,
                    r.value,
                    if r.ok { "ok" } else { "FAILED" }
                );
            }
            palpate::say!("wrote {0}/stability.csv, {0}/stability.md", out.display());
            Ok(())
        }
        BenchStudy::Contact {
            backend,
            quick,
            out,
        } => {
            use palpate::bench::contact;
            let rows = contact::study(backend, quick, &mut |s| {
                palpate::say_err!("bench contact: {s}")
            })?;
            let header = format!(
                "Written by `palpate bench contact{}` on {}. A sphere of radius {} mm pressed into a block of E = {} kPa, nu = {} (bottom held, half-width and depth {} contact radii), relaxed to a static state; error = (F - F_Hertz)/F_Hertz. In the hybrid blocks the particles within 2a of the tool are awake (dynamic) unless the label says otherwise; the rest move with the coarse core, which stiffens the contact the less the more are awake (compare the a/2 rows with 1a, 2a, 4a and all awake).",
                if quick { " --quick" } else { "" },
                adapter_name(backend),
                contact::HertzCase::default().radius * 1e3,
                contact::HertzCase::default().youngs_modulus / 1e3,
                contact::HertzCase::default().poisson_ratio,
                contact::HertzCase::default().block
            );
            contact::write(&out, &rows, &header)?;
            palpate::say!("wrote {0}/contact.csv, {0}/contact.md", out.display());
            Ok(())
        }
        BenchStudy::Haptic { seconds, out } => {
            use palpate::bench::haptic;
            let cores = palpate::cpu::stepper::available_cores();
            let mut runs = vec![(Backend::Cpu, Some(cores))];
            if cores > 1 {
                runs.push((Backend::Cpu, Some(cores - 1)));
            }
            if palpate::gpu::GpuContext::new().is_ok() {
                runs.push((Backend::Gpu, None));
            }
            let scratch =
                std::env::temp_dir().join(format!("palpate-bench-haptic-{}", std::process::id()));
            let mut rows = haptic::study(&runs, seconds, &scratch, &mut |s| {
                palpate::say_err!("bench haptic: {s}")
            })?;
            palpate::say_err!(
                "bench haptic: lv_touch with the hand away half the time, sleep on and off"
            );
            rows.extend(haptic::sleep_study(
                cores.saturating_sub(1).max(1),
                seconds,
                &scratch,
            )?);
            let header = format!(
                "Written by `palpate bench haptic --seconds {seconds}` on a machine with {cores} cores; GPU: {}. A scripted device presses each scene at 0.5 Hz (sin², 4 mm into lv, 0.06 into ed0, 3 mm into lv_touch) for {seconds} s; device spec touch (k_c = 360 N/m). The last two rows hold the hand 15 mm back from lv_touch for the first half, then press as above: with sleep the body rests unstepped while the tool is clear of it.",
                adapter_name(Backend::Gpu)
            );
            haptic::write(&out, &rows, &header)?;
            palpate::say!(
                "wrote {0}/haptic_bench.csv, {0}/haptic_bench.md",
                out.display()
            );
            Ok(())
        }
        BenchStudy::Land {
            backend,
            quick,
            out,
        } => {
            use palpate::bench::land;
            let rows = land::study(backend, quick, &mut |s| {
                palpate::say_err!("bench land: {s}")
            })?;
            let header = format!(
                "Written by `palpate bench land{}` on {} ({} cores). Each row is one `--until-static` solve (relative residual 1e-3, ramped follower pressure, dynamic relaxation with critical mass damping at the Rayleigh-quotient frequency); monitored values are the deformed z of the benchmark's points, interpolated in the containing tet. κ/C is the bulk modulus over Guccione's C (the penalty for incompressibility).",
                if quick { " --quick" } else { "" },
                adapter_name(backend),
                palpate::cpu::stepper::available_cores()
            );
            land::write(&out, &rows, &header)?;
            palpate::say!(
                "wrote {0}/land.csv, {0}/land.md, {0}/land.png, {0}/land_pareto.png",
                out.display()
            );
            Ok(())
        }
        BenchStudy::Accuracy {
            backend,
            quick,
            out,
        } => {
            use palpate::bench::accuracy::{self, Problem};
            let opts = accuracy::AccuracyOptions { backend, quick };
            let mut studies = Vec::new();
            for problem in [Problem::Beam, Problem::Lv] {
                studies.push(accuracy::study(problem, &opts, &mut |s| {
                    palpate::say_err!("bench accuracy: {s}")
                })?);
            }
            let fronts = accuracy::write(&out, &studies, &adapter_name(backend))?;
            for (study, front) in studies.iter().zip(&fronts) {
                let p = study.problem;
                palpate::say!(
                    "{}: reference {} at {} x bound: changes {:.2e} against the next-coarser mesh, {:.2e} against 2x dt",
                    p.name(),
                    p.label(study.reference.0),
                    study.reference.1,
                    study.reference_mesh_change,
                    study.reference_dt_change
                );
                for (i, r) in study.runs.iter().enumerate() {
                    palpate::say!(
                        "  {:<8} {:>7} tets  dt {:.2} x bound  {:>7} steps  {:>8.3} s  error {:.3e}{}",
                        p.label(r.cells),
                        r.tets,
                        r.safety,
                        r.steps,
                        r.wall_seconds,
                        r.error,
                        if front.contains(&i) { "  (Pareto)" } else { "" }
                    );
                }
                for (c, s) in &study.diverged {
                    palpate::say!("  {} at {s} x bound: diverged", p.label(*c));
                }
            }
            palpate::say!(
                "wrote {0}/accuracy.csv, {0}/accuracy.png, {0}/accuracy_lv.png",
                out.display()
            );
            Ok(())
        }
    }
}

/// The note a run or session whose particle sub-steps were raised prints: the layer's largest
/// stiffening and the most sub-steps per core step, against the scene's (None where the
/// count never went above the scene's).
fn raised_substeps_note(s: &palpate::output::summary::RunSummary) -> Option<String> {
    substeps_note(
        s.particle_substeps,
        s.particle_substeps_max,
        s.max_particle_stiffening,
    )
}

/// [`raised_substeps_note`] from the scene's count, the most used and the largest stiffening.
fn substeps_note(base: Option<u32>, most: Option<u32>, stiffening: Option<f32>) -> Option<String> {
    let (base, most, stiffening) = (base?, most?, stiffening?);
    (most > base).then(|| {
        format!(
            "note: the particle layer stiffened up to {stiffening:.1}x under the tool: its sub-steps were raised to up to {most} per core step (the scene's: {base}) to keep it stable, and its steps took longer there"
        )
    })
}

/// Warn when a run ends with inverted tets or particles (det F ≤ 0): there the force is not
/// the material's, and StVK pushes an inverted element towards its mirror image, not back.
fn warn_inverted(scene: &Scene, s: &palpate::output::summary::RunSummary) {
    let particles = s.inverted_particles.unwrap_or(0);
    if s.inverted_tets == 0 && particles == 0 {
        return;
    }
    let what = match s.inverted_particles {
        Some(n) => format!("{} tets and {n} particles are", s.inverted_tets),
        None => format!("{} tets are", s.inverted_tets),
    };
    palpate::say_err!(
        "warning: {}: {what} inverted (det F <= 0) at the end{}",
        scene.origin,
        inversion_advice(scene, particles > 0)
    );
}

/// Warn when a haptic session's counts while in contact found inverted elements (the end
/// state's count is [`warn_inverted`]'s).
fn warn_inverted_in_contact(scene: &Scene, h: &palpate::haptic_run::HapticStats) {
    let peak = &h.physics.inverted_peak;
    let Some(t) = peak.at_seconds else {
        return;
    };
    let what = if scene.particles.is_some() {
        format!("{} tets and {} particles were", peak.tets, peak.particles)
    } else {
        format!("{} tets were", peak.tets)
    };
    palpate::say_err!(
        "warning: {}: while the tool touched the tissue, up to {what} inverted (det F <= 0; the most at t = {t:.3} s, of {} counts){}",
        scene.origin,
        h.physics.inversion_checks,
        inversion_advice(scene, peak.particles > 0)
    );
}

/// The note a diverged run or session of `scene` prints when its particles follow the paper
/// model: eq. 13 as the paper writes it, a_i = Σ_j m_j σ_j/(ρ_j ρ_i) ∇W, is one-sided (a
/// particle is pushed by its neighbours' stresses, not by its own), so its forces are not an
/// energy's gradient and, where a particle's neighbourhood is lopsided (the layer's surface),
/// do work of their own. On hm1 and lv_touch that grows at its own rate, whatever the dt
/// (BENCHMARKS.md), where tlsph (with StVK, or without hourglass control) holds.
fn paper_divergence_note(scene: &Scene, status: &RunStatus) -> Option<&'static str> {
    let paper = scene
        .particles
        .as_ref()
        .is_some_and(|p| p.model == palpate::scene::ParticleModel::Paper);
    (paper && status.divergence().is_some()).then_some(
        "note: the paper particle model's eq. 13 is one-sided (a particle is pushed by its neighbours' stresses, not by its own), so its forces are not an energy's gradient and at the layer's surface do work of their own; this grows at its own rate, so a smaller dt does not stop it (hm1 and lv_touch diverge at the same simulated time at dt and dt/2): use [particles] model = \"tlsph\"",
    )
}

/// What to do about inverted elements in `scene` (`particles`: some were particles).
fn inversion_advice(scene: &Scene, particles: bool) -> &'static str {
    let paper = scene
        .particles
        .as_ref()
        .is_some_and(|p| p.model == palpate::scene::ParticleModel::Paper);
    let stvk = scene.material.model == palpate::material::MaterialModel::Stvk;
    if particles && paper {
        "; the paper particle model's stress is StVK whatever the material (eq. 1-2), which pushes inverted particles towards their mirror image: use [particles] model = \"tlsph\" with [material] model = \"stable_neohookean\" for large compression, e.g. under a tool"
    } else if stvk {
        "; stvk pushes inverted elements towards their mirror image, not back (its energy is blind to reflections), so the force there is wrong: use [material] model = \"stable_neohookean\" for large compression, e.g. under a tool"
    } else {
        ": the force there is not the material's (a smaller dt or a finer mesh may help)"
    }
}

/// What `run` and `haptic` warn of before they start: [`warn_reoriented`], a tool
/// overlapping the tissue at `tool_at` (its centre, and when: "at t = 0"), and the scene's
/// loads far beyond its material.
fn warn_scene(scene: &Scene, tool_at: Option<(glam::DVec3, &str)>) {
    warn_reoriented(scene);
    if let Some((centre, when)) = tool_at {
        warn_tool_overlap(scene, centre, when);
    }
    for w in &scene.load_warnings {
        palpate::say_err!("warning: {w}");
    }
}

/// Warn of the tets the mesh validation reoriented (the first three, then the count) and of
/// coincident vertices (a mesh split where it looks joined).
fn warn_reoriented(scene: &Scene) {
    let r = &scene.mesh_report;
    let (pairs, count) = &r.coincident;
    if let Some((a, b)) = pairs.first() {
        palpate::say_err!(
            "warning: {}: vertices {a} and {b} lie at the same position{}: the tets on either side share no vertex there, so the mesh is split (merge the duplicates)",
            r.origin,
            if *count > 1 { format!(" ({count} such pairs)") } else { String::new() }
        );
    }
    for t in r.reoriented.iter().take(3) {
        palpate::say_err!(
            "warning: {}: tet {t} was inverted and has been reoriented",
            r.origin
        );
    }
    if r.reoriented.len() > 3 {
        palpate::say_err!(
            "warning: {}: {} tets reoriented in all",
            r.origin,
            r.reoriented.len()
        );
    }
}

/// Warn when the tool at `centre` starts inside the tissue at rest: its contact then shoves
/// the tissue out at once (or through the wall).
fn warn_tool_overlap(scene: &Scene, centre: glam::DVec3, when: &str) {
    if let Some(overlap) = scene
        .tool
        .as_ref()
        .and_then(|t| t.overlap(&scene.mesh, centre))
    {
        palpate::say_err!(
            "warning: {}: {when} the tool overlaps the tissue at rest: {overlap} (start the tool clear of the surface)",
            scene.origin
        );
    }
}

fn adapter_name(backend: Backend) -> String {
    match backend {
        Backend::Auto => match palpate::sim::pick_auto() {
            Ok((b, reason, _)) => format!("{} ({reason})", adapter_name(b)),
            Err(e) => e.to_string(),
        },
        Backend::Cpu => format!("cpu ({} threads)", palpate::cpu::stepper::available_cores()),
        Backend::Gpu => palpate::gpu::GpuContext::new()
            .map(|c| c.describe())
            .unwrap_or_else(|e| e.to_string()),
    }
}

#[cfg(test)]
mod tests {
    use super::{servo_rate_warning, substeps_note};
    use palpate::haptics::servo::ServoStats;

    /// The servo's shortfall is warned of: a rate under 95 % of the target, or over 1 % of
    /// the deadlines skipped; a session on time, or too short to tell, is not.
    #[test]
    fn a_servo_loop_short_of_its_rate_is_warned_of() {
        let stats = |ticks, rate_hz, missed_deadlines| ServoStats {
            ticks,
            rate_hz,
            target_rate_hz: 1000.0,
            missed_deadlines,
            ..Default::default()
        };
        assert_eq!(servo_rate_warning(&stats(5000, 999.8, 3)), None);
        assert_eq!(servo_rate_warning(&stats(50, 600.0, 40)), None);
        let slow = servo_rate_warning(&stats(821, 607.0, 2)).unwrap();
        assert!(
            slow.starts_with("warning: the servo loop ran at 607.0 Hz against its 1000 Hz"),
            "{slow}"
        );
        let skipping = servo_rate_warning(&stats(5000, 990.0, 60)).unwrap();
        assert!(
            skipping.contains("60 of its 5060 deadlines skipped"),
            "{skipping}"
        );
    }

    /// A run whose particle sub-steps were raised says so, with the layer's stiffening and
    /// the counts; one that kept the scene's count, or has no particle layer, does not.
    #[test]
    fn raised_particle_substeps_are_noted() {
        let note = substeps_note(Some(1), Some(6), Some(59.9)).unwrap();
        assert!(
            note.contains("59.9x") && note.contains("up to 6 per core step (the scene's: 1)"),
            "{note}"
        );
        assert_eq!(substeps_note(Some(1), Some(1), Some(1.4)), None);
        assert_eq!(substeps_note(None, None, None), None);
    }
}
