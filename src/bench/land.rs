//! `palpate bench land`: the Land et al. 2015 cardiac-mechanics benchmark, problems 1 and 2
//! (built-in scenes `land_p1`, `land_p2`; docs/cardiac.md), solved to a static state with
//! `--until-static` over a mesh-refinement series, with the monitored values:
//!
//! * problem 1: the deformed z of the point (10, 0.5, 1) mm of the beam (reference ≈ 4.17 mm);
//! * problem 2: the deformed z of the endocardial apex (0, 0, −17) mm and of the epicardial
//!   apex (0, 0, −20) mm (references ≈ −26.6 and −28.3 mm).
//!
//! Monitored points are evaluated by linear interpolation in the tet that contains their
//! rest position (the FE solution itself, also where no vertex sits at the point).

use crate::error::{PalpateError, Result};
use crate::mesh::TetMesh;
use crate::output::csv_field;
use crate::run::{run_with_state, RunLength, RunOptions};
use crate::scene::{Scene, SceneFile};
use crate::sim::Backend;
use glam::DVec3;
use std::path::Path;

/// One of the two passive problems.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Problem {
    /// The beam.
    P1,
    /// The ventricle.
    P2,
}

impl Problem {
    /// The built-in scene's name.
    pub fn scene_name(self) -> &'static str {
        match self {
            Problem::P1 => "land_p1",
            Problem::P2 => "land_p2",
        }
    }

    /// Guccione's C of the problem, Pa.
    pub fn guccione_c(self) -> f64 {
        match self {
            Problem::P1 => 2000.0,
            Problem::P2 => 1.0e4,
        }
    }

    /// The monitored points at rest, m, with their names.
    pub fn points(self) -> &'static [(&'static str, [f64; 3])] {
        match self {
            Problem::P1 => &[("z(10, 0.5, 1)", [0.01, 0.0005, 0.001])],
            Problem::P2 => &[
                ("z endo apex", [0.0, 0.0, -0.017]),
                ("z epi apex", [0.0, 0.0, -0.020]),
            ],
        }
    }

    /// The consensus values of the paper (figure readings, docs/cardiac.md), mm.
    pub fn reference_mm(self) -> &'static [f64] {
        match self {
            Problem::P1 => &[4.17],
            Problem::P2 => &[-26.6, -28.3],
        }
    }

    /// The mesh of refinement level `n` (1, 2, …): p1 `cells = [10n, n, n]` (60 n³ tets),
    /// p2 `resolution = n` (96 n³ tets).
    pub fn mesh_label(self, n: usize) -> String {
        match self {
            Problem::P1 => format!("cells [{}, {n}, {n}]", 10 * n),
            Problem::P2 => format!("lv resolution {n}"),
        }
    }
}

/// One variant of a problem's scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LandCase {
    /// The problem.
    pub problem: Problem,
    /// Refinement level (see [`Problem::mesh_label`]).
    pub level: usize,
    /// κ / C.
    pub kappa_ratio: f64,
    /// `"nodal_average"` or `"element"`.
    pub volume_term: &'static str,
}

impl LandCase {
    /// The built-in scene with this mesh, bulk modulus and volume term.
    pub fn scene(&self) -> Result<Scene> {
        let p = self.problem;
        let text = Scene::builtin_text(p.scene_name())
            .ok_or_else(|| PalpateError::Usage(format!("no built-in scene {}", p.scene_name())))?;
        let mut file: SceneFile = toml::from_str(text).map_err(|e| PalpateError::SceneParse {
            origin: p.scene_name().into(),
            message: e.to_string(),
        })?;
        let n = self.level;
        match p {
            Problem::P1 => file.mesh.cells = Some(vec![10 * n, n, n]),
            Problem::P2 => file.mesh.resolution = Some(n),
        }
        file.material.bulk_modulus = Some(self.kappa_ratio * p.guccione_c());
        file.material.volume_term = Some(self.volume_term.to_string());
        let origin = format!(
            "{} {} kappa/C {} {}",
            p.scene_name(),
            p.mesh_label(n),
            self.kappa_ratio,
            self.volume_term
        );
        Scene::from_file(file, &origin, p.scene_name(), None)
    }
}

