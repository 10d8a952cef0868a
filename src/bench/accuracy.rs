//! `palpate bench accuracy`: run time against error for the cantilever under gravity.
//!
//! The reference problem is the built-in `beam` released from rest under gravity; the
//! observable is the tip deflection (mean vertical displacement of the vertices at x = L)
//! over the first 0.1 s, a third of the first bending period and the whole initial swing.
//! Error = max over sample times |tip(t) − tip_ref(t)| / max |tip_ref|, with the reference
//! linearly interpolated. The reference is the finest mesh at a quarter of the stable step;
//! its own convergence is estimated by comparing it with the next-coarser mesh and with the
//! same mesh at twice the step, and both numbers are written beside the results.
//!
//! Writes `accuracy.csv` and `accuracy.png` (log-log error versus wall time, Pareto front).

use super::beam_scene;
use crate::error::{PalpateError, Result};
use crate::material::MaterialModel;
use crate::model::Model;
use crate::output::png::{loglog_plot, pareto_front, PlotPoint};
use crate::sim::{Advance, Backend, SimOptions, Simulation};
use std::fmt::Write;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

/// Simulated time of each run, s.
pub const DURATION: f64 = 0.1;

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
    /// Beam cells.
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
    /// Tip-deflection history (t, deflection m).
    pub history: Vec<(f64, f64)>,
    /// Relative error against the reference (NaN for the reference or a diverged run).
    pub error: f64,
}

fn tip_vertices(model: &Model) -> Vec<usize> {
    (0..model.n_vertices())
        .filter(|&i| (model.rest[3 * i] - 0.1).abs() < 1e-6)
        .collect()
}

/// Run the beam with `cells` at `safety` × bound, sampling the tip `samples` times.
pub fn run_case(
    cells: [usize; 3],
    safety: f64,
    backend: Backend,
    samples: usize,
) -> Result<Option<Run>> {
    let scene = beam_scene(cells, MaterialModel::Stvk)?;
    let model = Arc::new(Model::from_scene(&scene));
    let dt = safety * model.bounds.dt_bound;
    let mut sim = Simulation::from_model(
        model.clone(),
        backend,
        dt,
        0.0,
        SimOptions {
            allow_unstable: true,
            ..Default::default()
        },
    )?;
    let tip = tip_vertices(&model);
    let total = (DURATION / dt).round() as u64;
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
        let d = -tip.iter().map(|&i| u[3 * i + 2] as f64).sum::<f64>() / tip.len() as f64;
        history.push((sim.time, d));
    }
    Ok(Some(Run {
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

/// The sweep: runs, and the reference's estimated errors (mesh, time step).
pub struct Study {
    /// Sweep runs.
    pub runs: Vec<Run>,
    /// Reference cells and safety.
    pub reference: ([usize; 3], f64),
    /// Reference vs next-coarser mesh (an estimate of its mesh error).
    pub reference_mesh_change: f64,
    /// Reference vs twice its step (an estimate of its time-step error).
    pub reference_dt_change: f64,
    /// Runs that diverged: (cells, safety).
    pub diverged: Vec<([usize; 3], f64)>,
}

/// Run the sweep.
pub fn study(opts: &AccuracyOptions, progress: &mut dyn FnMut(&str)) -> Result<Study> {
    let (meshes, safeties, reference, coarser): (
        Vec<[usize; 3]>,
        Vec<f64>,
        [usize; 3],
        [usize; 3],
    ) = if opts.quick {
        (
            vec![[5, 1, 1], [10, 2, 2]],
            vec![0.9, 0.5],
            [20, 4, 4],
            [10, 2, 2],
        )
    } else {
        (
            vec![[10, 2, 2], [15, 3, 3], [20, 4, 4], [30, 6, 6]],
            vec![0.9, 0.5, 0.25],
            [40, 8, 8],
            [30, 6, 6],
        )
    };
    let fine = 200;
    progress(&format!("reference {reference:?} at 0.25 x bound"));
    let missing = || PalpateError::Usage("the reference run diverged".into());
    let r = run_case(reference, 0.25, opts.backend, fine)?.ok_or_else(missing)?;
    progress("reference checks");
    let r_dt = run_case(reference, 0.5, opts.backend, fine)?.ok_or_else(missing)?;
    let r_mesh = run_case(coarser, 0.25, opts.backend, fine)?.ok_or_else(missing)?;
    let mut runs = Vec::new();
    let mut diverged = Vec::new();
    for &cells in &meshes {
        for &s in &safeties {
            progress(&format!("{cells:?} at {s} x bound"));
            match run_case(cells, s, opts.backend, 40)? {
                Some(mut run) => {
                    run.error = history_error(&run.history, &r.history);
                    runs.push(run);
                }
                None => diverged.push((cells, s)),
            }
        }
    }
    Ok(Study {
        reference_mesh_change: history_error(&r_mesh.history, &r.history),
        reference_dt_change: history_error(&r_dt.history, &r.history),
        reference: (reference, 0.25),
        runs,
        diverged,
    })
}

/// Write `accuracy.csv` and `accuracy.png` into `dir`; returns the Pareto-optimal run indices.
pub fn write(dir: &Path, study: &Study, adapter: &str) -> Result<Vec<usize>> {
    std::fs::create_dir_all(dir).map_err(|source| PalpateError::OutputIo {
        path: dir.to_path_buf(),
        source,
    })?;
    let points: Vec<PlotPoint> = study
        .runs
        .iter()
        .map(|r| PlotPoint {
            x: r.wall_seconds.max(1e-6),
            y: r.error.max(1e-9),
            series: {
                let mut cells: Vec<[usize; 3]> = study.runs.iter().map(|q| q.cells).collect();
                cells.dedup();
                cells.iter().position(|c| *c == r.cells).unwrap_or(0)
            },
        })
        .collect();
    let front = pareto_front(&points);
    let mut csv = format!(
        "# adapter: {adapter}; reference {:?} at {} x bound; reference vs coarser mesh {:.3e}, vs 2x dt {:.3e}\nmesh,tets,safety,dt_s,steps,wall_seconds,error,pareto\n",
        study.reference.0, study.reference.1, study.reference_mesh_change, study.reference_dt_change
    );
    for (i, r) in study.runs.iter().enumerate() {
        let _ = writeln!(
            csv,
            "{}x{}x{},{},{},{:e},{},{:.4},{:.4e},{}",
            r.cells[0],
            r.cells[1],
            r.cells[2],
            r.tets,
            r.safety,
            r.dt,
            r.steps,
            r.wall_seconds,
            r.error,
            front.contains(&i)
        );
    }
    for (c, s) in &study.diverged {
        let _ = writeln!(csv, "{}x{}x{},,{s},,,,diverged,false", c[0], c[1], c[2]);
    }
    crate::output::write_atomic(&dir.join("accuracy.csv"), csv.as_bytes())?;
    let mut legend: Vec<String> = Vec::new();
    for r in &study.runs {
        let name = format!("{}x{}x{}", r.cells[0], r.cells[1], r.cells[2]);
        if !legend.contains(&name) {
            legend.push(name);
        }
    }
    let canvas = loglog_plot(
        &points,
        &front,
        "run time [s]",
        "tip error (rel, max over t)",
        &legend,
    );
    crate::output::write_atomic(&dir.join("accuracy.png"), &canvas.png())?;
    Ok(front)
}
