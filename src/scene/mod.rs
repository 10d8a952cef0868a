//! Scene description: the TOML file format (DESIGN.md §4), its validation, the built-in
//! scenes, and the resolved [`Scene`] that a simulation is built from.
//!
//! Unknown keys are refused. Every error names the scene (file path or built-in name), the
//! key, and what is wrong, on one line.

use crate::error::{PalpateError, Result};
use crate::material::{MaterialModel, MaterialParams};
use crate::mesh::{generators, tags, TetMesh, ValidationReport};
use glam::DVec3;
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// The built-in scenes: (name, TOML text).
pub const BUILTIN: &[(&str, &str)] = &[
    ("beam", include_str!("../../scenes/beam.toml")),
    ("ed0", include_str!("../../scenes/ed0.toml")),
    ("lv", include_str!("../../scenes/lv.toml")),
    ("hm1", include_str!("../../scenes/hm1.toml")),
    ("hm2", include_str!("../../scenes/hm2.toml")),
];

/// The scene `palpate run` uses when none is named.
pub const DEFAULT_SCENE: &str = "lv";

/// `[mesh]`: exactly one of `generator` (with its parameters) or `file`.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshSpec {
    /// `"beam"`, `"ellipsoid_shell"` or `"lv"`.
    pub generator: Option<String>,
    /// Path of a mesh file (relative to the scene file).
    pub file: Option<PathBuf>,
    /// beam: box size [x, y, z], m.
    pub size: Option<[f64; 3]>,
    /// beam: [nx, ny, nz] cells; ellipsoid_shell: [layers through the wall, cells per cube-face edge];
    /// lv: [layers through the wall, disk cells].
    pub cells: Option<Vec<usize>>,
    /// ellipsoid_shell: inner semi-axes [a, b, c], m.
    pub inner_radii: Option<[f64; 3]>,
    /// ellipsoid_shell: outer semi-axes [a, b, c], m.
    pub outer_radii: Option<[f64; 3]>,
    /// lv: short-axis radius [endocardium, epicardium], m.
    pub short_radius: Option<[f64; 2]>,
    /// lv: long-axis radius [endocardium, epicardium], m.
    pub long_radius: Option<[f64; 2]>,
    /// lv: height of the base plane, m.
    pub base_z: Option<f64>,
    /// lv: one resolution knob k: layers = k, disk = 4k (96 k³ tets).
    pub resolution: Option<usize>,
    /// Factor applied to all coordinates (e.g. 0.001 for a file in mm).
    pub scale: Option<f64>,
}

/// `[material]`.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    /// Constitutive model: `"stvk"`, `"stable_neohookean"` or `"corotational"`.
    pub model: Option<String>,
    /// Young's modulus E, Pa.
    pub youngs_modulus: Option<f64>,
    /// Poisson ratio ν, in (−1, 0.5).
    pub poisson_ratio: Option<f64>,
    /// First Lamé parameter λ, Pa (instead of E, ν).
    pub lambda: Option<f64>,
    /// Shear modulus μ, Pa (instead of E, ν).
    pub mu: Option<f64>,
    /// Rest density ρ, kg/m³.
    pub density: Option<f64>,
    /// Viscosity [φ, ψ] of paper eq. (4), Pa·s.
    pub viscosity: Option<[f64; 2]>,
}

/// A plane n·x = offset.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlaneSpec {
    /// Plane normal (need not be unit).
    pub normal: [f64; 3],
    /// Offset along the unit normal, m.
    pub offset: f64,
}

/// An axis-aligned box.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxSpec {
    /// Lower corner, m.
    pub min: [f64; 3],
    /// Upper corner, m.
    pub max: [f64; 3],
}

