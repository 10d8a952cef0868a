//! `[[fixed]]`: vertices held at rest, selected by plane, box or surface tag.

use super::Bad;
use crate::error::Result;
use crate::mesh::{tags, TetMesh};
use glam::DVec3;
use serde::Deserialize;

/// A plane n·x = offset.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlaneSpec {
    /// Plane normal (need not be unit).
    #[serde(deserialize_with = "super::exact::array")]
    pub normal: [f64; 3],
    /// Offset along the unit normal, m.
    pub offset: f64,
}

/// An axis-aligned box.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxSpec {
    /// Lower corner, m.
    #[serde(deserialize_with = "super::exact::array")]
    pub min: [f64; 3],
    /// Upper corner, m.
    #[serde(deserialize_with = "super::exact::array")]
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

/// The mesh's bounding-box diagonal, m: the scale of a plane's default tolerance.
pub(super) fn bounding_diagonal(mesh: &TetMesh) -> f64 {
    let (lo, hi) = mesh.positions.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), p| (lo.min(*p), hi.max(*p)),
    );
    (hi - lo).length()
}

/// The unit normal of `plane`; a zero or non-finite normal is an error naming
/// `{item}.plane.normal`.
pub(super) fn unit_normal(plane: &PlaneSpec, item: &str, bad: &Bad) -> Result<DVec3> {
    super::unit_direction(plane.normal).ok_or_else(|| {
        bad(
            &format!("{item}.plane.normal"),
            "must be a finite non-zero vector".into(),
        )
    })
}

/// The vertex-tag bit of surface tag `name`; an unknown tag, or a mesh without vertex tags,
/// is an error naming `{item}.tag`.
pub(super) fn tag_bit(name: &str, mesh: &TetMesh, item: &str, bad: &Bad) -> Result<u32> {
    // A mesh without tags is named first: listing the known tags would suggest they exist.
    if mesh.vertex_tags.is_empty() {
        return Err(bad(
            &format!("{item}.tag"),
            format!("this mesh carries no vertex tags, so tag '{name}' selects nothing"),
        ));
    }
    tags::by_name(name).ok_or_else(|| {
        bad(
            &format!("{item}.tag"),
            format!("unknown tag '{name}' (known: endocardium, epicardium, base)"),
        )
    })
}

pub(super) fn select_fixed(specs: &[FixedSpec], mesh: &TetMesh, bad: &Bad) -> Result<Vec<bool>> {
    let mut fixed = vec![false; mesh.n_vertices()];
    let diag = bounding_diagonal(mesh);
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
        let finite = |what: &str, v: &[f64]| {
            if v.iter().all(|x| x.is_finite()) {
                Ok(())
            } else {
                Err(bad(
                    &format!("{item}.{what}"),
                    match v {
                        [one] => format!("must be finite, got {}", super::Num(*one)),
                        _ => format!("must be finite, got {v:?}"),
                    },
                ))
            }
        };
        if let Some(plane) = &spec.plane {
            finite("plane.normal", &plane.normal)?;
            finite("plane.offset", &[plane.offset])?;
        }
        if let Some(b) = &spec.bbox {
            finite("box.min", &b.min)?;
            finite("box.max", &b.max)?;
            if let Some(k) = (0..3).find(|&k| b.min[k] > b.max[k]) {
                return Err(bad(
                    &format!("{item}.box"),
                    format!(
                        "min {:?} is above max {:?} along {} (the box holds no point)",
                        b.min,
                        b.max,
                        ["x", "y", "z"][k]
                    ),
                ));
            }
        }
        if let Some(t) = spec.tolerance {
            super::at_least(bad, &format!("{item}.tolerance"), t, 0.0, "m")?;
        }
        let select: Box<dyn Fn(usize, DVec3) -> bool> = if let Some(plane) = &spec.plane {
            let n = unit_normal(plane, &item, bad)?;
            let tol = spec.tolerance.unwrap_or(1e-6 * diag);
            let offset = plane.offset;
            Box::new(move |_, p| (n.dot(p) - offset).abs() <= tol)
        } else if let Some(b) = &spec.bbox {
            let (bmin, bmax) = (DVec3::from_array(b.min), DVec3::from_array(b.max));
            Box::new(move |_, p| p.cmpge(bmin).all() && p.cmple(bmax).all())
        } else {
            let bit = tag_bit(spec.tag.as_deref().unwrap_or_default(), mesh, &item, bad)?;
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
