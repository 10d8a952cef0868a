//! `palpate bench contact`: the tool's penalty contact against Hertz's solution.
//!
//! A rigid sphere of radius R pressed to depth d into an elastic half-space (Young's modulus
//! E, Poisson ratio ν, frictionless) carries F = 4/3 E* √R d^{3/2}, E* = E/(1 − ν²), over a
//! contact radius a = √(R d) (Johnson, *Contact Mechanics*, 1985, §4.2). The half-space is
//! a block of half-width and depth `block` × a, bottom held, meshed on a grid graded from
//! cells of `fine` × a under the contact; the sphere moves down to depth d and the block is
//! relaxed to a static state (`--until-static`). Errors come from the mesh (how well it
//! resolves a), the penalty (the sphere sinks by about p/k into the surface, p ≈ E* a/R the
//! contact pressure), the finite block (stiffer than a half-space by O(a/block)) and the
//! static tolerance.

use crate::error::Result;
use crate::material::MaterialParams;
use crate::mesh::{generators, TetMesh};
use crate::run::{run, RunLength, RunOptions};
use crate::scene::{Scene, SolverSettings, Tool};
use crate::sim::Backend;
use glam::DVec3;
use std::path::Path;

/// One Hertz case.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HertzCase {
    /// Sphere radius R, m.
    pub radius: f64,
    /// Indentation depth d, m.
    pub depth: f64,
    /// Young's modulus E, Pa.
    pub youngs_modulus: f64,
    /// Poisson ratio ν.
    pub poisson_ratio: f64,
    /// Cell size under the contact, in contact radii a.
    pub fine: f64,
    /// Growth of the cell size away from the contact.
    pub growth: f64,
    /// Half-width and depth of the block, in contact radii.
    pub block: f64,
    /// Contact penalty k, Pa/m.
    pub penalty: f64,
    /// A particle layer: the top `layers` tet layers become the particle zone with lattice
    /// spacing `spacing` (in contact radii); None: tets only.
    pub particles: Option<ParticleLayer>,
}

/// The particle zone of a hybrid Hertz block.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ParticleLayer {
    /// Lattice spacing, in contact radii.
    pub spacing: f64,
    /// Tet layers (from the top) in the zone.
    pub layers: usize,
    /// Kernel support radius, in spacings (the scene default is 2.4).
    pub kernel_radius: f64,
    /// Activation radius from the tool's surface, in contact radii (the bench uses 2); None:
    /// every particle dynamic (`activation = "all"`).
    pub activation: Option<f64>,
    /// Design 8's coupling (`coupling = "exact"`; needs `activation` None) instead of the
    /// energy blend.
    pub exact: bool,
}

impl Default for HertzCase {
    fn default() -> Self {
        HertzCase {
            radius: 5e-3,
            depth: 0.5e-3,
            youngs_modulus: 1e4,
            poisson_ratio: 0.3,
            fine: 1.0 / 3.0,
            growth: 1.4,
            block: 8.0,
            penalty: 1e9,
            particles: None,
        }
    }
}

impl HertzCase {
    /// The activation-bias case: core cells 2a, the top two layers as particles a/2, awake
    /// within `activation` contact radii of the tool (None: all awake).
    pub fn awake_within(activation: Option<f64>) -> HertzCase {
        HertzCase {
            fine: 2.0,
            particles: Some(ParticleLayer {
                spacing: 0.5,
                layers: 2,
                kernel_radius: 2.4,
                activation,
                exact: false,
            }),
            ..HertzCase::default()
        }
    }

    /// [`HertzCase::awake_within`]`(None)` under design 8's coupling (`coupling = "exact"`).
    pub fn exact_all_awake() -> HertzCase {
        let mut case = HertzCase::awake_within(None);
        if let Some(p) = case.particles.as_mut() {
            p.exact = true;
        }
        case
    }

    /// `cells a/3`, or `core 2a + particles a/3` for a hybrid block (with its kernel support
    /// and activation radius when they are not the defaults, 2.4Δx and 2a).
    pub fn label(&self) -> String {
        let Some(p) = self.particles else {
            return format!("cells a/{:.1}", 1.0 / self.fine);
        };
        let mut label = format!(
            "core {:.1}a + particles a/{:.1}",
            self.fine,
            1.0 / p.spacing
        );
        if p.kernel_radius != 2.4 {
            label.push_str(&format!(" (support {}Δx)", p.kernel_radius));
        }
        match p.activation {
            Some(2.0) => {}
            Some(r) => label.push_str(&format!(" (awake within {r}a)")),
            None => label.push_str(" (all awake)"),
        }
        if p.exact {
            label.push_str(" (exact coupling)");
        }
        label
    }

