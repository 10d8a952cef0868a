//! `[tool]`: a rigid sphere the user holds. Contact is a penalty per unit area of the tissue
//! surface (so the force does not depend on the mesh), optionally damped; `palpate run`
//! moves the tool along a keyframed `path`, `palpate haptic` moves it with the device
//! (device positions are offsets from `home`).

use super::{positive, Bad};
use crate::error::Result;
use crate::mesh::TetMesh;
use glam::{DMat3, DVec3};
use serde::Deserialize;

/// `[tool]` as written in the scene file.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ToolSpec {
    /// Sphere radius, m.
    pub radius: Option<f64>,
    /// Contact penalty, Pa per metre of penetration (force per unit surface area per metre).
    pub stiffness: Option<f64>,
    /// Contact damping, Pa·s/m (force per unit area per m/s of approach speed; default 0).
    pub damping: Option<f64>,
    /// Keyframes `[t s, x m, y m, z m]`, time strictly increasing; linear between them,
    /// held after the last.
    #[serde(default, deserialize_with = "super::exact::option_rows")]
    pub path: Option<Vec<[f64; 4]>>,
    /// Where the haptic device's origin maps to, m (default: the first keyframe).
    #[serde(default, deserialize_with = "super::exact::option")]
    pub home: Option<[f64; 3]>,
}

/// A validated tool.
#[derive(Clone, Debug, PartialEq)]
pub struct Tool {
    /// Sphere radius, m.
    pub radius: f64,
    /// Contact penalty per unit area, Pa/m.
    pub stiffness: f64,
    /// Contact damping per unit area, Pa·s/m.
    pub damping: f64,
    /// Keyframes (t, position), t strictly increasing (may be empty for `haptic`).
    pub path: Vec<(f64, DVec3)>,
    /// The scene position of the device origin, m.
    pub home: DVec3,
}

impl Tool {
    /// The tool's centre at time `t` on the path: linear between keyframes, the first before
    /// the first keyframe, held after the last; `home` without a path.
    pub fn position_at(&self, t: f64) -> DVec3 {
        let p = &self.path;
        match p.iter().position(|(tk, _)| *tk > t) {
            None => p.last().map_or(self.home, |(_, x)| *x),
            Some(0) => p[0].1,
            Some(k) => {
                let (t0, x0) = p[k - 1];
                let (t1, x1) = p[k];
                x0 + (x1 - x0) * ((t - t0) / (t1 - t0))
            }
        }
    }

    /// The tool's speed on the path's leg that starts at or before `t` and ends after it,
    /// m/s (0 before the first keyframe and from the last one on: the tool stays put).
    pub fn leg_speed_at(&self, t: f64) -> f64 {
        let p = &self.path;
        match p.iter().position(|(tk, _)| *tk > t) {
            Some(k) if k > 0 => (p[k].1 - p[k - 1].1).length() / (p[k].0 - p[k - 1].0),
            _ => 0.0,
        }
    }

    /// The path's fastest leg, [`fastest_leg`].
    pub fn fastest_leg(&self) -> Option<(f64, f64, f64)> {
        fastest_leg(self.path.iter().copied())
    }

    /// The path's fastest leg that presses into the tissue or moves the tool within it: one
    /// that ends inside the mesh's rest surface ([`Tool::surface_gap`] < 0) no farther out
    /// than it began (a withdrawal is not one); as [`fastest_leg`].
    pub fn fastest_pressing_leg(&self, mesh: &TetMesh) -> Option<(f64, f64, f64)> {
        // Signed: a centre inside the tissue is the radius plus its depth in (the distance to
        // the surface alone grows again past the surface, and read a deeper press as a
        // withdrawal).
        let faces: Vec<[DVec3; 3]> = mesh
            .boundary_faces()
            .into_iter()
            .map(|f| f.map(|i| mesh.positions[i as usize]))
            .collect();
        let gaps: Vec<f64> = self
            .path
            .iter()
            .map(|(_, x)| {
                let d =
                    crate::particles::sampling::distance_to_triangles(faces.iter().copied(), *x);
                if centre_inside(mesh, *x).is_some() {
                    -d - self.radius
                } else {
                    d - self.radius
                }
            })
            .collect();
        (1..self.path.len())
            .filter(|&k| gaps[k] < 0.0 && gaps[k] <= gaps[k - 1])
            .filter_map(|k| fastest_leg([self.path[k - 1], self.path[k]]))
            .max_by(|a, b| a.0.total_cmp(&b.0))
    }

