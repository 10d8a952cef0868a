//! The average-nodal-Jacobian stages (`tet_volume_change` → `nodal_pressure` →
//! `fem_forces_split` with `NODAL_PRESSURE`) and the split element forces, on the CPU twins:
//! J_a = 1 at rest and det F under a homogeneous deformation, forces = −∂E/∂x by central
//! differences of the total energy (nodal average and per element, every split law, fibred
//! Guccione with a fibre per tet), the patch test, momentum balance, and what the nodal
//! average costs per step.

#![allow(clippy::needless_range_loop)]

mod common;

use common::{free_model, jittered_beam, tissue, Rng};
use glam::{DMat3, DVec3};
use palpate::cpu::fem_forces_split::{fem_forces_split, SplitVariant};
use palpate::cpu::nodal_pressure::nodal_pressure;
use palpate::cpu::tet_volume_change::tet_volume_change;
use palpate::cpu::{gather, load3};
use palpate::material::{
    GuccioneParams, HyperelasticParams, MaterialConstants, MaterialModel, VolumetricLaw,
};
use palpate::mesh::TetMesh;
use palpate::model::Model;
use std::sync::Arc;

/// One split-law force evaluation on the CPU twins, in stage order.
struct Split {
    model: Arc<Model>,
    constants: MaterialConstants,
    fibres: Vec<f32>,
    variant: SplitVariant,
}

/// Every intermediate buffer of one evaluation.
struct Evaluation {
    forces: Vec<f32>,
    energy: f64,
    vertex_pressure: Vec<f32>,
    tet_energy: Vec<f32>,
}

impl Split {
    fn new(model: Arc<Model>, h: HyperelasticParams, variant: SplitVariant) -> Split {
        let mut rng = Rng(5);
        let fibres = (0..model.n_tets())
            .flat_map(|_| {
                let f = rng.vec().normalize();
                [f.x as f32, f.y as f32, f.z as f32]
            })
            .collect();
        Split {
            model,
            constants: h.constants(),
            fibres,
            variant,
        }
    }

    fn eval(&self, u: &[f32]) -> Evaluation {
        let m = &self.model;
        let params = m.step_params(1e-6, 0.0);
        let (nv, nt) = (m.n_vertices(), m.n_tets());
        let mut vertex_pressure = vec![0.0; nv];
        let mut vertex_energy = vec![0.0; nv];
        if self.variant.nodal_pressure {
            let mut delta = vec![0.0; nt];
            tet_volume_change(&params, u, &m.tets, &m.dm_inv, &m.rest_volume, &mut delta);
            nodal_pressure(
                &params,
                &self.constants,
                &m.incidence_offsets,
                &m.incidence,
                &m.rest_volume,
                &delta,
                &mut vertex_pressure,
                &mut vertex_energy,
                self.variant.volumetric,
            );
        }
        let mut corner = vec![0.0; 12 * nt];
        let mut tet_energy = vec![0.0; nt];
        fem_forces_split(
            &params,
            &self.constants,
            u,
            &vec![0.0; u.len()],
            &m.tets,
            &m.dm_inv,
            &m.rest_volume,
            &self.fibres,
            &vertex_pressure,
            &vertex_energy,
            &mut corner,
            &mut tet_energy,
            self.variant,
        );
        let mut forces = vec![0.0; 3 * nv];
        gather(
            &params,
            &corner,
            &m.incidence_offsets,
            &m.incidence,
            &m.mass,
            &m.external_forces,
            &mut forces,
        );
        Evaluation {
            forces,
            energy: tet_energy.iter().map(|&e| e as f64).sum(),
            vertex_pressure,
            tet_energy,
        }
    }
}

fn material(model: MaterialModel, kappa_over_mu: f64, law: VolumetricLaw) -> HyperelasticParams {
    let mu = tissue().mu;
    let mut h = HyperelasticParams::new(kappa_over_mu * mu);
    h.volumetric = law;
    if model == MaterialModel::Guccione {
        h.guccione = GuccioneParams::new(0.25 * mu, 8.0, 2.0, 4.0);
    }
    h
}

fn affine(model: &Model, a: DMat3) -> Vec<f32> {
    (0..model.n_vertices())
        .flat_map(|i| {
            let x = load3(&model.rest, i).as_dvec3();
            ((a * x) - x).to_array().map(|c| c as f32)
        })
        .collect()
}

