//! Scene description: the TOML file format (DESIGN.md §4), its validation, the built-in
//! scenes, and the resolved [`Scene`] that a simulation is built from.
//!
//! Unknown keys are refused. Every error names the scene (file path or built-in name), the
//! key, and what is wrong, on one line.

mod exact;
mod fixed;
mod loads;
mod material;
mod mesh;
pub mod particles;
mod solver;
mod tool;

pub use fixed::{BoxSpec, FixedSpec, PlaneSpec};
pub use loads::{FollowerLoads, FollowerSpec, LoadsSpec, PressureSpec};
pub use material::MaterialSpec;
pub use mesh::MeshSpec;
pub use particles::{ParticleModel, ParticleSettings, ParticleSpec, MAX_PARTICLES};
pub use solver::{DtSpec, SolverSettings, SolverSpec};
pub use tool::{
    activation_lag_warning, fastest_leg, longest_step_leg, short_time, tunnelling_warning, Tool,
    ToolOverlap, ToolSpec,
};

use crate::error::{PalpateError, Result};
use crate::material::{HyperelasticParams, MaterialParams};
use crate::mesh::{TetMesh, ValidationReport};
use glam::DVec3;
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// The built-in scenes: (name, TOML text).
pub const BUILTIN: &[(&str, &str)] = &[
    ("beam", include_str!("../../scenes/beam.toml")),
    ("ed0", include_str!("../../scenes/ed0.toml")),
    ("lv", include_str!("../../scenes/lv.toml")),
    ("hm1", include_str!("../../scenes/hm1.toml")),
    ("hm1_exact", include_str!("../../scenes/hm1_exact.toml")),
    ("hm2", include_str!("../../scenes/hm2.toml")),
    ("lv_touch", include_str!("../../scenes/lv_touch.toml")),
    ("land_p1", include_str!("../../scenes/land_p1.toml")),
    ("land_p2", include_str!("../../scenes/land_p2.toml")),
];

/// The scene `palpate run` uses when none is named.
pub const DEFAULT_SCENE: &str = "lv";

/// The whole scene file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    /// Short name (defaults to the file stem).
    pub name: Option<String>,
    /// One line saying what the scene is.
    pub description: Option<String>,
    /// `[mesh]`.
    pub mesh: MeshSpec,
    /// `[material]`.
    pub material: MaterialSpec,
    /// `[[fixed]]`.
    #[serde(default)]
    pub fixed: Vec<FixedSpec>,
    /// `[loads]`.
    #[serde(default)]
    pub loads: LoadsSpec,
    /// `[solver]`.
    #[serde(default)]
    pub solver: SolverSpec,
    /// `[tool]` (none: no contact stage).
    pub tool: Option<ToolSpec>,
    /// `[particles]` (none: no particle stages).
    pub particles: Option<ParticleSpec>,
}

/// A validated scene, ready to build a simulation from.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Scene name.
    pub name: String,
    /// Where it came from: a file path or `built-in scene 'name'`.
    pub origin: String,
    /// One-line description.
    pub description: String,
    /// The mesh at rest.
    pub mesh: TetMesh,
    /// What mesh validation fixed.
    pub mesh_report: ValidationReport,
    /// Material. For a split law μ is its small-strain shear modulus and λ = κ − 2μ/3.
    pub material: MaterialParams,
    /// The split law's constants (None for the (λ, μ) laws).
    pub hyperelastic: Option<HyperelasticParams>,
    /// A constant fibre for every tet (`material.fibre`), overriding the mesh's fibres.
    pub fibre: Option<[f64; 3]>,
    /// Follower pressures (None: no follower stage).
    pub follower: Option<FollowerLoads>,
    /// Per vertex: held fixed at rest.
    pub fixed: Vec<bool>,
    /// Gravity, m/s².
    pub gravity: [f64; 3],
    /// Constant external force per vertex (surface pressures), N.
    pub external_forces: Vec<DVec3>,
    /// Solver settings.
    pub solver: SolverSettings,
    /// The tool, if the scene has one.
    pub tool: Option<Tool>,
    /// The particle layer, if the scene has one.
    pub particles: Option<ParticleSettings>,
    /// Warnings, each naming the scene and its key, for loads far beyond what the material
    /// bears ([`loads::overload_warnings`]); `run` and `haptic` print them.
    pub load_warnings: Vec<String>,
    /// The files the scene was read from (the scene file, its mesh file): a job refuses an
    /// output folder where it would replace or remove one of them.
    pub input_files: Vec<PathBuf>,
}