    /// Contact radius a = √(R d), m.
    pub fn contact_radius(&self) -> f64 {
        (self.radius * self.depth).sqrt()
    }

    /// Hertz's force F = 4/3 E/(1 − ν²) √R d^{3/2}, N.
    pub fn hertz_force(&self) -> f64 {
        let e_star = self.youngs_modulus / (1.0 - self.poisson_ratio * self.poisson_ratio);
        4.0 / 3.0 * e_star * self.radius.sqrt() * self.depth.powf(1.5)
    }

    /// The block: x, y ∈ [−L, L], z ∈ [−L, 0], L = block·a, graded from `fine`·a cells at
    /// the origin.
    pub fn mesh(&self) -> TetMesh {
        let a = self.contact_radius();
        let l = self.block * a;
        let half = generators::graded_axis(0.0, l, self.fine * a, self.growth);
        let mut xs: Vec<f64> = half.iter().rev().map(|x| -x).collect();
        xs.extend_from_slice(&half[1..]);
        let zs: Vec<f64> = half.iter().rev().map(|z| -z).collect();
        let mut mesh = generators::graded_box(&xs, &xs, &zs);
        if let Some(layer) = self.particles {
            // Region 1: the top `layers` layers of cells (the particle zone); region 0: core.
            let top = zs[zs.len() - 1 - layer.layers.min(zs.len() - 1)];
            for e in 0..mesh.n_tets() {
                let z: f64 = mesh.corners(e).iter().map(|p| p.z).sum::<f64>() / 4.0;
                mesh.regions[e] = (z > top) as u32;
            }
        }
        mesh
    }

    /// The scene: the block with its bottom held, the sphere moved from just above the
    /// surface to depth d over 5 ms and held there.
    pub fn scene(&self) -> Result<Scene> {
        let mut mesh = self.mesh();
        let report = mesh.validate("hertz block")?;
        let bottom = mesh
            .positions
            .iter()
            .map(|p| p.z)
            .fold(f64::INFINITY, f64::min);
        let fixed = mesh
            .positions
            .iter()
            .map(|p| p.z <= bottom + 1e-12)
            .collect();
        let n = mesh.n_vertices();
        let r = self.radius;
        Ok(Scene {
            name: "hertz".into(),
            origin: "hertz block".into(),
            description: "sphere pressed into a block (Hertz)".into(),
            mesh,
            mesh_report: report,
            material: MaterialParams::elastic(self.youngs_modulus, self.poisson_ratio, 1000.0),
            hyperelastic: None,
            fibre: None,
            follower: None,
            fixed,
            gravity: [0.0; 3],
            external_forces: vec![DVec3::ZERO; n],
            load_warnings: Vec::new(),
            input_files: Vec::new(),
            solver: SolverSettings {
                dt: None,
                safety: 0.5,
                damping: 0.0,
                static_tolerance: 1e-3,
                duration: None,
                mass_scaling: 1.0,
            },
            tool: Some(Tool {
                radius: r,
                stiffness: self.penalty,
                damping: 0.0,
                path: vec![
                    (0.0, DVec3::new(0.0, 0.0, r + 0.05 * self.depth)),
                    (5e-3, DVec3::new(0.0, 0.0, r - self.depth)),
                ],
                home: DVec3::new(0.0, 0.0, r),
            }),
            particles: self.particles.map(|layer| crate::scene::ParticleSettings {
                exact_coupling: layer.exact,
                region: 1,
                spacing: layer.spacing * self.contact_radius(),
                model: crate::scene::ParticleModel::Tlsph,
                activation_radius: layer.activation.unwrap_or(2.0) * self.contact_radius(),
                kernel_radius: layer.kernel_radius,
                hourglass: 0.1,
                hysteresis: 1.5,
                dwell: 0.01,
                blend: 0.01,
                activation_interval: 10,
                all_active: layer.activation.is_none(),
            }),
        })
    }
}