#[test]
fn vertex_jacobian_is_one_at_rest_and_det_f_under_a_homogeneous_deformation() {
    let mesh = jittered_beam([4, 3, 3], 3);
    let model = free_model(&mesh, tissue());
    let h = material(
        MaterialModel::StableNeohookeanSplit,
        100.0,
        VolumetricLaw::Quadratic,
    );
    let kappa = h.bulk_modulus;
    let split = Split::new(
        model.clone(),
        h,
        SplitVariant {
            model: MaterialModel::StableNeohookeanSplit,
            viscous: false,
            volumetric: VolumetricLaw::Quadratic,
            nodal_pressure: true,
        },
    );
    let rest = split.eval(&vec![0.0; 3 * model.n_vertices()]);
    assert!(rest.vertex_pressure.iter().all(|&p| p == 0.0));
    assert!(rest.forces.iter().all(|&f| f == 0.0) && rest.energy == 0.0);

    let a = DMat3::from_cols_array(&[1.03, 0.01, -0.02, 0.004, 0.97, 0.01, -0.01, 0.02, 1.015]);
    let out = split.eval(&affine(&model, a));
    let expected = a.determinant() - 1.0;
    let worst = out
        .vertex_pressure
        .iter()
        .map(|&p| (p as f64 / kappa - expected).abs() / expected.abs())
        .fold(0.0, f64::max);
    eprintln!("J_a − 1 vs det F − 1 = {expected:.5}: worst rel err {worst:.2e}");
    assert!(worst < 1e-4, "{worst}");
    // Energy: Σ_e V_e Ψ_iso + Σ_a V_a U(J_a), with V_a = Σ_e V_e/4 and every J_a = det A.
    let u = 0.5 * kappa * expected * expected;
    let hm = glam::Mat3::from_cols_array(&(a - DMat3::IDENTITY).to_cols_array().map(|c| c as f32));
    let (_, psi_iso, _) = palpate::material::isochoric_stress_energy(
        MaterialModel::StableNeohookeanSplit,
        hm,
        tissue().mu as f32,
        &split.constants,
        glam::Vec3::ZERO,
    );
    let total_volume: f64 = model.rest_volume.iter().map(|&v| v as f64).sum();
    let expected_energy = total_volume * (psi_iso as f64 + u);
    let err = (out.energy - expected_energy).abs() / expected_energy;
    eprintln!(
        "energy {:.6e} J vs Σ V Ψ_iso + Σ V_a U(J_a) = {expected_energy:.6e} J (rel {err:.1e})",
        out.energy
    );
    assert!(err < 1e-4, "{err}");
}

fn fd_check(split: &Split, amplitude: f64, seed: u64) -> f64 {
    let m = &split.model;
    let mut rng = Rng(seed);
    let u: Vec<f32> = (0..3 * m.n_vertices())
        .map(|_| (rng.sym() * amplitude) as f32)
        .collect();
    let base = split.eval(&u);
    let fmax = base.forces.iter().map(|x| x.abs()).fold(0.0, f32::max) as f64;
    let delta = (1e-3 * amplitude) as f32;
    let mut worst: f64 = 0.0;
    for k in (0..u.len()).step_by(5) {
        let mut up = u.clone();
        up[k] += delta;
        let mut dn = u.clone();
        dn[k] -= delta;
        let d = up[k] as f64 - dn[k] as f64;
        let fd = -(split.eval(&up).energy - split.eval(&dn).energy) / d;
        worst = worst.max((fd - base.forces[k] as f64).abs() / fmax);
    }
    worst
}