impl Scene {
    /// The files the scene was read from, each named as such for an error
    /// ([`crate::output::check_inputs_are_not_outputs`]).
    pub fn inputs(&self) -> impl Iterator<Item = (&'static str, &Path)> {
        self.input_files
            .iter()
            .map(|p| ("file the scene reads", p.as_path()))
    }
}

/// One line per built-in scene: its name and description.
pub fn builtin_list() -> Vec<(String, String)> {
    BUILTIN
        .iter()
        .map(|(name, text)| {
            let desc = toml::from_str::<SceneFile>(text)
                .ok()
                .and_then(|s| s.description)
                .unwrap_or_default();
            (name.to_string(), desc)
        })
        .collect()
}

/// Line number (1-based) of a byte offset.
fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
}

impl Scene {
    /// The TOML text of a built-in scene (a starting point for variants).
    pub fn builtin_text(name: &str) -> Option<&'static str> {
        BUILTIN.iter().find(|(n, _)| *n == name).map(|(_, t)| *t)
    }

    /// Load a built-in scene by name, or a scene file by path.
    pub fn load(name_or_path: &str) -> Result<Scene> {
        if let Some((name, text)) = BUILTIN.iter().find(|(n, _)| *n == name_or_path) {
            return Scene::from_toml(text, &format!("built-in scene '{name}'"), name, None);
        }
        let path = Path::new(name_or_path);
        if !path.exists() {
            let names: Vec<&str> = BUILTIN.iter().map(|(n, _)| *n).collect();
            return Err(PalpateError::SceneParse {
                origin: name_or_path.to_string(),
                message: format!(
                    "no such scene file, and not a built-in scene (built-in: {})",
                    names.join(", ")
                ),
            });
        }
        let text = crate::input::read_regular_text(path, crate::input::MAX_SCENE_BYTES).map_err(
            |source| PalpateError::SceneIo {
                path: path.to_path_buf(),
                source,
            },
        )?;
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "scene".into());
        let mut scene = Scene::from_toml(&text, &path.display().to_string(), &stem, path.parent())?;
        scene.input_files.insert(0, path.to_path_buf());
        Ok(scene)
    }

    /// Parse and validate scene TOML. `origin` names it in errors; `dir` resolves mesh files.
    pub fn from_toml(
        text: &str,
        origin: &str,
        default_name: &str,
        dir: Option<&Path>,
    ) -> Result<Scene> {
        if text.trim().is_empty() {
            return Err(PalpateError::SceneParse {
                origin: origin.to_string(),
                message: "the file is empty (a scene needs at least [mesh] and [material])".into(),
            });
        }
        let file: SceneFile = toml::from_str(text).map_err(|e| {
            let mut message =
                crate::input::clip(&plain_types(&e.message().trim().replace('\n', " ")), 1000);
            let line = e.span().map(|s| {
                let n = line_of(text, s.start);
                let src = text.lines().nth(n - 1).unwrap_or("");
                let src = src.split('#').next().unwrap_or("").trim();
                if let Some(section) = single_table_as_array(src) {
                    message = format!(
                        "[{section}] is a single table: write [{section}], not [[{section}]]"
                    );
                } else if message == "duplicate key" && src.starts_with('[') {
                    message = format!("the table {src} is given twice");
                }
                format!("line {n} `{}`: ", crate::input::excerpt(src))
            });
            PalpateError::SceneParse {
                origin: origin.to_string(),
                message: format!("{}{message}", line.unwrap_or_default()),
            }
        })?;
        Scene::from_file(file, origin, default_name, dir)
    }

    /// Validate a parsed scene file and build its mesh.
    pub fn from_file(
        file: SceneFile,
        origin: &str,
        default_name: &str,
        dir: Option<&Path>,
    ) -> Result<Scene> {
        let bad = |item: &str, message: String| PalpateError::SceneValue {
            origin: origin.to_string(),
            item: item.to_string(),
            message,
        };
        let resolved = material::resolve_material(&file.material, &bad)?;
        let material = resolved.params;
        if resolved.hyperelastic.is_some() && file.particles.is_some() {
            return Err(bad(
                "particles",
                format!(
                    "the particle layer does not support the split law '{}' (use stvk, stable_neohookean or corotational)",
                    material.model.name()
                ),
            ));
        }
        let (mesh, mesh_report) = mesh::build_mesh(&file.mesh, origin, dir, &bad)?;
        let input_files = file
            .mesh
            .file
            .iter()
            .map(|f| match dir {
                Some(d) if f.is_relative() => d.join(f),
                _ => f.clone(),
            })
            .collect();
        if let (Some(h), None) = (&resolved.hyperelastic, resolved.fibre) {
            let fibres: Vec<f32> = mesh
                .fibres
                .iter()
                .flat_map(|f| f.to_array().map(|c| c as f32))
                .collect();
            h.check_fibres(material.model, &fibres, mesh.n_tets())
                .map_err(|e| {
                    let (key, rest) = e.split_once(' ').unwrap_or(("material.fibre", &e));
                    bad(key.trim_end_matches(':'), rest.to_string())
                })?;
        }
        let follower = loads::follower_loads(&file.loads.follower_pressure, &mesh, &bad)?;
        let fixed = fixed::select_fixed(&file.fixed, &mesh, &bad)?;
        let gravity = file.loads.gravity.unwrap_or([0.0; 3]);
        if gravity.iter().any(|g| !g.is_finite()) {
            return Err(bad("loads.gravity", "must be finite".into()));
        }
        let solver = solver::resolve_solver(&file.solver, &bad)?;
        let external_forces = loads::pressure_forces(&file.loads.pressure, &mesh, &bad)?;
        let tool = match &file.tool {
            Some(spec) => Some(tool::resolve_tool(spec, &bad)?),
            None => None,
        };
        let particles = match &file.particles {
            Some(spec) => Some(particles::resolve_particles(spec, &mesh, &bad)?),
            None => None,
        };
        if particles.as_ref().is_some_and(|p| p.exact_coupling)
            && crate::material::elastic_stress_differential(
                material.model,
                glam::Mat3::ZERO,
                glam::Mat3::ZERO,
                1.0,
                1.0,
            )
            .is_none()
        {
            return Err(bad(
                "particles.coupling",
                format!(
                    "\"exact\" needs a material law with a stress differential (stvk, stable_neohookean, corotational), not \"{}\"",
                    material.model.name()
                ),
            ));
        }
        if let Some(name) = &file.name {
            // Bidirectional controls reorder the console line the name is printed on.
            let odd = |c: char| c.is_control() || crate::input::is_bidi_control(c);
            if name.trim().is_empty() || name.chars().any(odd) {
                return Err(bad(
                    "name",
                    format!(
                        "\"{}\" is empty or holds control characters: give a short name, or leave it out to use the file's name",
                        crate::input::excerpt(name)
                    ),
                ));
            }
            if name.chars().count() > MAX_NAME_CHARS {
                return Err(bad(
                    "name",
                    format!(
                        "{} characters, more than {MAX_NAME_CHARS}: give a short name (it heads every console line and summary)",
                        name.chars().count()
                    ),
                ));
            }
        }
        // A split law's E from its bulk modulus K and shear modulus μ, 9Kμ/(3K + μ): through
        // λ = K − 2μ/3 it cancels to 0 when K ≪ μ.
        let youngs_modulus = match &resolved.hyperelastic {
            Some(h) if h.bulk_modulus > 0.0 => {
                9.0 * h.bulk_modulus * material.mu / (3.0 * h.bulk_modulus + material.mu)
            }
            _ => material.youngs_modulus(),
        };
        let mut load_warnings: Vec<String> =
            loads::overload_warnings(&file.loads, youngs_modulus, material.density, &mesh)
                .into_iter()
                .map(|w| format!("{origin}: {w}"))
                .collect();
        if particles
            .as_ref()
            .is_some_and(|p| p.model == ParticleModel::Paper)
            && material.model != crate::material::MaterialModel::Stvk
        {
            load_warnings.push(format!(
                "{origin}: particles.model = \"paper\" gives the particles StVK's stress (paper eq. 1-2, 8) whatever [material] model says, here \"{}\": the core and the particle layer follow different laws (use particles.model = \"tlsph\", which uses the material's)",
                material.model.name()
            ));
        }
        Ok(Scene {
            name: file.name.unwrap_or_else(|| default_name.to_string()),
            origin: origin.to_string(),
            description: file.description.unwrap_or_default(),
            mesh,
            mesh_report,
            material,
            hyperelastic: resolved.hyperelastic,
            fibre: resolved.fibre,
            follower,
            fixed,
            gravity,
            external_forces,
            solver,
            tool,
            particles,
            load_warnings,
            input_files,
        })
    }
}

