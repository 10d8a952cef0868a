//! `palpate bench accuracy`: run time against error for two reference problems.
//!
//! * `beam`: the built-in cantilever released from rest under gravity; observable: the tip
//!   deflection (mean vertical displacement of the vertices at x = L) over the first 0.1 s.
//! * `lv`: the built-in left ventricle (base fixed, the scene's damping α = 60/s) under a
//!   suddenly applied 1 kPa endocardial pressure; observable: the change of cavity volume over the first 0.05 s,
//!   ΔV = −⅓ Σ_endocardial faces (x·n A)|deformed − the same at rest (the base cap is fixed
//!   with the base, so it drops out). Mesh parameter: the LV resolution k.
//!
//! Error = max over sample times |obs(t) − obs_ref(t)| / max |obs_ref|, with the reference
//! linearly interpolated. The reference is the finest mesh at a quarter of the stable step;
//! its own convergence is estimated by comparing it with the next-coarser mesh and with the
//! same mesh at twice the step, and both numbers are written beside the results.
//!
//! Writes `accuracy.csv` (both problems) and `accuracy.png` / `accuracy_lv.png` (log-log error
//! versus wall time, Pareto front).

use super::{beam_scene, lv_scene};
use crate::error::{PalpateError, Result};
use crate::material::MaterialModel;
use crate::model::Model;
use crate::output::png::{loglog_plot, pareto_front, PlotPoint};
use crate::scene::Scene;
use crate::sim::{Advance, Backend, SimOptions, Simulation};
use std::fmt::Write;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

/// A reference problem.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Problem {
    /// Cantilever under gravity, tip deflection.
    Beam,
    /// Left ventricle under endocardial pressure, cavity volume change.
    Lv,
}

impl Problem {
    /// Name in files.
    pub fn name(self) -> &'static str {
        match self {
            Problem::Beam => "beam",
            Problem::Lv => "lv",
        }
    }

    /// Simulated time of each run, s.
    pub fn duration(self) -> f64 {
        match self {
            Problem::Beam => 0.1,
            Problem::Lv => 0.05,
        }
    }

    /// The scene at mesh parameter `cells` (beam: cells; LV: cells[0] = k).
    fn scene(self, cells: [usize; 3]) -> Result<Scene> {
        match self {
            Problem::Beam => beam_scene(cells, MaterialModel::Stvk),
            Problem::Lv => lv_scene(cells[0], MaterialModel::Stvk),
        }
    }

    /// What is observed: the beam's tip vertices, or the LV's endocardial faces.
    fn observer(self, scene: &Scene, model: &Model) -> Observer {
        match self {
            Problem::Beam => Observer::Tip(
                (0..model.n_vertices())
                    .filter(|&i| (model.rest[3 * i] - 0.1).abs() < 1e-6)
                    .collect(),
            ),
            Problem::Lv => {
                let endo = crate::mesh::tags::ENDOCARDIUM;
                let tags = &scene.mesh.vertex_tags;
                let faces = scene.mesh.boundary_faces();
                Observer::Cavity(
                    faces
                        .into_iter()
                        .filter(|f| f.iter().all(|&v| tags[v as usize] & endo != 0))
                        .collect(),
                )
            }
        }
    }

    /// Mesh label.
    pub fn label(self, cells: [usize; 3]) -> String {
        match self {
            Problem::Beam => format!("{}x{}x{}", cells[0], cells[1], cells[2]),
            Problem::Lv => format!("k={}", cells[0]),
        }
    }
}

/// The observable of a problem.
enum Observer {
    /// Mean downward displacement of these vertices, m.
    Tip(Vec<usize>),
    /// Change of the volume enclosed by these (solid-outward) faces, m³.
    Cavity(Vec<[u32; 3]>),
}

impl Observer {
    fn observe(&self, model: &Model, u: &[f32]) -> f64 {
        match self {
            Observer::Tip(v) => {
                -v.iter().map(|&i| u[3 * i + 2] as f64).sum::<f64>() / v.len() as f64
            }
            Observer::Cavity(faces) => {
                let at = |i: u32, moved: bool| {
                    let i = i as usize;
                    glam::DVec3::from_array(std::array::from_fn(|k| {
                        model.rest[3 * i + k] as f64 + if moved { u[3 * i + k] as f64 } else { 0.0 }
                    }))
                };
                let volume = |moved: bool| {
                    -faces
                        .iter()
                        .map(|f| at(f[0], moved).dot(at(f[1], moved).cross(at(f[2], moved))) / 6.0)
                        .sum::<f64>()
                };
                volume(true) - volume(false)
            }
        }
    }
}

