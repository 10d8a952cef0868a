//! The CPU reference path checked against mathematics: forces are the negative energy
//! gradient, the paper's literal eq. (6) gives the same forces, the patch test, rigid-motion
//! invariance, momentum balance, and energy behaviour of whole trajectories.

#![allow(clippy::needless_range_loop)] // the paper's formulas, index by index

mod common;

use common::{free_model, jittered_beam, tissue, Rng};
use glam::{DMat3, DVec3, Mat3, Vec3};
use palpate::cpu::fem_forces::{load_dm_inv, tet_forces, FemVariant};
use palpate::cpu::{fem_forces, gather, load3, CpuStepper};
use palpate::material::MaterialModel;
use palpate::model::Model;
use palpate::params::StepParams;
use palpate::stepper::{State, Stepper};

fn params(model: &Model) -> StepParams {
    model.step_params(1e-5, 0.0)
}

/// Internal forces (per vertex, packed) and total elastic energy for displacements `u`.
fn forces_and_energy(model: &Model, u: &[f32], v: &[f32]) -> (Vec<f32>, f64) {
    let p = params(model);
    let mut corner = vec![0.0; 12 * model.n_tets()];
    let mut energy = vec![0.0; model.n_tets()];
    fem_forces(
        &p,
        u,
        v,
        &model.tets,
        &model.dm_inv,
        &model.rest_volume,
        &mut corner,
        &mut energy,
        model.fem_variant(),
    );
    let mut f = vec![0.0; 3 * model.n_vertices()];
    gather(
        &p,
        &corner,
        &model.incidence_offsets,
        &model.incidence,
        &model.mass,
        &model.external_forces,
        &mut f,
    );
    (f, energy.iter().map(|&e| e as f64).sum())
}

fn random_displacement(model: &Model, rng: &mut Rng, amplitude: f64) -> Vec<f32> {
    (0..3 * model.n_vertices())
        .map(|_| (rng.sym() * amplitude) as f32)
        .collect()
}

#[test]
fn forces_are_the_negative_energy_gradient() {
    let mesh = jittered_beam([3, 2, 2], 7);
    let model = free_model(&mesh, tissue());
    let mut rng = Rng(11);
    let h = 0.01 * 0.5; // half a cell
    let u = random_displacement(&model, &mut rng, 0.05 * h);
    let v = vec![0.0; u.len()];
    let (f, _) = forces_and_energy(&model, &u, &v);
    let fmax = f.iter().map(|x| x.abs()).fold(0.0, f32::max) as f64;
    let delta = 1e-4 * h;
    let mut worst: f64 = 0.0;
    for k in (0..u.len()).step_by(7) {
        let mut up = u.clone();
        up[k] += delta as f32;
        let mut dn = u.clone();
        dn[k] -= delta as f32;
        let d = (up[k] as f64) - (dn[k] as f64);
        let fd = -(forces_and_energy(&model, &up, &v).1 - forces_and_energy(&model, &dn, &v).1) / d;
        worst = worst.max((fd - f[k] as f64).abs() / fmax);
    }
    assert!(
        worst < 2e-3,
        "finite-difference mismatch {worst:.2e} of max force"
    );
}

/// Paper eq. (1), (2), (6) literally, in f64: β from N_i(X_j) = δ_ij, ε = (∂x/∂u·∂x/∂u) − δ,
/// σ = λ tr(ε) I + 2μ ε, f_i = vol/2 Σ_j x_j Σ_k Σ_l β_jl β_ik σ_kl (+ eq. 3–4 for viscosity).
fn paper_eq6(
    rest: [DVec3; 4],
    x: [DVec3; 4],
    xdot: [DVec3; 4],
    lambda: f64,
    mu: f64,
    phi: f64,
    psi: f64,
) -> [DVec3; 4] {
    // M[j] = [X_j, 1]; β = (Mᵀ)⁻¹ so that Σ_k β_ik M[j][k] = δ_ij. Solve via 3×3 blocks:
    let dm = DMat3::from_cols(rest[1] - rest[0], rest[2] - rest[0], rest[3] - rest[0]);
    let inv = dm.inverse();
    // gradients of N_1..3 are the rows of Dm⁻¹, ∇N_0 = −Σ.
    let mut grad = [DVec3::ZERO; 4];
    for i in 1..4 {
        grad[i] = inv.row(i - 1);
    }
    grad[0] = -(grad[1] + grad[2] + grad[3]);
    let beta = |j: usize, l: usize| grad[j][l];
    let dxdu = |l: usize, p: &[DVec3; 4]| (0..4).map(|j| p[j] * beta(j, l)).sum::<DVec3>();
    let mut eps = [[0.0; 3]; 3];
    let mut nu = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            eps[i][j] = dxdu(i, &x).dot(dxdu(j, &x)) - if i == j { 1.0 } else { 0.0 };
            nu[i][j] = dxdu(i, &x).dot(dxdu(j, &xdot)) + dxdu(i, &xdot).dot(dxdu(j, &x));
        }
    }
    let tr_e = eps[0][0] + eps[1][1] + eps[2][2];
    let tr_n = nu[0][0] + nu[1][1] + nu[2][2];
    let mut sigma = [[0.0; 3]; 3];
    for k in 0..3 {
        for l in 0..3 {
            let d = if k == l { 1.0 } else { 0.0 };
            sigma[k][l] =
                lambda * tr_e * d + 2.0 * mu * eps[k][l] + phi * tr_n * d + 2.0 * psi * nu[k][l];
        }
    }
    let vol = dm.determinant() / 6.0;
    let mut f = [DVec3::ZERO; 4];
    for (i, fi) in f.iter_mut().enumerate() {
        for j in 0..4 {
            let mut s = 0.0;
            for k in 0..3 {
                for l in 0..3 {
                    s += beta(j, l) * beta(i, k) * sigma[k][l];
                }
            }
            *fi += x[j] * s;
        }
        *fi *= vol / 2.0;
    }
    f
}

