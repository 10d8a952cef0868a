//! `[loads]`: gravity, dead-load surface pressures and follower pressures.

use super::Bad;
use crate::error::Result;
use crate::mesh::TetMesh;
use glam::DVec3;
use serde::Deserialize;

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

/// `[[loads.follower_pressure]]`: a pressure on the deformed surface (a follower load: its
/// direction and area follow the faces as they move), on the boundary faces whose vertices
/// all carry `tag`, or all lie within `tolerance` of `plane`; optionally ramped linearly from
/// 0 over `ramp_seconds` of simulated time.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FollowerSpec {
    /// Surface tag (`endocardium`, `epicardium`, `base`).
    pub tag: Option<String>,
    /// A plane n·x = offset.
    pub plane: Option<super::PlaneSpec>,
    /// Distance tolerance for `plane`, m (default 1e-6 × the mesh's bounding-box diagonal).
    pub tolerance: Option<f64>,
    /// Pressure, Pa (positive pushes into the body).
    pub pascals: f64,
    /// Ramp time, s (default: the full load from the start).
    pub ramp_seconds: Option<f64>,
}

/// `[loads]`.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadsSpec {
    /// Gravity, m/s².
    #[serde(default, deserialize_with = "super::exact::option")]
    pub gravity: Option<[f64; 3]>,
    /// Surface pressures.
    #[serde(default)]
    pub pressure: Vec<PressureSpec>,
    /// Follower pressures.
    #[serde(default)]
    pub follower_pressure: Vec<FollowerSpec>,
}

/// The resolved follower pressures: loaded faces (outward), their pressure and the ramp.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FollowerLoads {
    /// Loaded boundary faces, oriented with the normal out of the body.
    pub faces: Vec<[u32; 3]>,
    /// Pressure per face, Pa.
    pub face_pressure: Vec<f64>,
    /// Ramp time, s (0: none); items that set different ramps are refused.
    pub ramp_seconds: f64,
}

/// Select the faces of the `[[loads.follower_pressure]]` items (None when there are none).
pub(super) fn follower_loads(
    specs: &[FollowerSpec],
    mesh: &TetMesh,
    bad: &Bad,
) -> Result<Option<FollowerLoads>> {
    if specs.is_empty() {
        return Ok(None);
    }
    let faces = mesh.boundary_faces();
    let diag = super::fixed::bounding_diagonal(mesh);
    let mut out = FollowerLoads::default();
    for (k, spec) in specs.iter().enumerate() {
        let item = format!("loads.follower_pressure[{k}]");
        if !spec.pascals.is_finite() {
            return Err(bad(&format!("{item}.pascals"), "must be finite".into()));
        }
        if let Some(r) = spec.ramp_seconds {
            if !(r.is_finite() && r > 0.0) {
                return Err(bad(
                    &format!("{item}.ramp_seconds"),
                    format!("must be > 0 s, got {}", super::Num(r)),
                ));
            }
            out.ramp_seconds = out.ramp_seconds.max(r);
        }
        let select: Box<dyn Fn(u32) -> bool> = match (&spec.tag, &spec.plane) {
            (Some(name), None) => {
                if spec.tolerance.is_some() {
                    return Err(bad(
                        &format!("{item}.tolerance"),
                        "applies to a plane only".into(),
                    ));
                }
                let bit = super::fixed::tag_bit(name, mesh, &item, bad)?;
                Box::new(move |v| mesh.vertex_tags[v as usize] & bit != 0)
            }
            (None, Some(plane)) => {
                let n = super::fixed::unit_normal(plane, &item, bad)?;
                let tol = super::at_least(
                    bad,
                    &format!("{item}.tolerance"),
                    spec.tolerance.unwrap_or(1e-6 * diag),
                    0.0,
                    "m",
                )?;
                let offset = plane.offset;
                Box::new(move |v| (n.dot(mesh.positions[v as usize]) - offset).abs() <= tol)
            }
            _ => return Err(bad(&item, "give exactly one of tag or plane".into())),
        };
        let before = out.faces.len();
        for face in &faces {
            if face.iter().all(|&v| select(v)) {
                out.faces.push(*face);
                out.face_pressure.push(spec.pascals);
            }
        }
        if out.faces.len() == before {
            return Err(bad(&item, "selects no boundary face".into()));
        }
        // One ramp drives every follower pressure: items that set different ones (or one
        // where another leaves it out) would be merged silently. Checked after the item's
        // own keys, whose errors come first.
        if spec.ramp_seconds != specs[0].ramp_seconds {
            let say =
                |r: Option<f64>| r.map_or("none".to_string(), |r| format!("{} s", super::Num(r)));
            return Err(bad(
                &format!("{item}.ramp_seconds"),
                format!(
                    "is {} but loads.follower_pressure[0]'s is {}: one ramp drives every follower pressure, so give them all the same ramp_seconds",
                    say(spec.ramp_seconds),
                    say(specs[0].ramp_seconds)
                ),
            ));
        }
    }
    Ok(Some(out))
}