/// `[[fixed]]`: vertices held at rest, chosen by plane, box or tag.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FixedSpec {
    /// Vertices within `tolerance` of this plane.
    pub plane: Option<PlaneSpec>,
    /// Distance tolerance for `plane`, m (default 1e-6 × the mesh's bounding-box diagonal).
    pub tolerance: Option<f64>,
    /// Vertices inside this box.
    #[serde(rename = "box")]
    pub bbox: Option<BoxSpec>,
    /// Vertices with this surface tag (`endocardium`, `epicardium`, `base`).
    pub tag: Option<String>,
}

/// `[[loads.pressure]]`: a pressure on the boundary faces whose vertices all carry `tag`,
/// pushing into the solid (a dead load: set on the rest shape, constant in direction).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PressureSpec {
    /// Surface tag (`endocardium`, `epicardium`, `base`).
    pub tag: String,
    /// Pressure, Pa.
    pub pascals: f64,
}

/// `[loads]`.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadsSpec {
    /// Gravity, m/s².
    pub gravity: Option<[f64; 3]>,
    /// Surface pressures.
    #[serde(default)]
    pub pressure: Vec<PressureSpec>,
}

/// `dt`: `"auto"` or seconds.
#[derive(Clone, Debug, Deserialize)]
#[serde(untagged)]
pub enum DtSpec {
    /// Seconds.
    Seconds(f64),
    /// Must be `"auto"`.
    Word(String),
}

/// `[solver]`.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SolverSpec {
    /// `"auto"` (safety × stability bound) or a step in seconds.
    pub dt: Option<DtSpec>,
    /// Safety factor for `dt = "auto"`, in (0, 1].
    pub safety: Option<f64>,
    /// Mass-proportional damping α, 1/s: v ← v / (1 + α dt) each step.
    pub damping: Option<f64>,
    /// `--until-static` stops when ‖residual force‖ ≤ tolerance · ‖external load‖.
    pub static_tolerance: Option<f64>,
    /// Simulated time `palpate run` uses when no length is given, s.
    pub duration: Option<f64>,
}

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
}

/// Solver settings after validation.
#[derive(Clone, Debug, PartialEq)]
pub struct SolverSettings {
    /// A fixed step in seconds, or None for auto.
    pub dt: Option<f64>,
    /// Safety factor for auto dt.
    pub safety: f64,
    /// Mass-proportional damping α, 1/s.
    pub damping: f64,
    /// Relative residual tolerance for `--until-static`.
    pub static_tolerance: f64,
    /// Default run length, s.
    pub duration: Option<f64>,
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
    /// Material.
    pub material: MaterialParams,
    /// Per vertex: held fixed at rest.
    pub fixed: Vec<bool>,
    /// Gravity, m/s².
    pub gravity: [f64; 3],
    /// Constant external force per vertex (surface pressures), N.
    pub external_forces: Vec<DVec3>,
    /// Solver settings.
    pub solver: SolverSettings,
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
        let text = std::fs::read_to_string(path).map_err(|source| PalpateError::SceneIo {
            path: path.to_path_buf(),
            source,
        })?;
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "scene".into());
        Scene::from_toml(&text, &path.display().to_string(), &stem, path.parent())
    }

    /// Parse and validate scene TOML. `origin` names it in errors; `dir` resolves mesh files.
    pub fn from_toml(
        text: &str,
        origin: &str,
        default_name: &str,
        dir: Option<&Path>,
    ) -> Result<Scene> {
        let file: SceneFile = toml::from_str(text).map_err(|e| {
            let line = e.span().map(|s| {
                let n = line_of(text, s.start);
                let src = text.lines().nth(n - 1).unwrap_or("");
                let src = src.split('#').next().unwrap_or("").trim();
                format!("line {n} `{src}`: ")
            });
            PalpateError::SceneParse {
                origin: origin.to_string(),
                message: format!(
                    "{}{}",
                    line.unwrap_or_default(),
                    e.message().trim().replace('\n', " ")
                ),
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
        let material = resolve_material(&file.material, &bad)?;
        let (mesh, mesh_report) = build_mesh(&file.mesh, origin, dir, &bad)?;
        let fixed = select_fixed(&file.fixed, &mesh, &bad)?;
        let gravity = file.loads.gravity.unwrap_or([0.0; 3]);
        if gravity.iter().any(|g| !g.is_finite()) {
            return Err(bad("loads.gravity", "must be finite".into()));
        }
        let solver = resolve_solver(&file.solver, &bad)?;
        let external_forces = pressure_forces(&file.loads.pressure, &mesh, &bad)?;
        Ok(Scene {
            name: file.name.unwrap_or_else(|| default_name.to_string()),
            origin: origin.to_string(),
            description: file.description.unwrap_or_default(),
            mesh,
            mesh_report,
            material,
            fixed,
            gravity,
            external_forces,
            solver,
        })
    }
}

type Bad<'a> = dyn Fn(&str, String) -> PalpateError + 'a;

fn positive(bad: &Bad, item: &str, v: f64, unit: &str) -> Result<f64> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(bad(item, format!("must be > 0 {unit}, got {v}")))
    }
}

