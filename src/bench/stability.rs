//! `palpate bench stability`: (a) the largest stable dt per material and mesh, by bisection,
//! as a ratio to our wave-speed bound and to the paper's eq. 14; (b) squash the beam to 10 %
//! of its height and release; (c) start from randomly inverted elements; (d) a probe pushing
//! at 10× a haptic device's maximum force; (e) a long ED0 run, energy bounded; (f) the
//! paper's Table 1 scenes at the paper's dt. Writes `stability.csv` and `stability.md`.

use super::{beam_scene, kinetic, load_work, lv_scene};
use crate::error::{PalpateError, Result};
use crate::inversion::inverted_tets;
use crate::material::MaterialModel;
use crate::model::Model;
use crate::scene::Scene;
use crate::sim::{Advance, Backend, DivergencePolicy, Guarded, SimOptions, Simulation};
use crate::stepper::State;
use glam::DVec3;
use std::fmt::Write;
use std::path::Path;
use std::sync::Arc;

/// Peak force of a desktop haptic device (Geomagic Touch class), N; the probe case pushes 10×.
pub const DEVICE_MAX_FORCE: f64 = 3.3;

/// The safety factor `dt = "auto"` uses (re-exported for the stress tests).
pub const DEFAULT_SAFETY_CHECK: f64 = crate::timestep::DEFAULT_SAFETY;

/// Mass-proportional damping of the release cases (b) and (c), 1/s.
pub const RELEASE_DAMPING: f64 = 200.0;

/// Radius of the probe's contact patch in case (d), m.
pub const PROBE_RADIUS: f64 = 0.005;

/// Steps of the long ED0 run in the full study.
pub const ED0_STEPS: u64 = 1_000_000;

/// Steps of the long ED0 run with `--quick` (seconds, where the full run takes minutes).
pub const QUICK_ED0_STEPS: u64 = 20_000;

/// How much to run.
#[derive(Clone, Copy, Debug)]
pub struct StabilityOptions {
    /// Backend.
    pub backend: Backend,
    /// CI-sized: fewer meshes, steps and bisection rounds.
    pub quick: bool,
    /// Steps of the long ED0 run (1e6 for the full study).
    pub ed0_steps: u64,
}

/// Builds a scene for a material model.
type SceneMaker = Box<dyn Fn(MaterialModel) -> Result<Scene>>;

/// One result row.
#[derive(Clone, Debug)]
pub struct Row {
    /// Case (a)–(f).
    pub case: String,
    /// Material model.
    pub material: String,
    /// Mesh / scene.
    pub mesh: String,
    /// What was measured.
    pub quantity: String,
    /// The number.
    pub value: f64,
    /// Survived / recovered / stable.
    pub ok: bool,
}

struct Rng(u64);
impl Rng {
    fn sym(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    }
}

fn sim(model: &Arc<Model>, backend: Backend, dt: f64, damping: f64) -> Result<Simulation> {
    Simulation::from_model(model.clone(), backend, dt, damping, SimOptions::default())
}

/// Most dt halvings a stress case allows: each halving doubles the remaining steps, and a
/// case that still diverges at dt/64 is reported as diverged.
pub const STRESS_MAX_HALVINGS: u32 = 6;

/// Run for `duration` s from the current state under the `halve-dt` divergence policy (at most
/// [`STRESS_MAX_HALVINGS`] times). Returns the halvings, or None when it still diverged.
fn run_halving(s: &mut Simulation, duration: f64) -> Result<Option<u32>> {
    let end = s.time + duration;
    s.max_halvings = s.halvings + STRESS_MAX_HALVINGS;
    let start = s.halvings;
    while s.time < end - 0.5 * s.dt {
        let n = (((end - s.time) / s.dt).round() as u64).clamp(1, 500);
        if let Guarded::Diverged { .. } = s.advance_with(n as u32, DivergencePolicy::HalveDt)? {
            return Ok(None);
        }
    }
    Ok(Some(s.halvings - start))
}

/// Run `steps` in batches; Err(step) on divergence.
fn run_for(s: &mut Simulation, steps: u64) -> Result<std::result::Result<(), u64>> {
    let mut left = steps;
    while left > 0 {
        let b = left.min(500);
        if let Advance::Diverged { step, .. } = s.advance(b as u32)? {
            return Ok(Err(step));
        }
        left -= b;
    }
    Ok(Ok(()))
}