/// The unit vector along `v`, or None when `v` is zero or not finite. Scaled by its largest
/// component first, so that a finite vector whose length over- or underflows (1e200, 1e-200)
/// still has its direction.
pub fn unit_direction(v: [f64; 3]) -> Option<glam::DVec3> {
    let v = glam::DVec3::from_array(v);
    let scale = v.abs().max_element();
    if !(v.is_finite() && scale > 0.0) {
        return None;
    }
    Some((v / scale).normalize())
}

/// Longest scene `name` accepted, in characters.
pub const MAX_NAME_CHARS: usize = 200;

/// A scene value in an error message: as written for everyday magnitudes, in exponent form
/// beyond them (1e-300 is not printed as 300 digits).
pub struct Num(pub f64);

impl std::fmt::Display for Num {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let a = self.0.abs();
        if a == 0.0 || !a.is_finite() || (1e-4..1e6).contains(&a) {
            write!(f, "{}", self.0)
        } else {
            write!(f, "{:e}", self.0)
        }
    }
}

/// A parser message with Rust's type names in a scene's terms: "expected usize" is "expected
/// a whole number >= 0", "expected struct MeshSpec" is "expected a table ([mesh] …)".
fn plain_types(message: &str) -> String {
    let mut out = message.to_string();
    for (rust, plain) in [
        ("expected usize", "expected a whole number >= 0"),
        ("expected u64", "expected a whole number >= 0"),
        ("expected u32", "expected a whole number >= 0"),
        ("expected i64", "expected a whole number"),
        ("expected f64", "expected a number"),
        ("expected f32", "expected a number"),
        ("expected a sequence", "expected an array [ … ]"),
        ("expected a map", "expected a table"),
        ("floating point `", "number `"),
    ] {
        out = out.replace(rust, plain);
    }
    // "expected struct MeshSpec": a section written as a value.
    while let Some(at) = out.find("expected struct ") {
        let rest = &out[at + "expected struct ".len()..];
        let end = rest
            .find(|c: char| !c.is_alphanumeric() && c != '_')
            .unwrap_or(rest.len());
        out = format!("{}expected a table{}", &out[..at], &rest[end..]);
    }
    out
}