/// The result of one static solve.
#[derive(Clone, Debug, PartialEq)]
pub struct LandRun {
    /// The case.
    pub case: LandCase,
    /// Tets.
    pub tets: usize,
    /// Vertices.
    pub vertices: usize,
    /// Monitored values (deformed z), mm, in [`Problem::points`] order.
    pub monitored_mm: Vec<f64>,
    /// Steps to the static state.
    pub steps: u64,
    /// The time step, s.
    pub dt: f64,
    /// Wall-clock seconds.
    pub wall_seconds: f64,
    /// Backend and adapter.
    pub adapter: String,
    /// Run status ("ok" when static).
    pub status: String,
}

/// Displacement at rest position `x`: linear interpolation in the tet containing `x` (the
/// one whose smallest barycentric coordinate is largest), or None when `x` is farther than
/// 1e-6 of a tet outside the mesh.
pub fn point_displacement(mesh: &TetMesh, displacements: &[f32], x: DVec3) -> Option<DVec3> {
    let mut best: Option<(f64, usize, [f64; 4])> = None;
    for (e, tet) in mesh.tets.iter().enumerate() {
        let p = tet.map(|i| mesh.positions[i as usize]);
        let m = glam::DMat3::from_cols(p[1] - p[0], p[2] - p[0], p[3] - p[0]);
        let det = m.determinant();
        if det.abs() <= 0.0 {
            continue;
        }
        let b = m.inverse() * (x - p[0]);
        let w = [1.0 - b.x - b.y - b.z, b.x, b.y, b.z];
        let min = w.iter().copied().fold(f64::INFINITY, f64::min);
        if best.is_none_or(|(m0, _, _)| min > m0) {
            best = Some((min, e, w));
        }
    }
    let (min, e, w) = best?;
    if min < -1e-6 {
        return None;
    }
    let tet = mesh.tets[e];
    Some(
        (0..4)
            .map(|c| {
                let u = crate::cpu::load3(displacements, tet[c] as usize);
                DVec3::new(u.x as f64, u.y as f64, u.z as f64) * w[c]
            })
            .sum(),
    )
}

/// Deformed z of the problem's monitored points, mm.
pub fn monitored_mm(problem: Problem, mesh: &TetMesh, displacements: &[f32]) -> Result<Vec<f64>> {
    problem
        .points()
        .iter()
        .map(|(name, x)| {
            let x = DVec3::from_array(*x);
            let u = point_displacement(mesh, displacements, x).ok_or_else(|| {
                PalpateError::Usage(format!("monitored point {name} lies outside the mesh"))
            })?;
            Ok(1e3 * (x.z + u.z))
        })
        .collect()
}

/// Solve one case to a static state (scratch outputs under `scratch`).
pub fn solve(case: &LandCase, backend: Backend, scratch: &Path) -> Result<LandRun> {
    let scene = case.scene()?;
    let (summary, state) = run_with_state(
        &scene,
        &RunOptions {
            backend,
            length: RunLength::UntilStatic {
                max_steps: 3_000_000,
            },
            out: scratch.to_path_buf(),
            batch: 500,
            ..Default::default()
        },
    )?;
    Ok(LandRun {
        case: *case,
        tets: summary.tets,
        vertices: summary.vertices,
        monitored_mm: monitored_mm(case.problem, &scene.mesh, &state.displacements)?,
        steps: summary.steps,
        dt: summary.dt,
        wall_seconds: summary.wall_seconds,
        adapter: summary.adapter.clone(),
        status: summary.status.to_string(),
    })
}