/// The outcome of one case.
#[derive(Clone, Debug, PartialEq)]
pub struct HertzResult {
    /// The case.
    pub case: HertzCase,
    /// Tets of the block.
    pub tets: usize,
    /// Particles of its particle zone (0 without).
    pub particles: usize,
    /// Vertical force on the tool at the static state, N.
    pub force: f64,
    /// Hertz's force, N.
    pub hertz: f64,
    /// (force − hertz)/hertz.
    pub relative_error: f64,
    /// Steps to the static state.
    pub steps: u64,
    /// Wall-clock seconds.
    pub wall_seconds: f64,
    /// The run's status (`ok` when it reached the static tolerance).
    pub status: String,
}

impl HertzResult {
    /// One line for logs: the block, depth, penalty, size, force against Hertz, steps, wall
    /// time and status.
    pub fn line(&self) -> String {
        let c = &self.case;
        format!(
            "{}, depth {:.2} mm, penalty {:.0e} Pa/m: {} tets, {} particles, F = {:.4e} N vs Hertz {:.4e} N ({:+.2} %), {} steps, {:.1} s, {}",
            c.label(),
            1e3 * c.depth,
            c.penalty,
            self.tets,
            self.particles,
            self.force,
            self.hertz,
            100.0 * self.relative_error,
            self.steps,
            self.wall_seconds,
            self.status
        )
    }
}

/// Run one case to a static state on `backend`, writing the run's outputs to `out`.
pub fn run_case(case: &HertzCase, backend: Backend, out: &Path) -> Result<HertzResult> {
    let scene = case.scene()?;
    let summary = run(
        &scene,
        &RunOptions {
            backend,
            length: RunLength::UntilStatic { max_steps: 400_000 },
            out: out.to_path_buf(),
            ..Default::default()
        },
    )?;
    let force = summary.tool_force.map_or(0.0, |f| f[2]);
    let hertz = case.hertz_force();
    Ok(HertzResult {
        case: *case,
        tets: summary.tets,
        particles: summary.particles,
        force,
        hertz,
        relative_error: (force - hertz) / hertz,
        steps: summary.steps,
        wall_seconds: summary.wall_seconds,
        status: summary.status.to_string(),
    })
}

/// The study (runs written to a temporary directory): the error against the cell size under the contact (penalty 1e9 Pa/m, three
/// depths, since a node-based penalty's error oscillates with where the contact edge falls
/// between vertices) and against the penalty (cells of a/2). `quick` runs a CI-sized subset.
pub fn study(backend: Backend, quick: bool, log: &mut dyn FnMut(&str)) -> Result<Vec<HertzResult>> {
    let base = HertzCase::default();
    let mut cases = Vec::new();
    let fines: &[f64] = if quick {
        &[0.5]
    } else {
        &[1.0, 0.5, 1.0 / 3.0, 0.25, 1.0 / 6.0]
    };
    for &fine in fines {
        for depth in [0.3e-3, 0.5e-3, 0.8e-3] {
            cases.push(HertzCase {
                fine,
                depth,
                ..base
            });
        }
    }
    let penalties: &[f64] = if quick { &[1e8] } else { &[1e7, 1e8] };
    for &penalty in penalties {
        cases.push(HertzCase {
            penalty,
            fine: 0.5,
            ..base
        });
    }
    // Error against run time (the Pareto plot): all-tet blocks refined under the contact,
    // and hybrid blocks — a coarse core of 2a cells whose top two layers are particles of
    // a/2, a/3, a/4 spacing — at depth 0.5 mm.
    let pareto_fines: &[f64] = if quick {
        &[]
    } else {
        &[1.0, 0.5, 1.0 / 3.0, 0.25]
    };
    for &fine in pareto_fines {
        if !cases
            .iter()
            .any(|c| c.fine == fine && c.depth == base.depth && c.penalty == base.penalty)
        {
            cases.push(HertzCase { fine, ..base });
        }
    }
    let spacings: &[f64] = if quick { &[] } else { &[0.5, 1.0 / 3.0, 0.25] };
    if !quick {
        cases.push(HertzCase { fine: 2.0, ..base });
    }
    for &spacing in spacings {
        cases.push(HertzCase {
            fine: 2.0,
            particles: Some(ParticleLayer {
                spacing,
                layers: 2,
                kernel_radius: 2.4,
                activation: Some(2.0),
                exact: false,
            }),
            ..base
        });
    }
    // What waking only the particles near the tool costs in accuracy: the a/2 layer awake
    // within 1a and 4a of the tool, and all awake, beside the 2a above.
    if !quick {
        for activation in [Some(1.0), Some(4.0), None] {
            cases.push(HertzCase::awake_within(activation));
        }
        cases.push(HertzCase::exact_all_awake());
    }
    let dir = std::env::temp_dir().join(format!("palpate-hertz-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|source| crate::error::PalpateError::OutputIo {
        path: dir.clone(),
        source,
    })?;
    let mut rows = Vec::new();
    for case in cases {
        let r = run_case(&case, backend, &dir)?;
        log(&r.line());
        rows.push(r);
    }
    Ok(rows)
}

