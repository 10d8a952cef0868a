//! The follower-pressure twins (`follower_pressure` → `follower_pressure_gather`): the load
//! turns with a rigidly rotated body (the dead load does not), a closed surface under one
//! pressure has zero net force and moment for any deformation, the forces do the work
//! −p δV (a consistent load), the ramp factor scales it, and Land et al.'s problem-1 face
//! pushes up with p·A.

#![allow(clippy::needless_range_loop)]

mod common;

use common::{jittered_beam, Rng};
use glam::{DMat3, DVec3};
use palpate::cpu::follower_pressure::{follower_pressure, FollowerLoad};
use palpate::cpu::follower_pressure_gather::{follower_incidence, follower_pressure_gather};
use palpate::cpu::load3;
use palpate::mesh::{generators, TetMesh};
use palpate::params::StepParams;

/// Loaded faces of a mesh and the per-vertex result of the two stages.
struct Follower {
    rest: Vec<f32>,
    faces: Vec<[u32; 3]>,
    pressure: Vec<f32>,
    offsets: Vec<u32>,
    incidence: Vec<u32>,
    n_vertices: usize,
}

impl Follower {
    fn new(mesh: &TetMesh, faces: Vec<[u32; 3]>, pascals: f32) -> Follower {
        let (offsets, incidence) = follower_incidence(mesh.n_vertices(), &faces);
        Follower {
            rest: mesh
                .positions
                .iter()
                .flat_map(|p| p.to_array().map(|c| c as f32))
                .collect(),
            pressure: vec![pascals; faces.len()],
            faces,
            offsets,
            incidence,
            n_vertices: mesh.n_vertices(),
        }
    }

    /// external_forces = dead + follower load at displacements `u` with ramp `s`.
    fn forces(&self, u: &[f32], s: f32, dead: &[f32]) -> Vec<f32> {
        let load = FollowerLoad {
            n_faces: self.faces.len() as u32,
            load_factor: s,
            ..Default::default()
        };
        let flat: Vec<u32> = self.faces.iter().flatten().copied().collect();
        let mut corner = vec![0.0; 9 * self.faces.len()];
        follower_pressure(&load, &self.rest, u, &flat, &self.pressure, &mut corner);
        let params = StepParams {
            n_vertices: self.n_vertices as u32,
            ..Default::default()
        };
        let mut out = vec![0.0; 3 * self.n_vertices];
        follower_pressure_gather(
            &params,
            &corner,
            &self.offsets,
            &self.incidence,
            dead,
            &mut out,
        );
        out
    }
}

fn rigid(mesh: &TetMesh, r: DMat3, t: DVec3) -> Vec<f32> {
    mesh.positions
        .iter()
        .flat_map(|x| ((r * *x + t) - *x).to_array().map(|c| c as f32))
        .collect()
}

fn max_abs(v: &[f32]) -> f32 {
    v.iter().map(|x| x.abs()).fold(0.0, f32::max)
}

#[test]
fn follower_load_rotates_with_the_body_and_the_dead_load_does_not() {
    let mesh = jittered_beam([4, 2, 2], 3);
    // An open surface: the faces on the plane z = 0.
    let faces: Vec<[u32; 3]> = mesh
        .boundary_faces()
        .into_iter()
        .filter(|f| f.iter().all(|&v| mesh.positions[v as usize].z == 0.0))
        .collect();
    assert!(!faces.is_empty());
    let follower = Follower::new(&mesh, faces, 2000.0);
    let zero = vec![0.0; 3 * mesh.n_vertices()];
    let at_rest = follower.forces(&zero, 1.0, &zero);
    let r = DMat3::from_axis_angle(DVec3::new(0.3, 1.0, -0.4).normalize(), 0.9);
    let u = rigid(&mesh, r, DVec3::new(0.01, -0.02, 0.03));
    let rotated = follower.forces(&u, 1.0, &zero);
    // The dead load: the rest-state forces, applied unchanged.
    let dead_after = follower.forces(&u, 0.0, &at_rest);
    let scale = max_abs(&at_rest) as f64;
    let (mut follower_err, mut dead_err) = (0.0f64, 0.0f64);
    for i in 0..mesh.n_vertices() {
        let expected = r * load3(&at_rest, i).as_dvec3();
        follower_err =
            follower_err.max((load3(&rotated, i).as_dvec3() - expected).length() / scale);
        dead_err = dead_err.max((load3(&dead_after, i).as_dvec3() - expected).length() / scale);
    }
    eprintln!("rotated 0.9 rad: follower |f − R f₀| {follower_err:.1e}, dead load {dead_err:.2} (of max |f₀|)");
    assert!(follower_err < 1e-5, "{follower_err}");
    assert!(dead_err > 0.5, "the dead load should not turn: {dead_err}");
}

