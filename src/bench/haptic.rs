//! `palpate bench haptic`: the servo loop and the physics thread together, on `lv` and `ed0`
//! with a tool added and on the default haptic scene `lv_touch`, per backend: tick rate,
//! lateness and model-age percentiles, missed deadlines, simulation steps/s, the realtime
//! factor and the physics' realtime capacity. A scripted device presses the tissue at
//! 0.5 Hz (sin² profile) for the whole run. Wall-clock numbers: run on a quiet machine.

use crate::error::Result;
use crate::haptic_run::{run_haptic, HapticOptions, HapticSummary};
use crate::output::{csv_field, write_atomic};
use crate::scene::Scene;
use crate::sim::Backend;
use glam::DVec3;
use std::fmt::Write as _;
use std::path::Path;

/// One benchmarked scene: how to build it and how to press it.
pub struct HapticCase {
    /// Label in the tables.
    pub label: &'static str,
    /// The scene with its tool.
    pub scene: Scene,
    /// Press direction (unit, device frame).
    pub direction: DVec3,
    /// Press depth from the tool's home, m.
    pub depth: f64,
}

/// The cases: `lv` + a 10 mm tool, `ed0` + a tool of radius 0.3 (unitless scene), and
/// `lv_touch` as shipped.
pub fn cases() -> Result<Vec<HapticCase>> {
    // `lv` as the haptic session tests use it: mass scaling 300 (the physics keeps up with
    // real time on 2 cores; at 100 it lags and the proxy and the physics fall into a
    // make-and-break contact cycle), mass damping near critical for the slowed wall, and
    // shear viscosity 20 Pa·s (without it the few surface vertices under the tool ring
    // against their contact springs).
    let lv = Scene::builtin_text("lv")
        .unwrap_or_default()
        .replace("duration = 0.1", "mass_scaling = 300.0")
        .replace("damping = 60.0", "damping = 11.5")
        .replace("viscosity = [0.0, 0.0]", "viscosity = [0.0, 20.0]")
        + "\n[tool]\nradius = 0.01\nstiffness = 1.0e8\ndamping = 2.0e4\nhome = [0.0207, 0.0, -0.005]\n";
    let ed0 = Scene::builtin_text("ed0").unwrap_or_default().to_string()
        + "\n[tool]\nradius = 0.3\nstiffness = 200.0\ndamping = 2.0\nhome = [0.0, 0.0, 1.62]\n";
    Ok(vec![
        HapticCase {
            label: "lv + tool",
            scene: Scene::from_toml(&lv, "lv + tool", "lv", None)?,
            direction: DVec3::NEG_X,
            depth: 0.004,
        },
        HapticCase {
            label: "ed0 + tool",
            scene: Scene::from_toml(&ed0, "ed0 + tool", "ed0", None)?,
            direction: DVec3::NEG_Z,
            depth: 0.06,
        },
        HapticCase {
            label: "lv_touch",
            scene: Scene::load("lv_touch")?,
            direction: DVec3::NEG_X,
            depth: 0.003,
        },
    ])
}

/// One session's numbers.
pub struct HapticRow {
    /// Case label.
    pub label: String,
    /// Backend and threads, e.g. `cpu ×1`.
    pub backend: String,
    /// The session's summary.
    pub summary: HapticSummary,
}

/// Press trajectory CSV: `depth·sin²(π t / 2)` along `direction` for `seconds`.
fn press_csv(direction: DVec3, depth: f64, seconds: f64) -> String {
    let mut s = String::from("t,x,y,z\n");
    let n = (seconds * 100.0).ceil() as usize;
    for i in 0..=n {
        let t = i as f64 / 100.0;
        let x = direction * (depth * (std::f64::consts::PI * t / 2.0).sin().powi(2));
        let _ = writeln!(s, "{t},{},{},{}", x.x, x.y, x.z);
    }
    s
}