#[test]
fn paper_eq6_literal_equals_the_p_equals_fs_form() {
    // Eq. (6) as printed is O'Brien & Hodgins' nodal force without its leading minus sign:
    // the force on node i is −eq.(6). With ε = 2E and σ = 2S it equals −V P ∇N_i.
    let mut rng = Rng(3);
    for case in 0..20 {
        let rest =
            [DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::Z].map(|p| p * 0.01 + rng.vec() * 0.002);
        let rest = if (rest[1] - rest[0]).dot((rest[2] - rest[0]).cross(rest[3] - rest[0])) > 0.0 {
            rest
        } else {
            [rest[0], rest[1], rest[3], rest[2]]
        };
        let x = rest.map(|p| p + rng.vec() * 0.001);
        let xdot = rest.map(|_| rng.vec() * 0.1);
        let (lambda, mu, phi, psi) = (4.0e5, 1.0e5, 20.0, 30.0);
        let lit = paper_eq6(rest, x, xdot, lambda, mu, phi, psi);
        let dm = DMat3::from_cols(rest[1] - rest[0], rest[2] - rest[0], rest[3] - rest[0]);
        let p = StepParams {
            lambda: lambda as f32,
            mu: mu as f32,
            phi: phi as f32,
            psi: psi as f32,
            ..Default::default()
        };
        let u = [0, 1, 2, 3].map(|k| (x[k] - rest[k]).as_vec3());
        let v = xdot.map(|q| q.as_vec3());
        let dmi = Mat3::from_cols_array(&dm.inverse().to_cols_array().map(|c| c as f32));
        let variant = FemVariant {
            model: MaterialModel::Stvk,
            viscous: true,
        };
        let (ours, _) = tet_forces(&p, u, v, dmi, (dm.determinant() / 6.0) as f32, variant);
        let scale = lit.iter().map(|f| f.length()).fold(0.0, f64::max);
        for k in 0..4 {
            let diff = (ours[k].as_dvec3() + lit[k]).length() / scale;
            assert!(
                diff < 1e-4,
                "case {case} corner {k}: ours {:?} vs −eq6 {:?} (rel {diff:.1e})",
                ours[k],
                -lit[k]
            );
        }
    }
}

#[test]
fn patch_test_affine_deformation_gives_uniform_stress_and_no_interior_force() {
    let mesh = jittered_beam([4, 3, 3], 5);
    let model = free_model(&mesh, tissue());
    let a = DMat3::from_cols_array(&[1.02, 0.01, -0.005, 0.003, 0.985, 0.01, -0.01, 0.004, 1.01]);
    let b = DVec3::new(1e-4, -2e-4, 3e-4);
    let u: Vec<f32> = mesh
        .positions
        .iter()
        .flat_map(|x| ((a * *x + b) - *x).to_array().map(|c| c as f32))
        .collect();
    let v = vec![0.0; u.len()];
    // Every tet sees F = A, so the same strain and stress.
    let p = params(&model);
    let mut stresses = Vec::new();
    for e in 0..model.n_tets() {
        let t = model.tets[e];
        let uu = t.map(|i| load3(&u, i as usize));
        let dmi = load_dm_inv(&model.dm_inv, e);
        let h = Mat3::from_cols(uu[1] - uu[0], uu[2] - uu[0], uu[3] - uu[0]) * dmi;
        let s = palpate::material::stvk_second_piola(
            palpate::material::green_strain_from_gradient(h),
            Mat3::ZERO,
            p.lambda,
            p.mu,
            0.0,
            0.0,
        );
        stresses.push(s);
    }
    let s0 = stresses[0];
    let smax = s0
        .to_cols_array()
        .iter()
        .map(|x| x.abs())
        .fold(0.0, f32::max);
    for s in &stresses {
        let d = (*s - s0)
            .to_cols_array()
            .iter()
            .map(|x| x.abs())
            .fold(0.0, f32::max);
        assert!(d / smax < 1e-3, "stress not uniform: {d} vs {smax}");
    }
    let (f, _) = forces_and_energy(&model, &u, &v);
    let boundary = mesh.boundary_vertices();
    let fmax = f.iter().map(|x| x.abs()).fold(0.0, f32::max);
    let mut interior = 0;
    for i in 0..model.n_vertices() {
        if boundary.binary_search(&(i as u32)).is_err() {
            interior += 1;
            let fi = load3(&f, i).length();
            assert!(
                fi / fmax < 1e-3,
                "interior vertex {i} has force {fi} (max {fmax})"
            );
        }
    }
    assert!(interior > 0);
}