/// Options.
#[derive(Clone, Copy, Debug)]
pub struct AccuracyOptions {
    /// Backend the run times are measured on.
    pub backend: Backend,
    /// CI-sized sweep.
    pub quick: bool,
}

/// One run of the sweep.
#[derive(Clone, Debug)]
pub struct Run {
    /// Problem.
    pub problem: Problem,
    /// Mesh parameter (beam cells; LV: [k, 0, 0]).
    pub cells: [usize; 3],
    /// Tets.
    pub tets: usize,
    /// dt / stability bound.
    pub safety: f64,
    /// Time step, s.
    pub dt: f64,
    /// Steps taken.
    pub steps: u64,
    /// Wall-clock seconds of stepping (sampling readbacks excluded).
    pub wall_seconds: f64,
    /// Observable history (t, value: m for the beam tip, m³ for the LV cavity).
    pub history: Vec<(f64, f64)>,
    /// Relative error against the reference (NaN for the reference itself).
    pub error: f64,
}

/// Run `problem` on mesh `cells` at `safety` × bound, sampling the observable `samples`
/// times; None when it diverged.
pub fn run_case(
    problem: Problem,
    cells: [usize; 3],
    safety: f64,
    backend: Backend,
    samples: usize,
) -> Result<Option<Run>> {
    let scene = problem.scene(cells)?;
    let model = Arc::new(Model::from_scene(&scene));
    let dt = safety * model.bounds.dt_bound;
    let opts = SimOptions {
        allow_unstable: true,
        ..Default::default()
    };
    let mut sim = Simulation::from_model(model.clone(), backend, dt, scene.solver.damping, opts)?;
    let observer = problem.observer(&scene, &model);
    let total = (problem.duration() / dt).round() as u64;
    let mut history = vec![(0.0, 0.0)];
    let mut wall = 0.0;
    for k in 1..=samples {
        let target = total * k as u64 / samples as u64;
        while sim.steps_done < target {
            let n = (target - sim.steps_done).min(500) as u32;
            let t0 = Instant::now();
            let r = sim.advance(n)?;
            wall += t0.elapsed().as_secs_f64();
            if let Advance::Diverged { .. } = r {
                return Ok(None);
            }
        }
        let u = sim.state()?.displacements;
        history.push((sim.time, observer.observe(&model, &u)));
    }
    Ok(Some(Run {
        problem,
        cells,
        tets: model.n_tets(),
        safety,
        dt,
        steps: sim.steps_done,
        wall_seconds: wall,
        history,
        error: f64::NAN,
    }))
}

fn interpolate(h: &[(f64, f64)], t: f64) -> f64 {
    let k = h.partition_point(|(ti, _)| *ti < t).clamp(1, h.len() - 1);
    let ((t0, y0), (t1, y1)) = (h[k - 1], h[k]);
    y0 + (y1 - y0) * ((t - t0) / (t1 - t0)).clamp(0.0, 1.0)
}

/// max_t |a(t) − ref(t)| / max |ref|.
pub fn history_error(a: &[(f64, f64)], reference: &[(f64, f64)]) -> f64 {
    let scale = reference.iter().map(|(_, y)| y.abs()).fold(0.0, f64::max);
    a.iter()
        .map(|&(t, y)| (y - interpolate(reference, t)).abs())
        .fold(0.0, f64::max)
        / scale
}

/// The sweep of one problem: runs, and the reference's estimated errors (mesh, time step).
pub struct Study {
    /// Problem.
    pub problem: Problem,
    /// Sweep runs.
    pub runs: Vec<Run>,
    /// Reference mesh and safety.
    pub reference: ([usize; 3], f64),
    /// Reference vs next-coarser mesh (an estimate of its mesh error).
    pub reference_mesh_change: f64,
    /// Reference vs twice its step (an estimate of its time-step error).
    pub reference_dt_change: f64,
    /// Runs that diverged: (mesh, safety).
    pub diverged: Vec<([usize; 3], f64)>,
}

/// The meshes, safety factors, reference and next-coarser mesh of a sweep.
type Sweep = (Vec<[usize; 3]>, Vec<f64>, [usize; 3], [usize; 3]);

fn sweep(problem: Problem, quick: bool) -> Sweep {
    match (problem, quick) {
        (Problem::Beam, true) => (
            vec![[5, 1, 1], [10, 2, 2]],
            vec![0.9, 0.5],
            [20, 4, 4],
            [10, 2, 2],
        ),
        (Problem::Beam, false) => (
            vec![[10, 2, 2], [15, 3, 3], [20, 4, 4], [30, 6, 6]],
            vec![0.9, 0.5, 0.25],
            [40, 8, 8],
            [30, 6, 6],
        ),
        (Problem::Lv, true) => (
            vec![[1, 0, 0], [2, 0, 0]],
            vec![0.9, 0.5],
            [3, 0, 0],
            [2, 0, 0],
        ),
        (Problem::Lv, false) => (
            vec![[2, 0, 0], [3, 0, 0], [4, 0, 0], [6, 0, 0]],
            vec![0.9, 0.5, 0.25],
            [8, 0, 0],
            [6, 0, 0],
        ),
    }
}