/// The section of a header line `[[name]]` whose section is one table, not a list (serde's
/// message for it names a field type instead).
fn single_table_as_array(line: &str) -> Option<&str> {
    let name = line.strip_prefix("[[")?.strip_suffix("]]")?.trim();
    ["mesh", "material", "loads", "solver", "tool", "particles"]
        .contains(&name)
        .then_some(name)
}

pub(crate) type Bad<'a> = dyn Fn(&str, String) -> PalpateError + 'a;

/// `v` when it is finite and at least `min`; else an error naming `item` ("must be finite
/// and >= …" for an infinity, which is >= any bound but no value to run with).
pub(crate) fn at_least(bad: &Bad, item: &str, v: f64, min: f64, unit: &str) -> Result<f64> {
    if v.is_finite() && v >= min {
        Ok(v)
    } else {
        let what = if v.is_infinite() { "finite and " } else { "" };
        let unit = if unit.is_empty() {
            String::new()
        } else {
            format!(" {unit}")
        };
        Err(bad(
            item,
            format!("must be {what}>= {}{unit}, got {}", Num(min), Num(v)),
        ))
    }
}

pub(crate) fn positive(bad: &Bad, item: &str, v: f64, unit: &str) -> Result<f64> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        let what = if v.is_infinite() { "finite and " } else { "" };
        let unit = if unit.is_empty() {
            String::new()
        } else {
            format!(" {unit}")
        };
        Err(bad(
            item,
            format!("must be {what}> 0{unit}, got {}", Num(v)),
        ))
    }
}