/// Write `contact.csv` and `contact.md` into `out`.
pub fn write(out: &Path, rows: &[HertzResult], header: &str) -> Result<()> {
    std::fs::create_dir_all(out).map_err(|source| crate::error::PalpateError::OutputIo {
        path: out.to_path_buf(),
        source,
    })?;
    let mut csv = String::from(
        "radius_m,depth_m,contact_radius_m,cell_over_a,particle_spacing_over_a,activation_radius_over_a,penalty_pa_per_m,tets,particles,force_n,hertz_n,relative_error,steps,wall_seconds,status\n",
    );
    let mut md = format!(
        "# Contact against Hertz\n\n{header}\n\n| block | depth mm | penalty Pa/m | tets | particles | F sim N | F Hertz N | error | steps | wall s |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n"
    );
    for r in rows {
        let c = &r.case;
        csv.push_str(&format!(
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
            c.radius,
            c.depth,
            c.contact_radius(),
            c.fine,
            c.particles.map_or(String::new(), |p| p.spacing.to_string()),
            c.particles.map_or(String::new(), |p| p
                .activation
                .map_or("all".into(), |r| r.to_string())),
            c.penalty,
            r.tets,
            r.particles,
            r.force,
            r.hertz,
            r.relative_error,
            r.steps,
            r.wall_seconds,
            crate::output::csv_field(&r.status.to_string())
        ));
        md.push_str(&format!(
            "| {} | {:.2} | {:.0e} | {} | {} | {:.4e} | {:.4e} | {:+.2} % | {} | {:.1} |\n",
            c.label(),
            1e3 * c.depth,
            c.penalty,
            r.tets,
            r.particles,
            r.force,
            r.hertz,
            100.0 * r.relative_error,
            r.steps,
            r.wall_seconds
        ));
    }
    // The Pareto plot: |error| against run time at depth 0.5 mm, penalty 1e9 Pa/m.
    let base = HertzCase::default();
    let series = ["all tets", "hybrid (core 2a)"];
    let picked: Vec<&HertzResult> = rows
        .iter()
        .filter(|r| r.case.depth == base.depth && r.case.penalty == base.penalty)
        .filter(|r| r.case.particles.is_some() || r.case.fine <= 1.0)
        .collect();
    if picked.iter().any(|r| r.case.particles.is_some()) {
        let points: Vec<crate::output::png::PlotPoint> = picked
            .iter()
            .map(|r| crate::output::png::PlotPoint {
                x: r.wall_seconds.max(1e-3),
                y: r.relative_error.abs().max(1e-4),
                series: usize::from(r.case.particles.is_some()),
            })
            .collect();
        let front = crate::output::png::pareto_front(&points);
        let labels: Vec<String> = series.iter().map(|s| s.to_string()).collect();
        let canvas = crate::output::png::loglog_plot(
            &points,
            &front,
            "run time to static [s]",
            "|F - F_Hertz| / F_Hertz",
            &labels,
        );
        crate::output::write_atomic(&out.join("accuracy_contact.png"), &canvas.png())?;
        md.push_str("\n![contact force error against run time](accuracy_contact.png)\n");
        md.push_str("\nPareto-optimal (no other run is both faster and more accurate): ");
        let names: Vec<String> = front.iter().map(|&i| picked[i].case.label()).collect();
        md.push_str(&names.join(", "));
        md.push('\n');
    }
    crate::output::write_atomic(&out.join("contact.csv"), csv.as_bytes())?;
    crate::output::write_atomic(&out.join("contact.md"), md.as_bytes())
}
