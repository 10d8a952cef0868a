//! `[mesh]`: a generator with its parameters, or a mesh file; size limits.

use super::{positive, Bad};
use crate::error::Result;
use crate::mesh::{generators, TetMesh, ValidationReport};
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// `[mesh]`: exactly one of `generator` (with its parameters) or `file`.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshSpec {
    /// `"beam"`, `"ellipsoid_shell"` or `"lv"`.
    pub generator: Option<String>,
    /// Path of a mesh file (relative to the scene file).
    pub file: Option<PathBuf>,
    /// beam: box size [x, y, z], m.
    #[serde(default, deserialize_with = "super::exact::option")]
    pub size: Option<[f64; 3]>,
    /// beam: [nx, ny, nz] cells; ellipsoid_shell: [layers through the wall, cells per cube-face edge];
    /// lv: [layers through the wall, disk cells].
    pub cells: Option<Vec<usize>>,
    /// ellipsoid_shell: inner semi-axes [a, b, c], m.
    #[serde(default, deserialize_with = "super::exact::option")]
    pub inner_radii: Option<[f64; 3]>,
    /// ellipsoid_shell: outer semi-axes [a, b, c], m.
    #[serde(default, deserialize_with = "super::exact::option")]
    pub outer_radii: Option<[f64; 3]>,
    /// lv: short-axis radius [endocardium, epicardium], m.
    #[serde(default, deserialize_with = "super::exact::option")]
    pub short_radius: Option<[f64; 2]>,
    /// lv: long-axis radius [endocardium, epicardium], m.
    #[serde(default, deserialize_with = "super::exact::option")]
    pub long_radius: Option<[f64; 2]>,
    /// lv: height of the base plane, m.
    pub base_z: Option<f64>,
    /// lv: one resolution knob k: layers = k, disk = 4k (96 k³ tets).
    pub resolution: Option<usize>,
    /// Factor applied to all coordinates (e.g. 0.001 for a file in mm).
    pub scale: Option<f64>,
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

pub(super) fn build_mesh(
    spec: &MeshSpec,
    origin: &str,
    dir: Option<&Path>,
    bad: &Bad,
) -> Result<(TetMesh, ValidationReport)> {
    let mesh = match (&spec.generator, &spec.file) {
        (Some(_), Some(_)) | (None, None) => {
            return Err(bad(
                "mesh",
                "give exactly one of `generator` or `file`".into(),
            ))
        }
        (None, Some(file)) => {
            only_keys(spec, "a mesh file", &["scale"], bad)?;
            if file.as_os_str().is_empty() {
                return Err(bad("mesh.file", "is empty: give a mesh file's path".into()));
            }
            let path = match dir {
                Some(d) if file.is_relative() => d.join(file),
                _ => file.clone(),
            };
            let mesh = crate::mesh::io::read(&path)?;
            // Its tets' errors name the file they are in. Its tets and vertices are named by their place in the file, which need not be
            // the file's own numbers (1-based TetGen, Gmsh tags).
            let from = format!(
                "{origin}: mesh file {} (elements and nodes counted from 0 in file order)",
                path.display()
            );
            check_memory(mesh.tets.len(), "mesh.file", "validate", bad)?;
            return finish(mesh, spec, &from, bad);
        }
        (Some(g), None) => match g.as_str() {
            "beam" => {
                only_keys(spec, "generator beam", &["size", "cells"], bad)?;
                let size = need(spec.size, "mesh.size", bad)?;
                for (i, s) in size.iter().enumerate() {
                    positive(bad, &format!("mesh.size[{i}]"), *s, "m")?;
                }
                let c = cells_n(spec, 3, bad)?;
                check_count(&[c[0], c[1], c[2], 6], "mesh.cells", bad)?;
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
                check_count(&[36, c[0], c[1], c[1]], "mesh.cells", bad)?;
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
                            "must lie inside the endocardium (|base_z| < {}), got {}{}",
                            geo.long_radius[0],
                            geo.base_z,
                            if spec.base_z.is_none() {
                                " (the default; set mesh.base_z for these radii)"
                            } else {
                                ""
                            }
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
                // With one disk cell the generator's first tets are flat (a degenerate-tet
                // error that would not name the key).
                if disk < 2 {
                    return Err(bad(
                        "mesh.cells",
                        format!("lv needs at least 2 disk cells, got {disk}"),
                    ));
                }
                let item = match spec.resolution {
                    Some(_) => "mesh.resolution",
                    None => "mesh.cells",
                };
                check_count(&[6, layers, disk, disk], item, bad)?;
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
    finish(mesh, spec, origin, bad)
}

/// Scale the mesh by `mesh.scale` and validate it, its errors naming `origin`.
fn finish(
    mut mesh: TetMesh,
    spec: &MeshSpec,
    origin: &str,
    bad: &Bad,
) -> Result<(TetMesh, ValidationReport)> {
    if let Some(s) = spec.scale {
        positive(bad, "mesh.scale", s, "")?;
        for p in &mut mesh.positions {
            *p *= s;
        }
    }
    let report = mesh.validate(origin)?;
    Ok((mesh, report))
}

/// Refuse a generator whose tet count (the product of `factors`) exceeds the limit,
/// overflows, or would not fit in the memory available to generate and validate it.
fn check_count(factors: &[usize], item: &str, bad: &Bad) -> Result<()> {
    match factors.iter().try_fold(1usize, |a, &x| a.checked_mul(x)) {
        Some(tets) if tets <= MAX_GENERATED_TETS => {
            check_memory(tets, item, "generate and validate", bad)
        }
        _ => Err(bad(
            item,
            format!("would make more than the limit of {MAX_GENERATED_TETS} tets"),
        )),
    }
}

/// Refuse a mesh of `tets` tets that the memory available could not take to `purpose`,
/// naming `item`.
fn check_memory(tets: usize, item: &str, purpose: &str, bad: &Bad) -> Result<()> {
    use crate::cpu::memory::{tets_over_available_memory, MESH_BYTES_PER_TET};
    match tets_over_available_memory(tets as f64, MESH_BYTES_PER_TET, purpose) {
        Some(why) => Err(bad(item, why)),
        None => Ok(()),
    }
}