    /// Time of the last keyframe (0 without a path).
    pub fn path_end(&self) -> f64 {
        self.path.last().map_or(0.0, |(t, _)| *t)
    }

    /// The distance from the sphere at `centre` to the mesh's boundary surface at rest (the
    /// nearest boundary point's distance less the radius; negative where the surface reaches
    /// into the sphere), scene length units.
    pub fn surface_gap(&self, mesh: &TetMesh, centre: DVec3) -> f64 {
        crate::particles::sampling::distance_to_triangles(
            mesh.boundary_faces()
                .into_iter()
                .map(|f| f.map(|i| mesh.positions[i as usize])),
            centre,
        ) - self.radius
    }

    /// How the sphere at `centre` overlaps the tissue at rest: its centre inside a tet (all
    /// four barycentric coordinates ≥ 0), else how deep the boundary surface reaches into it
    /// (R − the distance from the centre to the nearest boundary triangle, when > 0), else
    /// None. A tool that starts in the tissue shoves it out at once, or through the wall when
    /// it holds more than the wall's thickness.
    pub fn overlap(&self, mesh: &TetMesh, centre: DVec3) -> Option<ToolOverlap> {
        let inside = centre_inside(mesh, centre);
        let depth = -self.surface_gap(mesh, centre);
        match inside {
            Some(tet) if depth <= 0.0 => Some(ToolOverlap::Embedded { tet, gap: -depth }),
            Some(tet) => Some(ToolOverlap::CentreInside { tet }),
            None => (depth > 0.0).then_some(ToolOverlap::Surface { depth }),
        }
    }
}

/// The first tet of `mesh` at rest that holds `point` (all four barycentric coordinates
/// ≥ 0), if any.
fn centre_inside(mesh: &TetMesh, point: DVec3) -> Option<usize> {
    mesh.tets.iter().position(|tet| {
        let p = tet.map(|i| mesh.positions[i as usize]);
        let m = DMat3::from_cols(p[1] - p[0], p[2] - p[0], p[3] - p[0]);
        if m.determinant() == 0.0 {
            return false;
        }
        let b = m.inverse() * (point - p[0]);
        b.min_element() >= 0.0 && b.x + b.y + b.z <= 1.0
    })
}

/// Where a tool overlaps the tissue at rest ([`Tool::overlap`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ToolOverlap {
    /// The tool's centre lies inside tet `tet`.
    CentreInside {
        /// The tet holding the centre.
        tet: usize,
    },
    /// The whole sphere lies inside the tissue (its centre in tet `tet`), `gap` clear of the
    /// surface: the contact, which acts on the surface, cannot reach it.
    Embedded {
        /// The tet holding the centre.
        tet: usize,
        /// The distance from the sphere to the nearest boundary point, scene length units.
        gap: f64,
    },
    /// The boundary surface reaches `depth` into the sphere.
    Surface {
        /// R − the distance from the centre to the nearest boundary point, scene length units.
        depth: f64,
    },
}

impl std::fmt::Display for ToolOverlap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ToolOverlap::CentreInside { tet } => write!(
                f,
                "its centre lies inside the tissue (tet {tet}); its contact shoves the tissue out at once"
            ),
            ToolOverlap::Embedded { tet, gap } => write!(
                f,
                "it lies wholly inside the tissue (its centre in tet {tet}, {gap:.3e} clear of the surface), where the contact, which acts on the surface, cannot reach: it touches nothing until it comes out"
            ),
            ToolOverlap::Surface { depth } => write!(
                f,
                "the surface reaches {depth:.3e} m into it; its contact shoves the tissue out at once"
            ),
        }
    }
}