/// Stable for `steps` steps at `ratio` × the bound, from rest plus a small random velocity
/// (1e-3 c_p) that excites every mode.
fn stable_at(scene: &Scene, backend: Backend, ratio: f64, steps: u64) -> Result<bool> {
    let model = Arc::new(Model::from_scene(scene));
    let mut s = sim(&model, backend, ratio * model.bounds.dt_bound, 0.0)?;
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let a = 1e-3 * model.material.p_wave_speed();
    let velocities = (0..3 * model.n_vertices())
        .map(|k| {
            if model.inv_mass[k / 3] > 0.0 {
                (a * rng.sym()) as f32
            } else {
                0.0
            }
        })
        .collect();
    s.set_state(&State {
        displacements: vec![0.0; 3 * model.n_vertices()],
        velocities,
    })?;
    Ok(run_for(&mut s, steps)?.is_ok())
}

/// Largest stable dt / dt_bound, by bisection between a stable and an unstable ratio.
pub fn critical_ratio(scene: &Scene, backend: Backend, steps: u64, rounds: usize) -> Result<f64> {
    let (mut lo, mut hi) = (0.25, 4.0);
    if !stable_at(scene, backend, lo, steps)? {
        return Ok(0.0);
    }
    while stable_at(scene, backend, hi, steps)? {
        lo = hi;
        hi *= 2.0;
        if hi > 64.0 {
            return Ok(hi);
        }
    }
    for _ in 0..rounds {
        let mid = 0.5 * (lo + hi);
        if stable_at(scene, backend, mid, steps)? {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Ok(lo)
}

/// Elastic energy of the simulation's current state, J.
fn squash_energy(model: &Model, s: &mut Simulation) -> Result<f64> {
    Ok(super::elastic_energy(model, &s.state()?))
}

fn free_beam(cells: [usize; 3], material: MaterialModel) -> Result<Arc<Model>> {
    let scene = beam_scene(cells, material)?;
    Ok(Arc::new(Model::new(
        &scene.mesh,
        &vec![false; scene.mesh.n_vertices()],
        scene.material,
        [0.0; 3],
    )))
}

/// Run every case and return the rows.
pub fn study(opts: &StabilityOptions, progress: &mut dyn FnMut(&str)) -> Result<Vec<Row>> {
    let mut rows = Vec::new();
    let b = opts.backend;
    let (steps, rounds) = if opts.quick { (800, 4) } else { (3000, 7) };
    let meshes: Vec<(&str, SceneMaker)> = if opts.quick {
        vec![("beam 10x2x2", Box::new(|m| beam_scene([10, 2, 2], m)))]
    } else {
        vec![
            ("beam 10x2x2", Box::new(|m| beam_scene([10, 2, 2], m))),
            ("beam 20x4x4", Box::new(|m| beam_scene([20, 4, 4], m))),
            ("lv k=2", Box::new(|m| lv_scene(2, m))),
        ]
    };
    // (a) critical dt
    for (mesh, make) in &meshes {
        for material in MaterialModel::ALL {
            progress(&format!("(a) critical dt: {mesh}, {}", material.name()));
            let scene = make(material)?;
            let model = Model::from_scene(&scene);
            let r = critical_ratio(&scene, b, steps, rounds)?;
            let paper = r * model.bounds.dt_bound / model.bounds.dt_paper_eq14;
            let row = |q: &str, v: f64| Row {
                case: "a".into(),
                material: material.name().into(),
                mesh: mesh.to_string(),
                quantity: q.into(),
                value: v,
                ok: r > 0.0,
            };
            rows.push(row("dt_crit / dt_bound", r));
            rows.push(row("dt_crit / dt_paper_eq14", paper));
        }
    }
    // (b) squash to 10 % and release; (c) random inversion
    let cells = if opts.quick { [10, 2, 2] } else { [20, 4, 4] };
    let mesh_name = format!("free beam {}x{}x{}", cells[0], cells[1], cells[2]);
    for material in MaterialModel::ALL {
        progress(&format!("(b) squash: {}", material.name()));
        let model = free_beam(cells, material)?;
        let dt = 0.25 * model.bounds.dt_bound;
        let displacements: Vec<f32> = (0..model.n_vertices())
            .flat_map(|i| [0.0, 0.0, -0.9 * model.rest[3 * i + 2]])
            .collect();
        // Damping α = 200/s: the release ringing (through-thickness mode) decays by e^-5
        // in 0.05 s, so "recovered" is judged at rest, not mid-swing.
        let mut s = sim(&model, b, dt, RELEASE_DAMPING)?;
        s.set_state(&State {
            displacements,
            velocities: vec![0.0; 3 * model.n_vertices()],
        })?;
        let duration = if opts.quick { 0.05 } else { 0.2 };
        let e0 = squash_energy(&model, &mut s)?;
        let outcome = run_halving(&mut s, duration)?;
        let st = s.state()?;
        let inv = inverted_tets(&model, &st);
        let e1 = s.last.elastic_energy();
        // Recovered: the stored energy is gone (a rigid rotation of the free beam costs none)
        // and no element is left inverted.
        let recovered = outcome.is_some() && e1 < 1e-3 * e0 && inv == 0;
        let halved = outcome
            .map(|h| format!(", dt halved {h}x"))
            .unwrap_or_else(|| ", diverged".into());
        rows.push(Row {
            case: "b".into(),
            material: material.name().into(),
            mesh: mesh_name.clone(),
            quantity: format!("elastic energy after / at squash{halved}"),
            value: e1 / e0,
            ok: recovered,
        });
        rows.push(Row {
            case: "b".into(),
            material: material.name().into(),
            mesh: mesh_name.clone(),
            quantity: "inverted tets after release".into(),
            value: inv as f64,
            ok: recovered,
        });

        progress(&format!("(c) random inversion: {}", material.name()));
        let scene = beam_scene(cells, material)?;
        let boundary = scene.mesh.boundary_vertices();
        let cell = 0.1 / cells[0] as f64;
        let mut rng = Rng(42);
        let displacements: Vec<f32> = (0..model.n_vertices())
            .flat_map(|i| {
                let interior = boundary.binary_search(&(i as u32)).is_err();
                // Up to 1.6 cells: far enough to leave the vertex's star and invert tets.
                let d = if interior {
                    DVec3::new(rng.sym(), rng.sym(), rng.sym()) * 1.6 * cell
                } else {
                    DVec3::ZERO
                };
                d.to_array().map(|c| c as f32)
            })
            .collect();
        let start = State {
            displacements,
            velocities: vec![0.0; 3 * model.n_vertices()],
        };
        let inv0 = inverted_tets(&model, &start);
        let mut s = sim(&model, b, dt, RELEASE_DAMPING)?;
        s.set_state(&start)?;
        let outcome = run_halving(&mut s, if opts.quick { 0.05 } else { 0.2 })?;
        let st = s.state()?;
        let inv1 = inverted_tets(&model, &st);
        let ok = outcome.is_some() && inv1 == 0 && inv0 > 0;
        let halved = outcome
            .map(|h| format!(", dt halved {h}x"))
            .unwrap_or_else(|| ", diverged".into());
        rows.push(Row {
            case: "c".into(),
            material: material.name().into(),
            mesh: mesh_name.clone(),
            quantity: "inverted tets at start".into(),
            value: inv0 as f64,
            ok: inv0 > 0,
        });
        rows.push(Row {
            case: "c".into(),
            material: material.name().into(),
            mesh: mesh_name.clone(),
            quantity: format!("inverted tets at end ({inv0} at start{halved})"),
            value: inv1 as f64,
            ok,
        });
    }
    // (d) a probe pushing down on the cantilever's free end at 10x a device's maximum force
    for material in MaterialModel::ALL {
        progress(&format!(
            "(d) probe at {:.0} N: {}",
            10.0 * DEVICE_MAX_FORCE,
            material.name()
        ));
        let mut scene = beam_scene(cells, material)?;
        let tip: Vec<usize> = (0..scene.mesh.n_vertices())
            .filter(|&i| (scene.mesh.positions[i].x - 0.1).abs() < 1e-9)
            .collect();
        for &i in &tip {
            scene.external_forces[i] +=
                DVec3::new(0.0, 0.0, -10.0 * DEVICE_MAX_FORCE / tip.len() as f64);
        }
        let model = Arc::new(Model::from_scene(&scene));
        let mut s = sim(&model, b, 0.5 * model.bounds.dt_bound, 60.0)?;
        let outcome = run_halving(&mut s, if opts.quick { 0.05 } else { 0.2 })?;
        let st = s.state()?;
        let umax = crate::run::max_displacement(&st.displacements);
        let inv = inverted_tets(&model, &st);
        let halved = outcome
            .map(|h| format!("dt halved {h}x"))
            .unwrap_or_else(|| "diverged".into());
        rows.push(Row {
            case: "d".into(),
            material: material.name().into(),
            mesh: format!("beam {}x{}x{}", cells[0], cells[1], cells[2]),
            quantity: format!("max displacement, m ({halved}; {inv} inverted tets)"),
            value: umax,
            ok: outcome.is_some() && umax.is_finite() && inv == 0,
        });
    }
    // (e) long ED0 run: total energy bounded
    progress(&format!("(e) ed0 for {} steps", opts.ed0_steps));
    let scene = Scene::load("ed0")?;
    let model = Arc::new(Model::from_scene(&scene));
    let dt = crate::sim::choose_dt(&scene, &model, None, false, false)?;
    let mut s = sim(&model, b, dt, 0.0)?;
    let mut done = 0u64;
    let (mut e_max, mut el_max) = (0.0f64, 0.0f64);
    let chunk = (opts.ed0_steps / 100).max(100);
    let mut ok = true;
    while done < opts.ed0_steps {
        let n = chunk.min(opts.ed0_steps - done);
        if run_for(&mut s, n)?.is_err() {
            ok = false;
            break;
        }
        done += n;
        let st = s.state()?;
        let el = s.last.elastic_energy();
        let e = kinetic(&model, &st) + el - load_work(&model, &st);
        e_max = e_max.max(e);
        el_max = el_max.max(el);
    }
    // Energy starts at 0 and viscosity only removes it: the total may not rise above 0 by
    // more than 1 % of the largest elastic energy.
    let bounded = ok && e_max <= 0.01 * el_max;
    rows.push(Row {
        case: "e".into(),
        material: "stvk".into(),
        mesh: "ed0".into(),
        quantity: format!("max total energy / max elastic energy over {done} steps"),
        value: e_max / el_max.max(f64::MIN_POSITIVE),
        ok: bounded,
    });
    // (f) the paper's Table 1 scenes at the paper's dt
    for name in ["ed0", "hm1", "hm2"] {
        progress(&format!("(f) {name} at the paper's dt"));
        let scene = Scene::load(name)?;
        let model = Arc::new(Model::from_scene(&scene));
        let dt = scene.solver.dt.unwrap_or(model.bounds.dt_bound);
        let mut s = sim(&model, b, dt, scene.solver.damping)?;
        let n = if opts.quick { 500 } else { 5000 };
        let outcome = run_for(&mut s, n)?;
        rows.push(Row {
            case: "f".into(),
            material: "stvk".into(),
            mesh: name.into(),
            quantity: format!(
                "paper dt {dt:.1e} / dt_bound {:.2e}; {}",
                model.bounds.dt_bound,
                match outcome {
                    Ok(()) => format!("{n} steps ok"),
                    Err(step) => format!("diverged at step {step}"),
                }
            ),
            value: dt / model.bounds.dt_bound,
            ok: outcome.is_ok(),
        });
    }
    Ok(rows)
}

/// Write `stability.csv` and `stability.md` into `dir`.
pub fn write(dir: &Path, rows: &[Row], header: &str) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|source| PalpateError::OutputIo {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut csv = String::from("case,material,mesh,quantity,value,ok\n");
    let mut md = format!("# Stability study\n\n{header}\n\n| case | material | mesh | quantity | value | ok |\n|---|---|---|---|---:|---|\n");
    for r in rows {
        let _ = writeln!(
            csv,
            "{},{},{},\"{}\",{},{}",
            r.case, r.material, r.mesh, r.quantity, r.value, r.ok
        );
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {:.4} | {} |",
            r.case,
            r.material,
            r.mesh,
            r.quantity,
            r.value,
            if r.ok { "yes" } else { "**no**" }
        );
    }
    crate::output::write_atomic(&dir.join("stability.csv"), csv.as_bytes())?;
    crate::output::write_atomic(&dir.join("stability.md"), md.as_bytes())
}