#[test]
fn forces_are_the_negative_gradient_of_the_total_energy() {
    let mesh = jittered_beam([3, 2, 2], 7);
    let model = free_model(&mesh, tissue());
    let h_cell = 0.01;
    for nodal in [true, false] {
        for law in [
            VolumetricLaw::SimoTaylor,
            VolumetricLaw::LogSquared,
            VolumetricLaw::Quadratic,
        ] {
            for m in MaterialModel::SPLIT {
                let split = Split::new(
                    model.clone(),
                    material(m, 50.0, law),
                    SplitVariant {
                        model: m,
                        viscous: false,
                        volumetric: law,
                        nodal_pressure: nodal,
                    },
                );
                let worst = fd_check(&split, 0.05 * h_cell, 11);
                eprintln!(
                    "{:>24} {:<11} {}: worst |f + ∂E/∂x| / max|f| = {worst:.2e}",
                    m.name(),
                    law.name(),
                    if nodal {
                        "nodal average"
                    } else {
                        "per element  "
                    }
                );
                assert!(
                    worst < 2e-3,
                    "{} {} nodal {nodal}: {worst}",
                    m.name(),
                    law.name()
                );
            }
        }
    }
}

#[test]
fn patch_test_and_momentum_balance_with_the_nodal_average() {
    let mesh = jittered_beam([4, 3, 3], 5);
    let model = free_model(&mesh, tissue());
    for m in MaterialModel::SPLIT {
        let h = material(m, 100.0, VolumetricLaw::SimoTaylor);
        // The patch test needs a homogeneous material: one fibre for all tets.
        let mut split = Split::new(
            model.clone(),
            h,
            SplitVariant {
                model: m,
                viscous: false,
                volumetric: VolumetricLaw::SimoTaylor,
                nodal_pressure: true,
            },
        );
        split.fibres = (0..model.n_tets())
            .flat_map(|_| [0.6f32, 0.0, 0.8])
            .collect();
        let a =
            DMat3::from_cols_array(&[1.02, 0.01, -0.005, 0.003, 0.985, 0.01, -0.01, 0.004, 1.01]);
        let out = split.eval(&affine(&model, a));
        let fmax = out.forces.iter().map(|x| x.abs()).fold(0.0, f32::max);
        let boundary = mesh.boundary_vertices();
        let mut interior = 0;
        for i in 0..model.n_vertices() {
            if boundary.binary_search(&(i as u32)).is_err() {
                interior += 1;
                let fi = load3(&out.forces, i).length();
                assert!(
                    fi < 1e-3 * fmax,
                    "{}: interior vertex {i} force {fi} of {fmax}",
                    m.name()
                );
            }
        }
        assert!(interior > 0);
        // Every tet has the same energy density.
        let density: Vec<f64> = out
            .tet_energy
            .iter()
            .zip(&model.rest_volume)
            .map(|(&e, &v)| e as f64 / v as f64)
            .collect();
        let spread = density
            .iter()
            .fold(0.0f64, |a, d| a.max((d - density[0]).abs()));
        assert!(
            spread < 1e-3 * density[0],
            "{}: energy density spread {spread}",
            m.name()
        );

        // Random deformation: Σ f = 0, Σ x × f = 0.
        let mut rng = Rng(21);
        let u: Vec<f32> = (0..3 * model.n_vertices())
            .map(|_| (rng.sym() * 5e-4) as f32)
            .collect();
        let out = split.eval(&u);
        let (mut sum, mut moment, mut abs) = (DVec3::ZERO, DVec3::ZERO, 0.0);
        for i in 0..model.n_vertices() {
            let fi = load3(&out.forces, i).as_dvec3();
            let xi = mesh.positions[i] + load3(&u, i).as_dvec3();
            sum += fi;
            moment += xi.cross(fi);
            abs += fi.length();
        }
        assert!(sum.length() < 1e-5 * abs, "{}: Σf = {sum:?}", m.name());
        assert!(
            moment.length() < 1e-5 * abs * 0.03,
            "{}: Σx×f = {moment:?}",
            m.name()
        );
    }
}