/// Validate `[tool]`: radius and stiffness > 0, damping ≥ 0, keyframes finite with strictly
/// increasing times, and a home or a path.
pub(super) fn resolve_tool(spec: &ToolSpec, bad: &Bad) -> Result<Tool> {
    let radius = positive(
        bad,
        "tool.radius",
        spec.radius
            .ok_or_else(|| bad("tool.radius", "is required (m)".into()))?,
        "m",
    )?;
    let stiffness = positive(
        bad,
        "tool.stiffness",
        spec.stiffness
            .ok_or_else(|| bad("tool.stiffness", "is required (Pa/m)".into()))?,
        "Pa/m",
    )?;
    let damping = super::at_least(
        bad,
        "tool.damping",
        spec.damping.unwrap_or(0.0),
        0.0,
        "Pa s/m",
    )?;
    if spec.path.as_ref().is_some_and(|p| p.is_empty()) {
        return Err(bad(
            "tool.path",
            "is empty: give at least one [t, x, y, z] keyframe, or leave path out (the tool then stays at home)".into(),
        ));
    }
    let mut path = Vec::new();
    for (k, row) in spec.path.iter().flatten().enumerate() {
        if row.iter().any(|v| !v.is_finite()) {
            return Err(bad(
                &format!("tool.path[{k}]"),
                format!("must be finite, got {row:?}"),
            ));
        }
        let (t, x) = (row[0], DVec3::new(row[1], row[2], row[3]));
        if let Some((t_prev, _)) = path.last() {
            if t <= *t_prev {
                return Err(bad(
                    &format!("tool.path[{k}]"),
                    format!("time {t} s is not after the previous keyframe's {t_prev} s"),
                ));
            }
        }
        path.push((t, x));
    }
    let home = match (spec.home, path.first()) {
        (Some(h), _) if h.iter().all(|v| v.is_finite()) => DVec3::from_array(h),
        (Some(h), _) => {
            return Err(bad("tool.home", format!("must be finite, got {h:?}")));
        }
        (None, Some((_, x))) => *x,
        (None, None) => {
            return Err(bad(
                "tool",
                "give a path of [t, x, y, z] keyframes or a home position".into(),
            ))
        }
    };
    Ok(Tool {
        radius,
        stiffness,
        damping,
        path,
        home,
    })
}

/// The fastest leg of a piecewise-linear path through `(t, x)` keyframes (times increasing):
/// (speed m/s, its start, its end s); None with fewer than two keyframes.
pub fn fastest_leg(keyframes: impl IntoIterator<Item = (f64, DVec3)>) -> Option<(f64, f64, f64)> {
    let mut last: Option<(f64, DVec3)> = None;
    let mut fastest: Option<(f64, f64, f64)> = None;
    for (t, x) in keyframes {
        if let Some((t0, x0)) = last {
            let speed = (x - x0).length() / (t - t0);
            if fastest.is_none_or(|f| speed > f.0) {
                fastest = Some((speed, t0, t));
            }
        }
        last = Some((t, x));
    }
    fastest
}

/// The leg of a piecewise-linear path through `(t, x)` keyframes that moves the tool
/// farthest in a step of `step_seconds` (speed × min(step, the leg's duration)): (speed m/s,
/// its start, its end s), as [`fastest_leg`]; the leg for [`tunnelling_warning`] (the
/// fastest leg may be too short to matter beside a slower, longer one).
pub fn longest_step_leg(
    keyframes: impl IntoIterator<Item = (f64, DVec3)>,
    step_seconds: f64,
) -> Option<(f64, f64, f64)> {
    let mut last: Option<(f64, DVec3)> = None;
    let mut longest: Option<(f64, (f64, f64, f64))> = None;
    for (t, x) in keyframes {
        if let Some((t0, x0)) = last {
            let speed = (x - x0).length() / (t - t0);
            let per_step = speed * step_seconds.min(t - t0);
            if longest.is_none_or(|(d, _)| per_step > d) {
                longest = Some((per_step, (speed, t0, t)));
            }
        }
        last = Some((t, x));
    }
    longest.map(|(_, leg)| leg)
}

/// The warning for a tool moved by `what` (e.g. "tool.path moves the tool") along `leg`
/// ([`longest_step_leg`]) when it covers more than its `radius` in a step of `step_seconds`: it
/// can then pass through the surface between two steps without touching it.
pub fn tunnelling_warning(
    what: &str,
    leg: (f64, f64, f64),
    step_seconds: f64,
    radius: f64,
) -> Option<String> {
    let (speed, from, to) = leg;
    // A leg shorter than a step moves the tool its own length in it, no more.
    let per_step = speed * step_seconds.min(to - from);
    (per_step > radius).then(|| {
        format!(
            "{what} at {speed:.3e} m/s from t = {} to {} s: {per_step:.3e} m a step, more than the tool's radius {radius:.3e} m, so it can pass through the surface between two steps without touching it (slow it down)",
            short_time(from),
            short_time(to)
        )
    })
}

