//! `[loads]`: gravity and dead-load surface pressures.

use super::Bad;
use crate::error::Result;
use crate::mesh::{tags, TetMesh};
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