/// Hand withdrawn `away` m against `direction` (clear of the wake margin) for the first half
/// of `seconds`, back to home over 0.5 s, then [`press_csv`]'s sin² presses.
fn away_then_press_csv(direction: DVec3, depth: f64, away: f64, seconds: f64) -> String {
    let half = 0.5 * seconds;
    let mut s = String::from("t,x,y,z\n");
    let n = (seconds * 100.0).ceil() as usize;
    for i in 0..=n {
        let t = i as f64 / 100.0;
        let x = if t < half {
            -direction * away
        } else if t < half + 0.5 {
            -direction * (away * (1.0 - (t - half) / 0.5))
        } else {
            let tp = t - half - 0.5;
            direction * (depth * (std::f64::consts::PI * tp / 2.0).sin().powi(2))
        };
        let _ = writeln!(s, "{t},{},{},{}", x.x, x.y, x.z);
    }
    s
}

/// What sleeping at rest saves: `lv_touch` with the hand 15 mm back from its home for the
/// first half of `seconds` and pressing 3 mm for the rest, on the CPU with `threads`, with
/// and without sleep (rows labelled `… sleep` / `… no sleep`).
pub fn sleep_study(threads: usize, seconds: f64, scratch: &Path) -> Result<Vec<HapticRow>> {
    std::fs::create_dir_all(scratch).map_err(|source| crate::error::PalpateError::OutputIo {
        path: scratch.to_path_buf(),
        source,
    })?;
    let scene = Scene::load("lv_touch")?;
    let csv = scratch.join("lv_touch_away.csv");
    write_atomic(
        &csv,
        away_then_press_csv(DVec3::NEG_X, 0.003, 0.015, seconds).as_bytes(),
    )?;
    let mut rows = Vec::new();
    for sleep in [true, false] {
        let summary = run_session(
            &scene,
            &HapticOptions {
                backend: Backend::Cpu,
                threads: Some(threads),
                device: format!("scripted:{}", csv.display()),
                out: scratch.join(if sleep { "away-sleep" } else { "away-nosleep" }),
                sleep_at_rest: sleep,
                ..Default::default()
            },
        )?;
        rows.push(HapticRow {
            label: "lv_touch, hand away half the time".into(),
            backend: format!(
                "cpu ×{threads}, {}",
                if sleep { "sleep" } else { "no sleep" }
            ),
            summary,
        });
    }
    Ok(rows)
}

/// [`run_haptic`] on a thread of its own, as `palpate haptic` runs a session on a fresh
/// process's main thread: a one-thread session makes its physics thread a pool of its own for
/// good (`SimOptions::step_on_this_thread`), which the next sessions must not inherit.
fn run_session(scene: &Scene, opts: &HapticOptions) -> Result<HapticSummary> {
    std::thread::scope(|s| {
        let session = std::thread::Builder::new()
            .name("palpate-bench-session".into())
            .stack_size(8 << 20)
            .spawn_scoped(s, || run_haptic(scene, opts))
            .map_err(|e| {
                crate::error::PalpateError::Internal(format!("cannot start a session thread: {e}"))
            })?;
        session
            .join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
    })
}

/// Run every case on every (backend, threads) of `runs` for `seconds` each.
pub fn study(
    runs: &[(Backend, Option<usize>)],
    seconds: f64,
    scratch: &Path,
    log: &mut dyn FnMut(&str),
) -> Result<Vec<HapticRow>> {
    std::fs::create_dir_all(scratch).map_err(|source| crate::error::PalpateError::OutputIo {
        path: scratch.to_path_buf(),
        source,
    })?;
    let mut rows = Vec::new();
    for case in cases()? {
        let csv = scratch.join(format!("{}.csv", case.scene.name));
        write_atomic(
            &csv,
            press_csv(case.direction, case.depth, seconds).as_bytes(),
        )?;
        for &(backend, threads) in runs {
            let out = scratch.join(match (backend, threads) {
                (Backend::Gpu, _) => format!("{}-gpu", case.scene.name),
                (_, Some(t)) => format!("{}-cpu{t}", case.scene.name),
                _ => format!("{}-cpu", case.scene.name),
            });
            let summary = run_session(
                &case.scene,
                &HapticOptions {
                    backend,
                    threads,
                    device: format!("scripted:{}", csv.display()),
                    out,
                    ..Default::default()
                },
            )?;
            let label = match summary.run.backend {
                Backend::Gpu => format!("gpu ({})", summary.run.adapter),
                _ => format!("cpu ×{}", summary.run.threads),
            };
            log(&format!(
                "{}: {label}: {:.1} Hz, lateness p99 {:.0} us, model age p99 {:.2} ms, realtime {:.2} (capacity {:.2})",
                case.label,
                summary.haptic.servo.rate_hz,
                summary.haptic.servo.lateness_us.p99,
                summary.haptic.servo.model_age_ms.p99,
                summary.run.realtime_factor,
                summary.haptic.physics.realtime_capacity
            ));
            rows.push(HapticRow {
                label: case.label.to_string(),
                backend: label,
                summary,
            });
        }
    }
    Ok(rows)
}