/// The cases of the study: per problem a refinement series at κ/C = 100 with the nodal
/// average, at one mesh the plain element volume term (locking), and for the ventricle a
/// κ/C = 1000 series.
pub fn cases(quick: bool) -> Vec<LandCase> {
    let mut out = Vec::new();
    for (problem, levels, probe) in [
        (Problem::P1, if quick { 1..=2 } else { 1..=5 }, 2),
        (Problem::P2, if quick { 1..=2 } else { 1..=5 }, 2),
    ] {
        for level in levels {
            out.push(LandCase {
                problem,
                level,
                kappa_ratio: 100.0,
                volume_term: "nodal_average",
            });
        }
        out.push(LandCase {
            problem,
            level: probe,
            kappa_ratio: 100.0,
            volume_term: "element",
        });
        // κ/C = 1000 on the beam stalls at a residual of ~2.5e-4 after 3e6 steps (f32
        // round-off of the stiff volume term against a 4e-5 N load): ventricle only, a whole
        // series (quick: one mesh).
        if problem == Problem::P2 {
            for level in if quick { probe..=probe } else { 1..=5 } {
                out.push(LandCase {
                    problem,
                    level,
                    kappa_ratio: 1000.0,
                    volume_term: "nodal_average",
                });
            }
        }
    }
    out
}

/// Run the study; `progress` gets a line per finished run.
pub fn study(
    backend: Backend,
    quick: bool,
    progress: &mut dyn FnMut(String),
) -> Result<Vec<LandRun>> {
    let scratch = std::env::temp_dir().join(format!("palpate-bench-land-{}", std::process::id()));
    let mut rows = Vec::new();
    for case in cases(quick) {
        let r = solve(&case, backend, &scratch)?;
        progress(format!(
            "{} {} kappa/C {} {}: {} tets, {:?} mm, {} steps, {:.1} s, {}",
            case.problem.scene_name(),
            case.problem.mesh_label(case.level),
            case.kappa_ratio,
            case.volume_term,
            r.tets,
            r.monitored_mm
                .iter()
                .map(|v| (v * 1000.0).round() / 1000.0)
                .collect::<Vec<_>>(),
            r.steps,
            r.wall_seconds,
            r.status
        ));
        rows.push(r);
    }
    let _ = std::fs::remove_dir_all(&scratch);
    Ok(rows)
}

/// Write `land.csv`, `land.md`, `land.png` (error against the reference per problem and
/// point, against tets) and `land_pareto.png` (error against the finest run, against run
/// time) under `out`.
pub fn write(out: &Path, rows: &[LandRun], header: &str) -> Result<()> {
    std::fs::create_dir_all(out).map_err(|source| PalpateError::OutputIo {
        path: out.to_path_buf(),
        source,
    })?;
    let mut csv = String::from(
        "problem,mesh,tets,vertices,kappa_over_c,volume_term,point,z_mm,reference_mm,steps,dt_s,wall_seconds,adapter,status\n",
    );
    let mut md = format!(
        "# Land et al. 2015 benchmark, problems 1 and 2\n\n{header}\n\n![monitored values against mesh size](land.png)\n\n![error against the finest run of the series, against the time to a static solution](land_pareto.png)\n\n| problem | mesh | tets | κ/C | volume term | monitored (mm) | reference (mm) | steps | dt (s) | wall (s) | status |\n|---|---|---:|---:|---|---|---|---:|---:|---:|---|\n"
    );
    for r in rows {
        let c = &r.case;
        let p = c.problem;
        for (k, (name, _)) in p.points().iter().enumerate() {
            csv.push_str(&format!(
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
                p.scene_name(),
                csv_field(&p.mesh_label(c.level)),
                r.tets,
                r.vertices,
                c.kappa_ratio,
                csv_field(c.volume_term),
                csv_field(name),
                r.monitored_mm[k],
                p.reference_mm()[k],
                r.steps,
                r.dt,
                r.wall_seconds,
                csv_field(&r.adapter),
                csv_field(&r.status.to_string())
            ));
        }
        let values: Vec<String> = p
            .points()
            .iter()
            .zip(&r.monitored_mm)
            .map(|((name, _), v)| format!("{name} = {v:.3}"))
            .collect();
        let refs: Vec<String> = p.reference_mm().iter().map(|v| format!("{v}")).collect();
        md.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {:.2e} | {:.1} | {} |\n",
            p.scene_name(),
            p.mesh_label(c.level),
            r.tets,
            c.kappa_ratio,
            c.volume_term,
            values.join(", "),
            refs.join(", "),
            r.steps,
            r.dt,
            r.wall_seconds,
            r.status
        ));
    }
    let write = |name: &str, bytes: &[u8]| crate::output::write_atomic(&out.join(name), bytes);
    write("land.csv", csv.as_bytes())?;
    write("land.md", md.as_bytes())?;
    write("land.png", &plot(rows).png())?;
    write("land_pareto.png", &pareto_plot(rows).png())?;
    Ok(())
}