#[test]
fn cost_of_the_nodal_average_per_step_on_the_cpu_twins() {
    // Not asserted (timings are measured, not tested): printed for the report.
    let scene = palpate::Scene::load("lv").expect("lv scene");
    let model = Arc::new(Model::from_scene(&scene));
    let mut rng = Rng(9);
    let u: Vec<f32> = (0..3 * model.n_vertices())
        .map(|_| (rng.sym() * 1e-5) as f32)
        .collect();
    for m in [
        MaterialModel::StableNeohookeanSplit,
        MaterialModel::Guccione,
    ] {
        let mut times = [0.0f64; 2];
        for (k, nodal) in [false, true].into_iter().enumerate() {
            let split = Split::new(
                model.clone(),
                material(m, 500.0, VolumetricLaw::SimoTaylor),
                SplitVariant {
                    model: m,
                    viscous: false,
                    volumetric: VolumetricLaw::SimoTaylor,
                    nodal_pressure: nodal,
                },
            );
            split.eval(&u);
            let reps = 20;
            let t = std::time::Instant::now();
            for _ in 0..reps {
                std::hint::black_box(split.eval(&u));
            }
            times[k] = t.elapsed().as_secs_f64() / reps as f64;
        }
        eprintln!(
            "{} on lv ({} tets, {} vertices), one thread: per element {:.3} ms, nodal average {:.3} ms per force evaluation (×{:.2})",
            m.name(),
            model.n_tets(),
            model.n_vertices(),
            times[0] * 1e3,
            times[1] * 1e3,
            times[1] / times[0]
        );
    }
}

/// Lower-banded symmetric matrix (row i holds columns i − b ..= i) and its Cholesky solve.
struct Banded {
    n: usize,
    b: usize,
    rows: Vec<f64>,
}

impl Banded {
    fn new(n: usize, b: usize) -> Banded {
        Banded {
            n,
            b,
            rows: vec![0.0; n * (b + 1)],
        }
    }

    fn at(&mut self, i: usize, j: usize) -> &mut f64 {
        assert!(
            j <= i && i - j <= self.b,
            "({i}, {j}) outside the band {}",
            self.b
        );
        &mut self.rows[i * (self.b + 1) + (self.b - (i - j))]
    }

    fn get(&self, i: usize, j: usize) -> f64 {
        self.rows[i * (self.b + 1) + (self.b - (i - j))]
    }

    /// Solve K x = f by banded Cholesky (K symmetric positive definite).
    fn solve(mut self, f: &[f64]) -> Vec<f64> {
        let (n, b) = (self.n, self.b);
        for j in 0..n {
            for k in j.saturating_sub(b)..=j {
                let mut s = self.get(j, k);
                for m in j.saturating_sub(b)..k {
                    s -= self.get(j, m) * self.get(k, m);
                }
                if k == j {
                    assert!(s > 0.0, "stiffness not positive definite at {j}");
                    *self.at(j, j) = s.sqrt();
                } else {
                    *self.at(j, k) = s / self.get(k, k);
                }
            }
        }
        let mut y = f.to_vec();
        for i in 0..n {
            for m in i.saturating_sub(b)..i {
                y[i] -= self.get(i, m) * y[m];
            }
            y[i] /= self.get(i, i);
        }
        for i in (0..n).rev() {
            for m in i + 1..(i + b + 1).min(n) {
                y[i] -= self.get(m, i) * y[m];
            }
            y[i] /= self.get(i, i);
        }
        y
    }
}