fn resolve_material(m: &MaterialSpec, bad: &Bad) -> Result<MaterialParams> {
    let name = m.model.as_deref().unwrap_or("stvk");
    let model = MaterialModel::from_name(name).ok_or_else(|| {
        bad(
            "material.model",
            format!("unknown model '{name}' (known: stvk, stable_neohookean, corotational)"),
        )
    })?;
    let (lambda, mu) = match (m.youngs_modulus, m.poisson_ratio, m.lambda, m.mu) {
        (Some(e), Some(nu), None, None) => {
            positive(bad, "material.youngs_modulus", e, "Pa")?;
            if !(nu > -1.0 && nu < 0.5) {
                return Err(bad(
                    "material.poisson_ratio",
                    format!("must be in (-1, 0.5), got {nu}"),
                ));
            }
            MaterialParams::lame_from_young(e, nu)
        }
        (None, None, Some(l), Some(mu)) => {
            positive(bad, "material.mu", mu, "Pa")?;
            // λ may be negative down to the limit of positive bulk modulus K = λ + 2μ/3 > 0.
            if !l.is_finite() || l + 2.0 * mu / 3.0 <= 0.0 {
                return Err(bad(
                    "material.lambda",
                    format!("must give a positive bulk modulus λ + 2μ/3, got λ = {l}"),
                ));
            }
            (l, mu)
        }
        _ => {
            return Err(bad(
                "material",
                "give either youngs_modulus and poisson_ratio, or lambda and mu".into(),
            ))
        }
    };
    let density = positive(
        bad,
        "material.density",
        m.density
            .ok_or_else(|| bad("material.density", "is required (kg/m³)".into()))?,
        "kg/m³",
    )?;
    let [phi, psi] = m.viscosity.unwrap_or([0.0, 0.0]);
    if !(phi.is_finite() && psi.is_finite() && psi >= 0.0 && phi + 2.0 * psi / 3.0 >= 0.0) {
        return Err(bad(
            "material.viscosity",
            format!("[phi, psi] must have psi >= 0 and phi + 2 psi/3 >= 0, got [{phi}, {psi}]"),
        ));
    }
    Ok(MaterialParams {
        lambda,
        mu,
        phi,
        psi,
        density,
        model,
    })
}

fn need<T: Copy>(v: Option<T>, item: &str, bad: &Bad) -> Result<T> {
    v.ok_or_else(|| bad(item, "is required by this generator".into()))
}

fn cells_n(spec: &MeshSpec, n: usize, bad: &Bad) -> Result<Vec<usize>> {
    let cells = spec
        .cells
        .clone()
        .ok_or_else(|| bad("mesh.cells", "is required by this generator".into()))?;
    if cells.len() != n || cells.contains(&0) {
        return Err(bad(
            "mesh.cells",
            format!("needs {n} positive integers, got {cells:?}"),
        ));
    }
    Ok(cells)
}

