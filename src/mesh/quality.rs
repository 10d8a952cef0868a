//! The `palpate mesh` report: counts, volume, dihedral angles, an aspect-ratio histogram,
//! and the stable time step of the scene's material on this mesh.

use super::tet_quality;
use crate::scene::Scene;
use crate::timestep::TimeStepBounds;
use std::fmt::Write;

/// Upper edges of the aspect-ratio histogram bins (longest edge / smallest altitude; a
/// regular tet has 1.22).
pub const ASPECT_BINS: [f64; 7] = [1.5, 2.0, 3.0, 5.0, 10.0, 100.0, f64::INFINITY];

/// Counts of tets per [`ASPECT_BINS`] bin.
pub fn aspect_histogram(mesh: &super::TetMesh) -> [usize; 7] {
    let mut h = [0; 7];
    for t in 0..mesh.n_tets() {
        let a = tet_quality(&mesh.corners(t)).aspect_ratio;
        let k = ASPECT_BINS.iter().position(|&b| a <= b).unwrap_or(6);
        h[k] += 1;
    }
    h
}

/// Index of the tet with the smallest altitude and that altitude.
pub fn worst_altitude(mesh: &super::TetMesh) -> (usize, f64) {
    (0..mesh.n_tets())
        .map(|t| (t, tet_quality(&mesh.corners(t)).min_altitude))
        .fold((0, f64::INFINITY), |a, b| if b.1 < a.1 { b } else { a })
}

/// The text report for a scene's mesh.
pub fn report(scene: &Scene) -> String {
    let mesh = &scene.mesh;
    let s = mesh.stats();
    let b = TimeStepBounds::new(
        &crate::model::Model::stepped_material(scene),
        s.min_altitude,
        s.min_edge,
    );
    let (worst, _) = worst_altitude(mesh);
    let regions = {
        let mut r: Vec<u32> = mesh.regions.clone();
        r.sort_unstable();
        r.dedup();
        r
    };
    let mut out = String::new();
    let _ = writeln!(out, "scene {} ({})", scene.name, scene.origin);
    let _ = writeln!(
        out,
        "vertices {}, tets {}, boundary faces {}, regions {:?}",
        s.vertices, s.tets, s.boundary_faces, regions
    );
    let _ = writeln!(
        out,
        "volume {:.6e} m^3; tet volume min {:.3e}, mean {:.3e} m^3",
        s.volume, s.min_volume, s.mean_volume
    );
    let _ = writeln!(
        out,
        "dihedral angle min {:.2} deg, max {:.2} deg",
        s.min_dihedral_deg, s.max_dihedral_deg
    );
    let _ = writeln!(
        out,
        "shortest edge {:.3e} m, smallest altitude {:.3e} m (tet {worst})",
        s.min_edge, s.min_altitude
    );
    let _ = write!(
        out,
        "aspect ratio (longest edge / smallest altitude) histogram:"
    );
    let mut lo = 0.0;
    for (k, n) in aspect_histogram(mesh).iter().enumerate() {
        let _ = write!(out, " [{lo}, {}]: {n};", ASPECT_BINS[k]);
        lo = ASPECT_BINS[k];
    }
    let _ = writeln!(out);
    let scaling = scene.solver.mass_scaling;
    let _ = writeln!(
        out,
        "stable dt: {:.3e} s (h / c_p with viscosity; c_p = {:.3e} m/s{}); auto dt {:.3e} s (safety {}); paper eq. 14: {:.3e} s",
        b.dt_bound,
        b.p_wave_speed,
        if scaling != 1.0 {
            format!(", mass scaling {scaling}")
        } else {
            String::new()
        },
        scene.solver.safety * b.dt_bound,
        scene.solver.safety,
        b.dt_paper_eq14
    );
    if let Some(p) = &scene.particles {
        let _ = writeln!(
            out,
            "particle layer: region {}, spacing {:.3e} m, about {:.0} particles (sampled by `run`)",
            p.region,
            p.spacing,
            crate::scene::particles::estimated_count(mesh, p)
        );
    }
    if scene.particles.is_some() || scene.tool.is_some() {
        let _ = writeln!(
            out,
            "`run` and `haptic` also bound dt by the particle layer and the tool's contact springs: their dt can be smaller than this one"
        );
    }
    if !mesh.fibres.is_empty() {
        let _ = writeln!(out, "fibres: one per tet (helix-angle rule)");
    }
    out
}