/// The small-strain stiffness of the split laws (Ψ ≈ μ dev ε:dev ε + κ/2 (tr ε)², the
/// linearisation of every split law at rest with μ_eff = μ), in f64, as triplets
/// (3·vertex + component, …, value) over all vertices: the volume term per element,
/// κ V_e (div)ᵀ(div), or by the nodal average, Σ_a κ V_a g_a g_aᵀ with
/// θ_a = g_a·u = Σ_e V_e div u_e / Σ_e V_e, V_a = Σ_e V_e / 4.
fn split_stiffness(mesh: &TetMesh, mu: f64, kappa: f64, nodal: bool) -> Vec<(usize, usize, f64)> {
    let mut out = Vec::new();
    let grads: Vec<([DVec3; 4], f64)> = (0..mesh.n_tets())
        .map(|e| {
            let x = mesh.corners(e);
            let dm = DMat3::from_cols(x[1] - x[0], x[2] - x[0], x[3] - x[0]);
            let inv = dm.inverse();
            let mut g = [DVec3::ZERO; 4];
            for i in 1..4 {
                g[i] = inv.row(i - 1);
            }
            g[0] = -(g[1] + g[2] + g[3]);
            (g, dm.determinant() / 6.0)
        })
        .collect();
    for (e, tet) in mesh.tets.iter().enumerate() {
        let (g, v) = grads[e];
        for i in 0..4 {
            for j in 0..4 {
                for a in 0..3 {
                    for b in 0..3 {
                        // 2μ dev ε(u) : ε(w) and, per element, κ div u div w.
                        let mut k = mu * g[i][b] * g[j][a] - 2.0 * mu / 3.0 * g[i][a] * g[j][b];
                        if a == b {
                            k += mu * g[i].dot(g[j]);
                        }
                        if !nodal {
                            k += kappa * g[i][a] * g[j][b];
                        }
                        out.push((3 * tet[i] as usize + a, 3 * tet[j] as usize + b, v * k));
                    }
                }
            }
        }
    }
    if nodal {
        let mut around: Vec<Vec<usize>> = vec![Vec::new(); mesh.n_vertices()];
        for (e, tet) in mesh.tets.iter().enumerate() {
            for &i in tet {
                around[i as usize].push(e);
            }
        }
        for tets in &around {
            let w: f64 = tets.iter().map(|&e| grads[e].1).sum();
            let mut g: std::collections::BTreeMap<usize, f64> = Default::default();
            for &e in tets {
                let (gr, v) = grads[e];
                for c in 0..4 {
                    for comp in 0..3 {
                        *g.entry(3 * mesh.tets[e][c] as usize + comp).or_default() +=
                            v * gr[c][comp] / w;
                    }
                }
            }
            for (&i, &gi) in &g {
                for (&j, &gj) in &g {
                    out.push((i, j, kappa * w / 4.0 * gi * gj));
                }
            }
        }
    }
    out
}

/// The split-law material of the cantilever study: tissue μ, κ from ν, quadratic U.
fn cantilever_split(model: Arc<Model>, poisson: f64, nodal: bool) -> Split {
    let mu = tissue().mu;
    let mut h = HyperelasticParams::new(HyperelasticParams::bulk_modulus_from_poisson(mu, poisson));
    h.volumetric = VolumetricLaw::Quadratic;
    Split::new(
        model,
        h,
        SplitVariant {
            model: MaterialModel::StableNeohookeanSplit,
            viscous: false,
            volumetric: VolumetricLaw::Quadratic,
            nodal_pressure: nodal,
        },
    )
}

const BEAM: (f64, f64) = (0.1, 0.01);

fn cantilever_mesh(n: usize) -> (TetMesh, Vec<bool>) {
    let mesh = palpate::mesh::generators::beam([BEAM.0, BEAM.1, BEAM.1], [10 * n, n, n]);
    let fixed = mesh.positions.iter().map(|p| p.x == 0.0).collect();
    (mesh, fixed)
}

#[test]
fn the_small_strain_stiffness_is_the_tangent_of_the_twins_at_rest() {
    // Links the f64 stiffness of the locking study to the kernels: K v against central
    // differences −(f(εv) − f(−εv)) / 2ε of the CPU twins' forces, both volume terms.
    let (mesh, fixed) = cantilever_mesh(2);
    let model = Arc::new(Model::new(&mesh, &fixed, tissue(), [0.0; 3]));
    let mut rng = Rng(17);
    let v: Vec<f64> = (0..3 * mesh.n_vertices()).map(|_| rng.sym()).collect();
    for poisson in [0.3, 0.499] {
        for nodal in [false, true] {
            let split = cantilever_split(model.clone(), poisson, nodal);
            let k = split_stiffness(
                &mesh,
                tissue().mu,
                split.constants.bulk_modulus as f64,
                nodal,
            );
            let mut kv = vec![0.0; v.len()];
            for &(i, j, x) in &k {
                kv[i] += x * v[j];
            }
            let eps = 1e-7;
            let up: Vec<f32> = v.iter().map(|x| (eps * x) as f32).collect();
            let dn: Vec<f32> = up.iter().map(|x| -x).collect();
            let (fp, fm) = (split.eval(&up).forces, split.eval(&dn).forces);
            let scale = kv.iter().map(|x| x.abs()).fold(0.0, f64::max);
            let worst = (0..v.len())
                .map(|i| (kv[i] + (fp[i] as f64 - fm[i] as f64) / (2.0 * eps)).abs() / scale)
                .fold(0.0, f64::max);
            eprintln!("ν = {poisson}, nodal {nodal}: |K v − tangent of the twins| / max|K v| = {worst:.1e}");
            assert!(worst < 1e-4, "{worst}");
        }
    }
}