/// Refuse keys that the chosen generator does not take.
fn only_keys(spec: &MeshSpec, generator: &str, allowed: &[&str], bad: &Bad) -> Result<()> {
    let present = [
        ("size", spec.size.is_some()),
        ("cells", spec.cells.is_some()),
        ("inner_radii", spec.inner_radii.is_some()),
        ("outer_radii", spec.outer_radii.is_some()),
        ("short_radius", spec.short_radius.is_some()),
        ("long_radius", spec.long_radius.is_some()),
        ("base_z", spec.base_z.is_some()),
        ("resolution", spec.resolution.is_some()),
        ("scale", spec.scale.is_some()),
    ];
    for (key, is) in present {
        if is && !allowed.contains(&key) {
            return Err(bad(
                &format!("mesh.{key}"),
                format!("is not a parameter of {generator}"),
            ));
        }
    }
    Ok(())
}

/// Largest mesh a generator is allowed to make (tets), to refuse typos like cells = [1e6, …].
const MAX_GENERATED_TETS: usize = 200_000_000;

fn build_mesh(
    spec: &MeshSpec,
    origin: &str,
    dir: Option<&Path>,
    bad: &Bad,
) -> Result<(TetMesh, ValidationReport)> {
    let mut mesh = match (&spec.generator, &spec.file) {
        (Some(_), Some(_)) | (None, None) => {
            return Err(bad(
                "mesh",
                "give exactly one of `generator` or `file`".into(),
            ))
        }
        (None, Some(file)) => {
            only_keys(spec, "a mesh file", &["scale"], bad)?;
            let path = match dir {
                Some(d) if file.is_relative() => d.join(file),
                _ => file.clone(),
            };
            crate::mesh::io::read(&path)?
        }
        (Some(g), None) => match g.as_str() {
            "beam" => {
                only_keys(spec, "generator beam", &["size", "cells"], bad)?;
                let size = need(spec.size, "mesh.size", bad)?;
                for (i, s) in size.iter().enumerate() {
                    positive(bad, &format!("mesh.size[{i}]"), *s, "m")?;
                }
                let c = cells_n(spec, 3, bad)?;
                check_count(&[c[0], c[1], c[2], 6], bad)?;
                generators::beam(size, [c[0], c[1], c[2]])
            }
            "ellipsoid_shell" => {
                only_keys(
                    spec,
                    "generator ellipsoid_shell",
                    &["inner_radii", "outer_radii", "cells"],
                    bad,
                )?;
                let inner = need(spec.inner_radii, "mesh.inner_radii", bad)?;
                let outer = need(spec.outer_radii, "mesh.outer_radii", bad)?;
                for k in 0..3 {
                    positive(bad, "mesh.inner_radii", inner[k], "m")?;
                    if outer[k] <= inner[k] || !outer[k].is_finite() {
                        return Err(bad(
                            "mesh.outer_radii",
                            format!("must be larger than inner_radii, got {outer:?} vs {inner:?}"),
                        ));
                    }
                }
                let c = cells_n(spec, 2, bad)?;
                check_count(&[36, c[0], c[1], c[1]], bad)?;
                generators::ellipsoid_shell(inner, outer, c[0], c[1])
            }
            "lv" => {
                only_keys(
                    spec,
                    "generator lv",
                    &[
                        "short_radius",
                        "long_radius",
                        "base_z",
                        "cells",
                        "resolution",
                    ],
                    bad,
                )?;
                let mut geo = generators::LvGeometry::default();
                if let Some(r) = spec.short_radius {
                    geo.short_radius = r;
                }
                if let Some(r) = spec.long_radius {
                    geo.long_radius = r;
                }
                if let Some(z) = spec.base_z {
                    geo.base_z = z;
                }
                for (item, r) in [
                    ("mesh.short_radius", geo.short_radius),
                    ("mesh.long_radius", geo.long_radius),
                ] {
                    positive(bad, item, r[0], "m")?;
                    if r[1] <= r[0] || !r[1].is_finite() {
                        return Err(bad(
                            item,
                            format!("epicardium must exceed endocardium, got {r:?}"),
                        ));
                    }
                }
                if !(geo.base_z.is_finite() && geo.base_z.abs() < geo.long_radius[0]) {
                    return Err(bad(
                        "mesh.base_z",
                        format!(
                            "must lie inside the endocardium (|base_z| < {}), got {}",
                            geo.long_radius[0], geo.base_z
                        ),
                    ));
                }
                let (layers, disk) = match (spec.resolution, &spec.cells) {
                    (Some(k), None) if k > 0 && k <= 1 << 20 => (k, 4 * k),
                    (None, Some(_)) => {
                        let c = cells_n(spec, 2, bad)?;
                        (c[0], c[1])
                    }
                    _ => return Err(bad(
                        "mesh",
                        "lv takes either resolution = k in 1..=1048576 or cells = [layers, disk]"
                            .into(),
                    )),
                };
                check_count(&[6, layers, disk, disk], bad)?;
                generators::lv(geo, layers, disk)
            }
            other => {
                return Err(bad(
                    "mesh.generator",
                    format!("unknown generator '{other}' (known: beam, ellipsoid_shell, lv)"),
                ))
            }
        },
    };
    if let Some(s) = spec.scale {
        positive(bad, "mesh.scale", s, "")?;
        for p in &mut mesh.positions {
            *p *= s;
        }
    }
    let report = mesh.validate(origin)?;
    Ok((mesh, report))
}