/// Run the sweep of `problem`.
pub fn study(
    problem: Problem,
    opts: &AccuracyOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<Study> {
    let (meshes, safeties, reference, coarser) = sweep(problem, opts.quick);
    let fine = 200;
    progress(&format!(
        "{}: reference {} at 0.25 x bound",
        problem.name(),
        problem.label(reference)
    ));
    let missing = || PalpateError::Usage("the reference run diverged".into());
    let r = run_case(problem, reference, 0.25, opts.backend, fine)?.ok_or_else(missing)?;
    progress(&format!("{}: reference checks", problem.name()));
    let r_dt = run_case(problem, reference, 0.5, opts.backend, fine)?.ok_or_else(missing)?;
    let r_mesh = run_case(problem, coarser, 0.25, opts.backend, fine)?.ok_or_else(missing)?;
    let mut runs = Vec::new();
    let mut diverged = Vec::new();
    for &cells in &meshes {
        for &s in &safeties {
            progress(&format!(
                "{}: {} at {s} x bound",
                problem.name(),
                problem.label(cells)
            ));
            match run_case(problem, cells, s, opts.backend, 40)? {
                Some(mut run) => {
                    run.error = history_error(&run.history, &r.history);
                    runs.push(run);
                }
                None => diverged.push((cells, s)),
            }
        }
    }
    Ok(Study {
        problem,
        reference_mesh_change: history_error(&r_mesh.history, &r.history),
        reference_dt_change: history_error(&r_dt.history, &r.history),
        reference: (reference, 0.25),
        runs,
        diverged,
    })
}

/// Write `accuracy.csv` (all studies) and one plot per study (`accuracy.png` for the beam,
/// `accuracy_<problem>.png` otherwise) into `dir`; returns each study's Pareto-optimal runs.
pub fn write(dir: &Path, studies: &[Study], adapter: &str) -> Result<Vec<Vec<usize>>> {
    std::fs::create_dir_all(dir).map_err(|source| PalpateError::OutputIo {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut csv = format!("# adapter: {adapter}\n");
    for st in studies {
        let _ = writeln!(
            csv,
            "# {}: reference {} at {} x bound; reference vs next-coarser mesh {:.3e}, vs 2x dt {:.3e}",
            st.problem.name(),
            st.problem.label(st.reference.0),
            st.reference.1,
            st.reference_mesh_change,
            st.reference_dt_change
        );
    }
    csv.push_str("problem,mesh,tets,safety,dt_s,steps,wall_seconds,error,pareto\n");
    let mut fronts = Vec::new();
    for st in studies {
        let mut labels: Vec<String> = Vec::new();
        for r in &st.runs {
            let l = st.problem.label(r.cells);
            if !labels.contains(&l) {
                labels.push(l);
            }
        }
        let points: Vec<PlotPoint> = st
            .runs
            .iter()
            .map(|r| PlotPoint {
                x: r.wall_seconds.max(1e-6),
                y: r.error.max(1e-9),
                series: labels
                    .iter()
                    .position(|l| *l == st.problem.label(r.cells))
                    .unwrap_or(0),
            })
            .collect();
        let front = pareto_front(&points);
        for (i, r) in st.runs.iter().enumerate() {
            let _ = writeln!(
                csv,
                "{},{},{},{},{:e},{},{:.4},{:.4e},{}",
                st.problem.name(),
                st.problem.label(r.cells),
                r.tets,
                r.safety,
                r.dt,
                r.steps,
                r.wall_seconds,
                r.error,
                front.contains(&i)
            );
        }
        for (c, s) in &st.diverged {
            let _ = writeln!(
                csv,
                "{},{},,{s},,,,diverged,false",
                st.problem.name(),
                st.problem.label(*c)
            );
        }
        let y_label = match st.problem {
            Problem::Beam => "beam tip error (rel, max over t)",
            Problem::Lv => "lv cavity volume error (rel, max over t)",
        };
        let canvas = loglog_plot(&points, &front, "run time [s]", y_label, &labels);
        let name = match st.problem {
            Problem::Beam => "accuracy.png".to_string(),
            p => format!("accuracy_{}.png", p.name()),
        };
        crate::output::write_atomic(&dir.join(name), &canvas.png())?;
        fronts.push(front);
    }
    crate::output::write_atomic(&dir.join("accuracy.csv"), csv.as_bytes())?;
    Ok(fronts)
}