/// Tip deflection (mean −u_z of the end face) of the cantilever, L = 0.1 m, 10 mm square,
/// clamped at x = 0, unit shear traction −z on x = L (consistent loads A/3 per face
/// corner), small strain; and the Timoshenko deflection P L³/(3 E I) + P L/(k G A),
/// E = 2μ(1 + ν), G = μ, k = 5/6.
fn cantilever_tip_deflection(n: usize, nodal: bool, poisson: f64) -> (f64, f64) {
    let (length, width) = BEAM;
    let (mesh, fixed) = cantilever_mesh(n);
    let mu = tissue().mu;
    let kappa = HyperelasticParams::bulk_modulus_from_poisson(mu, poisson);
    // Free vertices ordered by x slice: the stiffness is banded (the nodal average couples
    // vertices two slices apart, through a shared vertex).
    let dx = length / (10 * n) as f64;
    let slice = |i: usize| (mesh.positions[i].x / dx).round() as usize;
    let mut order: Vec<usize> = (0..mesh.n_vertices()).filter(|&i| !fixed[i]).collect();
    order.sort_by_key(|&i| (slice(i), i));
    let mut dof_of = vec![usize::MAX; mesh.n_vertices()];
    for (k, &i) in order.iter().enumerate() {
        dof_of[i] = k;
    }
    let map = |g: usize| (!fixed[g / 3]).then(|| 3 * dof_of[g / 3] + g % 3);
    let mut k = Banded::new(3 * order.len(), 3 * (n + 1) * (n + 1) * 3);
    for (i, j, x) in split_stiffness(&mesh, mu, kappa, nodal) {
        if let (Some(r), Some(c)) = (map(i), map(j)) {
            if r >= c {
                *k.at(r, c) += x;
            }
        }
    }
    let mut f = vec![0.0; 3 * order.len()];
    let tip: Vec<usize> = (0..mesh.n_vertices())
        .filter(|&i| slice(i) == 10 * n)
        .collect();
    for face in mesh.boundary_faces() {
        if face.iter().all(|&v| slice(v as usize) == 10 * n) {
            let [a, b, c] = face.map(|v| mesh.positions[v as usize]);
            let area = 0.5 * (b - a).cross(c - a).length();
            for &v in &face {
                f[3 * dof_of[v as usize] + 2] -= area / 3.0;
            }
        }
    }
    let u = k.solve(&f);
    let deflection = -tip.iter().map(|&i| u[3 * dof_of[i] + 2]).sum::<f64>() / tip.len() as f64;
    let (area, inertia) = (width * width, width.powi(4) / 12.0);
    let e = 2.0 * mu * (1.0 + poisson);
    let reference = area * length.powi(3) / (3.0 * e * inertia) + length / (5.0 / 6.0 * mu);
    (deflection, reference)
}

#[test]
fn nodal_average_removes_volumetric_locking_in_a_bending_cantilever() {
    for poisson in [0.3, 0.499] {
        let mut series = [Vec::new(), Vec::new()];
        for n in 1..=5 {
            for (k, nodal) in [false, true].into_iter().enumerate() {
                let (d, reference) = cantilever_tip_deflection(n, nodal, poisson);
                series[k].push(d / reference);
            }
            eprintln!(
                "ν = {poisson}, {}×{n}×{n} cells ({} tets): tip deflection / Timoshenko = {:.3} per element, {:.3} nodal average",
                10 * n,
                60 * n * n * n,
                series[0][n - 1],
                series[1][n - 1]
            );
        }
        // Both converge from below (stiff linear tets); the nodal average monotonically.
        assert!(series[1].windows(2).all(|w| w[1] > w[0]));
        assert!(
            series[1][4] > 0.85 && series[1][4] < 1.02,
            "nodal: {:?}",
            series[1]
        );
        if poisson > 0.49 {
            // Per element the volume constraint locks: an order of magnitude too stiff.
            assert!(series[0][4] < 0.15, "per element: {:?}", series[0]);
        } else {
            assert!(
                series[0][4] > 0.8,
                "per element at ν = {poisson}: {:?}",
                series[0]
            );
        }
    }
}