/// Error against run time (as the accuracy study's Pareto plots): for each problem's first
/// monitored value, |z − z_finest| / |z_finest| against the wall time to a static solution,
/// where z_finest is the finest κ/C = 100 nodal-average run of that problem. Series: the
/// refinement series at κ/C = 100, the κ/C = 1000 runs and the element volume term; the
/// black line is the Pareto front over all of them.
fn pareto_plot(rows: &[LandRun]) -> crate::output::png::Canvas {
    use crate::output::png::{loglog_plot, pareto_front, PlotPoint};
    let mut points = Vec::new();
    let mut legend = Vec::new();
    for problem in [Problem::P1, Problem::P2] {
        let series_of = |r: &LandRun| {
            (r.case.problem == problem).then_some(if r.case.volume_term != "nodal_average" {
                2
            } else if r.case.kappa_ratio == 100.0 {
                0
            } else {
                1
            })
        };
        let Some(finest) = rows
            .iter()
            .filter(|r| series_of(r) == Some(0))
            .max_by_key(|r| r.tets)
        else {
            continue;
        };
        let short = match problem {
            Problem::P1 => "p1 tip",
            Problem::P2 => "p2 endo apex",
        };
        let base = legend.len();
        for label in ["k/C 100", "k/C 1000", "element"] {
            legend.push(format!("{short}, {label}"));
        }
        let z_finest = finest.monitored_mm[0];
        for r in rows {
            if std::ptr::eq(r, finest) {
                continue;
            }
            if let Some(series) = series_of(r) {
                points.push(PlotPoint {
                    x: r.wall_seconds.max(1e-3),
                    y: ((r.monitored_mm[0] - z_finest) / z_finest).abs().max(1e-6),
                    series: base + series,
                });
            }
        }
    }
    let front = pareto_front(&points);
    loglog_plot(
        &points,
        &front,
        "wall time to static [s]",
        "|z - z_finest| / |z_finest|",
        &legend,
    )
}

/// Relative error of each monitored value against the reference, per (problem, point), on
/// the refinement series (κ/C = 100, nodal average), against tets (log-log).
fn plot(rows: &[LandRun]) -> crate::output::png::Canvas {
    use crate::output::png::{loglog_plot, PlotPoint};
    let mut points = Vec::new();
    let mut legend = Vec::new();
    for problem in [Problem::P1, Problem::P2] {
        for (k, (name, _)) in problem.points().iter().enumerate() {
            let series = legend.len();
            legend.push(format!("{} {name}", problem.scene_name()));
            for r in rows.iter().filter(|r| {
                r.case.problem == problem
                    && r.case.kappa_ratio == 100.0
                    && r.case.volume_term == "nodal_average"
            }) {
                let reference = problem.reference_mm()[k];
                let err = ((r.monitored_mm[k] - reference) / reference).abs();
                points.push(PlotPoint {
                    x: r.tets as f64,
                    y: err.max(1e-6),
                    series,
                });
            }
        }
    }
    loglog_plot(
        &points,
        &[],
        "tets",
        "|z - z_ref| / |z_ref| (refinement series)",
        &legend,
    )
}