/// Refuse a generator whose tet count (the product of `factors`) exceeds the limit or
/// overflows.
fn check_count(factors: &[usize], bad: &Bad) -> Result<()> {
    match factors.iter().try_fold(1usize, |a, &x| a.checked_mul(x)) {
        Some(tets) if tets <= MAX_GENERATED_TETS => Ok(()),
        _ => Err(bad(
            "mesh.cells",
            format!("would make more than the limit of {MAX_GENERATED_TETS} tets"),
        )),
    }
}

fn select_fixed(specs: &[FixedSpec], mesh: &TetMesh, bad: &Bad) -> Result<Vec<bool>> {
    let mut fixed = vec![false; mesh.n_vertices()];
    let (lo, hi) = mesh.positions.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), p| (lo.min(*p), hi.max(*p)),
    );
    let diag = (hi - lo).length();
    for (k, spec) in specs.iter().enumerate() {
        let item = format!("fixed[{k}]");
        let chosen = [
            spec.plane.is_some(),
            spec.bbox.is_some(),
            spec.tag.is_some(),
        ]
        .iter()
        .filter(|b| **b)
        .count();
        if chosen != 1 {
            return Err(bad(&item, "give exactly one of plane, box or tag".into()));
        }
        if spec.tolerance.is_some() && spec.plane.is_none() {
            return Err(bad(
                &format!("{item}.tolerance"),
                "applies to a plane only".into(),
            ));
        }
        let select: Box<dyn Fn(usize, DVec3) -> bool> = if let Some(plane) = &spec.plane {
            let n = DVec3::from_array(plane.normal);
            if n.length() <= 0.0 || !n.is_finite() {
                return Err(bad(
                    &format!("{item}.plane.normal"),
                    "must be a non-zero vector".into(),
                ));
            }
            let n = n.normalize();
            let tol = spec.tolerance.unwrap_or(1e-6 * diag);
            let offset = plane.offset;
            Box::new(move |_, p| (n.dot(p) - offset).abs() <= tol)
        } else if let Some(b) = &spec.bbox {
            let (bmin, bmax) = (DVec3::from_array(b.min), DVec3::from_array(b.max));
            Box::new(move |_, p| p.cmpge(bmin).all() && p.cmple(bmax).all())
        } else {
            let name = spec.tag.as_deref().unwrap_or_default();
            let bit = tags::by_name(name).ok_or_else(|| {
                bad(
                    &format!("{item}.tag"),
                    format!("unknown tag '{name}' (known: endocardium, epicardium, base)"),
                )
            })?;
            if mesh.vertex_tags.is_empty() {
                return Err(bad(
                    &format!("{item}.tag"),
                    "this mesh carries no vertex tags".into(),
                ));
            }
            let tags_of = mesh.vertex_tags.clone();
            Box::new(move |i, _| tags_of[i] & bit != 0)
        };
        let mut count = 0;
        for (i, p) in mesh.positions.iter().enumerate() {
            if select(i, *p) {
                fixed[i] = true;
                count += 1;
            }
        }
        if count == 0 {
            return Err(bad(&item, "selects no vertex".into()));
        }
    }
    Ok(fixed)
}