/// The warning for a tool that `what` moves `travel` m (at `speed` m/s) between two
/// activation updates of the particles (`steps` core steps apart) when that is more than
/// their `activation_radius`: the tool can then reach particles still embedded in their host
/// tets (their contact goes to the host, the coarse core's response) before an update wakes
/// them.
pub fn activation_lag_warning(
    what: &str,
    speed: f64,
    travel: f64,
    steps: u32,
    activation_radius: f64,
) -> Option<String> {
    (travel > activation_radius).then(|| {
        format!(
            "{what} at up to {speed:.3e} m/s: {travel:.3e} m between two activation updates (particles.activation_interval = {steps} steps), more than particles.activation_radius = {activation_radius:.3e} m, so it can touch particles before they wake (the coarse core answers there); lower activation_interval or raise activation_radius"
        )
    })
}

/// A time for a message: as written when short (a keyframe's `0.5`), else to 5 significant
/// digits (a computed `0.04997868126357471` as `4.9979e-2`).
pub fn short_time(t: f64) -> String {
    let plain = format!("{t}");
    if plain.len() <= 8 {
        plain
    } else {
        format!("{t:.4e}")
    }
}

#[cfg(test)]
mod tests {
    use super::{longest_step_leg, short_time, tunnelling_warning, Tool};
    use glam::DVec3;

    #[test]
    fn a_legs_speed_is_the_one_the_tool_moves_at_then() {
        let tool = Tool {
            radius: 0.004,
            stiffness: 1e8,
            damping: 0.0,
            // Held until 0.1 s, 3 mm in 0.1 s, held, 1 mm back in 0.01 s.
            path: vec![
                (0.1, DVec3::ZERO),
                (0.2, DVec3::new(-0.003, 0.0, 0.0)),
                (0.5, DVec3::new(-0.003, 0.0, 0.0)),
                (0.51, DVec3::new(-0.002, 0.0, 0.0)),
            ],
            home: DVec3::ZERO,
        };
        for (t, want) in [
            (0.0, 0.0),
            (0.1, 0.03),
            (0.15, 0.03),
            (0.2, 0.0),
            (0.505, 0.1),
            (0.51, 0.0),
            (9.0, 0.0),
        ] {
            let v = tool.leg_speed_at(t);
            assert!((v - want).abs() < 1e-9, "at {t} s: {v} m/s, not {want}");
        }
    }

    #[test]
    fn the_longest_step_is_not_always_the_fastest_leg() {
        // 3 mm in 1 µs (3000 m/s), then 10 mm in 1 ms (10 m/s): with 1 ms steps the second
        // moves the tool 10 mm a step, the first only its 3 mm.
        let path = [
            (0.0, DVec3::ZERO),
            (1e-6, DVec3::new(0.003, 0.0, 0.0)),
            (0.001001, DVec3::new(0.013, 0.0, 0.0)),
        ];
        let (speed, from, to) = longest_step_leg(path, 1e-3).unwrap();
        assert!((speed - 10.0).abs() < 1e-6 && from == 1e-6 && to == 0.001001);
        assert!(tunnelling_warning("it moves", (speed, from, to), 1e-3, 0.004).is_some());
    }

    #[test]
    fn the_tunnelling_warning_counts_a_short_leg_once_and_prints_short_times() {
        // 10 mm in 1 ms, steps of 2 ms: the tool moves 10 mm in the step, not 20.
        let w = tunnelling_warning("it moves", (10.0, 0.0, 0.001), 0.002, 0.004).unwrap();
        assert!(w.contains("1.000e-2 m a step"), "{w}");
        // 3 mm in 1e-12 s: 3 mm in the step (the leg's length), under a 4 mm radius.
        assert_eq!(
            tunnelling_warning("it moves", (3e9, 0.0, 1e-12), 1e-3, 0.004),
            None
        );
        // A long leg: speed × step.
        let w = tunnelling_warning("it moves", (10.0, 0.5, 2.0), 1e-3, 0.004).unwrap();
        assert!(w.contains("from t = 0.5 to 2 s: 1.000e-2 m a step"), "{w}");
        assert_eq!(short_time(0.03), "0.03");
        assert_eq!(short_time(0.04997868126357471), "4.9979e-2");
        assert_eq!(short_time(1e-12), "1.0000e-12");
    }
}