#[test]
fn closed_surface_has_no_net_force_or_moment_and_the_load_does_work_minus_p_dv() {
    let mesh = jittered_beam([3, 2, 2], 9);
    let p = 1500.0f32;
    let follower = Follower::new(&mesh, mesh.boundary_faces(), p);
    let n = mesh.n_vertices();
    let zero = vec![0.0; 3 * n];
    let mut rng = Rng(4);
    let u: Vec<f32> = (0..3 * n).map(|_| (rng.sym() * 1e-3) as f32).collect();
    let f = follower.forces(&u, 1.0, &zero);
    let (mut sum, mut moment, mut abs) = (DVec3::ZERO, DVec3::ZERO, 0.0);
    for i in 0..n {
        let fi = load3(&f, i).as_dvec3();
        sum += fi;
        moment += (mesh.positions[i] + load3(&u, i).as_dvec3()).cross(fi);
        abs += fi.length();
    }
    eprintln!(
        "closed surface: |Σf| / Σ|f| = {:.1e}, |Σ x×f| = {:.1e}",
        sum.length() / abs,
        moment.length()
    );
    assert!(sum.length() < 1e-5 * abs, "Σf = {sum:?}");
    assert!(moment.length() < 1e-5 * abs * 0.03, "Σ x×f = {moment:?}");

    // Virtual work: Σ f·δu = −p δV, δV by central differences of the deformed volume.
    let volume = |u: &[f32]| -> f64 {
        mesh.tets
            .iter()
            .map(|t| {
                let x = t.map(|i| mesh.positions[i as usize] + load3(u, i as usize).as_dvec3());
                DMat3::from_cols(x[1] - x[0], x[2] - x[0], x[3] - x[0]).determinant() / 6.0
            })
            .sum()
    };
    let dir: Vec<f32> = (0..3 * n).map(|_| rng.sym() as f32).collect();
    let eps = 1e-6f32;
    let plus: Vec<f32> = u.iter().zip(&dir).map(|(a, d)| a + eps * d).collect();
    let minus: Vec<f32> = u.iter().zip(&dir).map(|(a, d)| a - eps * d).collect();
    let dv = (volume(&plus) - volume(&minus)) / 2.0;
    let work: f64 = (0..3 * n)
        .map(|k| f[k] as f64 * ((plus[k] as f64 - minus[k] as f64) / 2.0))
        .sum();
    let err = (work + p as f64 * dv).abs() / (p as f64 * dv).abs();
    eprintln!(
        "virtual work {work:.4e} J vs −p δV {:.4e} J (rel {err:.1e})",
        -p as f64 * dv
    );
    assert!(err < 1e-3, "{err}");
}

#[test]
fn ramp_scales_the_load_and_dead_loads_pass_through() {
    let mesh = jittered_beam([3, 2, 2], 2);
    let follower = Follower::new(&mesh, mesh.boundary_faces(), 800.0);
    let n = mesh.n_vertices();
    let mut rng = Rng(8);
    let u: Vec<f32> = (0..3 * n).map(|_| (rng.sym() * 1e-3) as f32).collect();
    let dead: Vec<f32> = (0..3 * n).map(|_| rng.sym() as f32).collect();
    let zero = vec![0.0; 3 * n];
    let full = follower.forces(&u, 1.0, &zero);
    let quarter = follower.forces(&u, 0.25, &zero);
    let none = follower.forces(&u, 0.0, &dead);
    let both = follower.forces(&u, 0.25, &dead);
    for k in 0..3 * n {
        assert!((quarter[k] - 0.25 * full[k]).abs() <= 1e-6 * max_abs(&full));
        assert_eq!(none[k], dead[k]);
        assert!((both[k] - (dead[k] + quarter[k])).abs() <= 1e-6);
    }
}

#[test]
fn land_problem_1_bottom_face_pushes_up_with_p_times_area() {
    // The 10 × 1 × 1 mm beam, 4 Pa on the face z = 0 (outward normal −z): net +z force p·A.
    let mesh = generators::beam([0.01, 0.001, 0.001], [10, 1, 1]);
    let faces: Vec<[u32; 3]> = mesh
        .boundary_faces()
        .into_iter()
        .filter(|f| f.iter().all(|&v| mesh.positions[v as usize].z == 0.0))
        .collect();
    let follower = Follower::new(&mesh, faces, 4.0);
    let zero = vec![0.0; 3 * mesh.n_vertices()];
    let f = follower.forces(&zero, 1.0, &zero);
    let total: DVec3 = (0..mesh.n_vertices())
        .map(|i| load3(&f, i).as_dvec3())
        .sum();
    let expected = 4.0 * 0.01 * 0.001;
    eprintln!("net force {total:?} N, expected (0, 0, {expected:e})");
    assert!((total - DVec3::new(0.0, 0.0, expected)).length() < 1e-6 * expected);
}