/// Nodal forces of the pressures: each tagged boundary face (outward normal n, area A)
/// gives −p·A·n/3 to each of its vertices.
fn pressure_forces(specs: &[PressureSpec], mesh: &TetMesh, bad: &Bad) -> Result<Vec<DVec3>> {
    let mut f = vec![DVec3::ZERO; mesh.n_vertices()];
    if specs.is_empty() {
        return Ok(f);
    }
    let faces = mesh.boundary_faces();
    for (k, spec) in specs.iter().enumerate() {
        let item = format!("loads.pressure[{k}]");
        if !spec.pascals.is_finite() {
            return Err(bad(&format!("{item}.pascals"), "must be finite".into()));
        }
        let bit = tags::by_name(&spec.tag).ok_or_else(|| {
            bad(
                &format!("{item}.tag"),
                format!(
                    "unknown tag '{}' (known: endocardium, epicardium, base)",
                    spec.tag
                ),
            )
        })?;
        if mesh.vertex_tags.is_empty() {
            return Err(bad(
                &format!("{item}.tag"),
                "this mesh carries no vertex tags".into(),
            ));
        }
        let mut count = 0;
        for face in &faces {
            if face
                .iter()
                .all(|&v| mesh.vertex_tags[v as usize] & bit != 0)
            {
                let [a, b, c] = face.map(|v| mesh.positions[v as usize]);
                let area_normal = (b - a).cross(c - a) * 0.5;
                for &v in face {
                    f[v as usize] -= area_normal * (spec.pascals / 3.0);
                }
                count += 1;
            }
        }
        if count == 0 {
            return Err(bad(
                &item,
                format!(
                    "no boundary face has all its vertices tagged '{}'",
                    spec.tag
                ),
            ));
        }
    }
    Ok(f)
}

fn resolve_solver(s: &SolverSpec, bad: &Bad) -> Result<SolverSettings> {
    let dt = match &s.dt {
        None => None,
        Some(DtSpec::Word(w)) if w == "auto" => None,
        Some(DtSpec::Word(w)) => {
            return Err(bad(
                "solver.dt",
                format!("must be \"auto\" or seconds, got \"{w}\""),
            ))
        }
        Some(DtSpec::Seconds(v)) => Some(positive(bad, "solver.dt", *v, "s")?),
    };
    let safety = s.safety.unwrap_or(crate::timestep::DEFAULT_SAFETY);
    if !(safety > 0.0 && safety <= 1.0) {
        return Err(bad(
            "solver.safety",
            format!("must be in (0, 1], got {safety}"),
        ));
    }
    let damping = s.damping.unwrap_or(0.0);
    if !(damping.is_finite() && damping >= 0.0) {
        return Err(bad(
            "solver.damping",
            format!("must be >= 0 1/s, got {damping}"),
        ));
    }
    let static_tolerance = s.static_tolerance.unwrap_or(1e-3);
    positive(bad, "solver.static_tolerance", static_tolerance, "")?;
    let duration = match s.duration {
        Some(d) => Some(positive(bad, "solver.duration", d, "s")?),
        None => None,
    };
    Ok(SolverSettings {
        dt,
        safety,
        damping,
        static_tolerance,
        duration,
    })
}