/// Nodal forces of the pressures: each tagged boundary face (outward normal n, area A)
/// gives −p·A·n/3 to each of its vertices.
pub(super) fn pressure_forces(
    specs: &[PressureSpec],
    mesh: &TetMesh,
    bad: &Bad,
) -> Result<Vec<DVec3>> {
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
        let bit = super::fixed::tag_bit(&spec.tag, mesh, &item, bad)?;
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

/// Warnings for loads far beyond what the material bears (a unit slip, kPa written as Pa ×
/// 1000, makes a run diverge in its first steps naming only a vertex): a pressure over
/// [`OVERLOAD_RATIO`] × the Young's modulus `youngs_modulus`, or gravity whose weight stress
/// ρ|g|L over the body's size L (the bounding-box diagonal) is. Each names its key.
pub(super) fn overload_warnings(
    loads: &LoadsSpec,
    youngs_modulus: f64,
    density: f64,
    mesh: &TetMesh,
) -> Vec<String> {
    let mut out = Vec::new();
    // A modulus that is not a positive number (a split law's λ cancelling its K at extreme
    // constants) gives no ratio worth a warning.
    if !(youngs_modulus.is_finite() && youngs_modulus > 0.0) {
        return out;
    }
    // Four significant digits: a modulus derived from λ and μ is 300000.00000000006 (the
    // shortest decimal of the rounded value, which reads 1e-20, not 1.0000000000000001e-20).
    let num = |x: f64| super::Num(format!("{x:.3e}").parse().unwrap_or(x));
    let mut pressure = |item: String, p: f64| {
        let ratio = p.abs() / youngs_modulus;
        if ratio > OVERLOAD_RATIO {
            out.push(format!(
                "{item} = {} Pa is {} x the material's Young's modulus ({} Pa): strains far beyond 1, so the run will likely diverge at once (a unit slip?)",
                num(p),
                num(ratio.round()),
                num(youngs_modulus)
            ));
        }
    };
    for (k, p) in loads.pressure.iter().enumerate() {
        pressure(format!("loads.pressure[{k}].pascals"), p.pascals);
    }
    for (k, p) in loads.follower_pressure.iter().enumerate() {
        pressure(format!("loads.follower_pressure[{k}].pascals"), p.pascals);
    }
    if let Some(g) = loads.gravity {
        // Scaled first, so that a component near f64's range gives its magnitude, not inf.
        let g = DVec3::from(g);
        let largest = g.abs().max_element();
        let g = if largest > 0.0 {
            largest * (g / largest).length()
        } else {
            0.0
        };
        let size = super::fixed::bounding_diagonal(mesh);
        let ratio = density * size / youngs_modulus * g;
        if ratio > OVERLOAD_RATIO {
            out.push(format!(
                "loads.gravity = {} m/s^2 weighs the body ({} m, {} kg/m^3) at {} x the material's Young's modulus ({} Pa): strains far beyond 1, so the run will likely diverge at once (a unit slip?)",
                num(g),
                num(size),
                num(density),
                num(ratio.round()),
                num(youngs_modulus)
            ));
        }
    }
    out
}

/// Load stress over Young's modulus above which [`overload_warnings`] warns.
pub const OVERLOAD_RATIO: f64 = 10.0;