#[test]
fn rigid_motion_gives_no_force_and_forces_balance() {
    let mesh = jittered_beam([3, 2, 2], 9);
    let model = free_model(&mesh, tissue());
    let r = DMat3::from_axis_angle(DVec3::new(1.0, 2.0, 0.5).normalize(), 0.6);
    let t = DVec3::new(0.01, -0.02, 0.005);
    let rigid: Vec<f32> = mesh
        .positions
        .iter()
        .flat_map(|x| ((r * *x + t) - *x).to_array().map(|c| c as f32))
        .collect();
    let stretch: Vec<f32> = mesh
        .positions
        .iter()
        .flat_map(|x| [(0.01 * x.x) as f32, 0.0, 0.0])
        .collect();
    let v = vec![0.0; rigid.len()];
    let (f_rigid, e_rigid) = forces_and_energy(&model, &rigid, &v);
    let (f_stretch, e_stretch) = forces_and_energy(&model, &stretch, &v);
    let m_r = f_rigid.iter().map(|x| x.abs()).fold(0.0, f32::max);
    let m_s = f_stretch.iter().map(|x| x.abs()).fold(0.0, f32::max);
    assert!(
        m_r < 1e-3 * m_s,
        "rigid motion force {m_r} vs 1 % stretch {m_s}"
    );
    assert!(
        e_rigid.abs() < 1e-5 * e_stretch,
        "rigid motion energy {e_rigid} vs {e_stretch}"
    );

    // Σ f = 0 and Σ x × f = 0 for any deformation (linear and angular momentum balance).
    let mut rng = Rng(21);
    let u = random_displacement(&model, &mut rng, 5e-4);
    let (f, _) = forces_and_energy(&model, &u, &v);
    let mut sum = glam::DVec3::ZERO;
    let mut moment = glam::DVec3::ZERO;
    let mut abs = 0.0;
    for i in 0..model.n_vertices() {
        let fi = load3(&f, i).as_dvec3();
        let xi = mesh.positions[i] + load3(&u, i).as_dvec3();
        sum += fi;
        moment += xi.cross(fi);
        abs += fi.length();
    }
    assert!(sum.length() < 1e-5 * abs, "Σf = {sum:?} (Σ|f| = {abs})");
    assert!(moment.length() < 1e-5 * abs * 0.03, "Σ x×f = {moment:?}");
}

/// Kinetic + elastic − gravity work Σ m g·u, J.
fn total_energy(model: &Model, st: &mut CpuStepper) -> (f64, f64, f64) {
    let s: State = st.read_state().unwrap();
    let mut ke = 0.0;
    let mut work = 0.0;
    let g = Vec3::from_array(model.gravity).as_dvec3();
    for i in 0..model.n_vertices() {
        let v = load3(&s.velocities, i).as_dvec3();
        ke += 0.5 * model.mass[i] as f64 * v.length_squared();
        work += model.mass[i] as f64 * g.dot(load3(&s.displacements, i).as_dvec3());
    }
    (ke, work, 0.0)
}

fn beam_energy_series(damping: f64, batches: usize, batch: u32) -> Vec<(f64, f64)> {
    let scene = palpate::Scene::load("beam").unwrap();
    let model = std::sync::Arc::new(Model::from_scene(&scene));
    let dt = scene.solver.safety * model.bounds.dt_bound;
    let mut st = CpuStepper::new(model.clone(), model.step_params(dt, damping));
    let mut out = Vec::new();
    for _ in 0..batches {
        let stats = st.run(batch).unwrap();
        let (ke, work, _) = total_energy(&model, &mut st);
        out.push((ke + stats.elastic_energy() - work, stats.elastic_energy()));
    }
    out
}

#[test]
fn undamped_energy_stays_bounded_over_10000_beam_steps() {
    let series = beam_energy_series(0.0, 200, 50);
    let scale = series.iter().map(|(_, el)| *el).fold(0.0, f64::max);
    let drift = series.iter().map(|(e, _)| e.abs()).fold(0.0, f64::max);
    assert!(scale > 0.0);
    assert!(
        drift < 0.02 * scale,
        "total energy strays {drift:.3e} J from 0 (elastic scale {scale:.3e} J)"
    );
}

#[test]
fn damped_energy_does_not_increase() {
    let series = beam_energy_series(30.0, 100, 50);
    let scale = series.iter().map(|(_, el)| *el).fold(0.0, f64::max);
    for w in series.windows(2) {
        assert!(
            w[1].0 <= w[0].0 + 1e-4 * scale,
            "energy rose from {:.6e} to {:.6e}",
            w[0].0,
            w[1].0
        );
    }
    assert!(
        series.last().unwrap().0 < series[5].0,
        "damping removed no energy"
    );
}