/// Write `haptic_bench.csv` and `haptic_bench.md` into `out` (not `haptic.csv`, the name of a
/// session's per-tick log).
pub fn write(out: &Path, rows: &[HapticRow], header: &str) -> Result<()> {
    std::fs::create_dir_all(out).map_err(|source| crate::error::PalpateError::OutputIo {
        path: out.to_path_buf(),
        source,
    })?;
    let mut csv = String::from(
        "scene,backend,tets,particles,ticks,rate_hz,lateness_p50_us,lateness_p99_us,lateness_p99_9_us,lateness_max_us,missed_deadlines,model_age_p50_ms,model_age_p99_ms,model_age_max_ms,steps_per_second,dt_s,realtime_factor,realtime_capacity,busy_fraction,active_particles_max,passivity_min_j,status,steps,slept_s\n",
    );
    let mut md = format!(
        "# Haptic loop\n\n{header}\n\n| scene | backend | tets | particles | rate Hz | lateness p50 / p99 / p99.9 / max µs | missed | model age p50 / p99 / max ms | steps/s | realtime | capacity | busy | asleep s |\n|---|---|---:|---:|---:|---|---:|---|---:|---:|---:|---:|---:|\n"
    );
    for r in rows {
        let s = &r.summary;
        let v = &s.haptic.servo;
        let (l, a) = (&v.lateness_us, &v.model_age_ms);
        let _ = writeln!(
            csv,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            csv_field(&r.label),
            csv_field(&r.backend),
            s.run.tets,
            s.run.particles,
            v.ticks,
            v.rate_hz,
            l.p50,
            l.p99,
            l.p99_9,
            l.max,
            v.missed_deadlines,
            a.p50,
            a.p99,
            a.max,
            s.run.steps_per_second,
            s.run.dt,
            s.run.realtime_factor,
            s.haptic.physics.realtime_capacity,
            s.haptic.physics.busy_fraction,
            s.run.active_particles_max.unwrap_or(0),
            v.passivity_min_energy_j,
            csv_field(&s.run.status.to_string()),
            s.run.steps,
            s.haptic.physics.slept_seconds
        );
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {:.1} | {:.1} / {:.0} / {:.0} / {:.0} | {} | {:.2} / {:.2} / {:.2} | {:.0} | {:.2} | {:.2} | {:.2} | {:.2} |",
            r.label,
            r.backend,
            s.run.tets,
            s.run.particles,
            v.rate_hz,
            l.p50,
            l.p99,
            l.p99_9,
            l.max,
            v.missed_deadlines,
            a.p50,
            a.p99,
            a.max,
            s.run.steps_per_second,
            s.run.realtime_factor,
            s.haptic.physics.realtime_capacity,
            s.haptic.physics.busy_fraction,
            s.haptic.physics.slept_seconds
        );
    }
    md.push_str("\nrealtime = simulated / wall seconds (the physics never runs ahead of the loop clock, so at most 1); capacity = simulated seconds stepped per second of batch work (what it could reach; ≥ 1 keeps up with the hand); busy = the physics thread's share of wall time spent in batches; asleep = simulated seconds that passed with the body at rest and the tool clear of it, unstepped (`palpate haptic --no-sleep` steps them). Lateness: how late each servo tick started after its deadline; model age: servo read of the device → the local model computed from it, as used by a tick.\n");
    write_atomic(&out.join("haptic_bench.csv"), csv.as_bytes())?;
    write_atomic(&out.join("haptic_bench.md"), md.as_bytes())
}
