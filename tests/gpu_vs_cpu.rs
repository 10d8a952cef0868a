//! GPU kernels against their CPU twins: each kernel on random valid inputs (relative error
//! ≤ 1e-5), and whole 500-step trajectories of the built-in scenes (≤ 1e-4 on displacement).
//! Runs on whatever adapter exists — in CI, the software Vulkan adapter (lavapipe).

mod common;

use common::{gpu, jittered_beam, rel_err, tissue, Rng};
use palpate::cpu;
use palpate::cpu::fem_forces::FemVariant;
use palpate::gpu::stepper::Stage;
use palpate::gpu::GpuStepper;
use palpate::material::MaterialModel;
use palpate::model::Model;
use palpate::params::StepParams;
use palpate::sim::{Advance, Backend, SimOptions, Simulation};
use std::sync::Arc;

const KERNEL_TOL: f64 = 1e-5;

fn model_of(variant: FemVariant) -> Arc<Model> {
    let viscous = variant.viscous;
    let mesh = jittered_beam([6, 4, 3], 42);
    let mut material = tissue();
    material.model = variant.model;
    if viscous {
        material.phi = 15.0;
        material.psi = 25.0;
    }
    let fixed: Vec<bool> = mesh.positions.iter().map(|p| p.x == 0.0).collect();
    let mut rng = Rng(77);
    let external: Vec<glam::DVec3> = (0..mesh.n_vertices()).map(|_| rng.vec() * 1e-3).collect();
    Arc::new(Model::with_loads(
        &mesh,
        &fixed,
        material,
        [0.0, -3.0, -9.81],
        &external,
    ))
}

fn random(n: usize, amp: f64, rng: &mut Rng) -> Vec<f32> {
    (0..n).map(|_| (rng.sym() * amp) as f32).collect()
}

fn setup(viscous: bool) -> (Arc<Model>, StepParams, GpuStepper) {
    setup_variant(FemVariant {
        model: MaterialModel::Stvk,
        viscous,
    })
}

fn setup_variant(variant: FemVariant) -> (Arc<Model>, StepParams, GpuStepper) {
    let m = model_of(variant);
    let p = m.step_params(0.5 * m.bounds.dt_bound, 12.0);
    let g = GpuStepper::new(gpu(), &m, p).expect("GPU stepper");
    (m, p, g)
}

#[test]
fn fem_forces_kernel_matches_cpu_twin_for_every_material_variant() {
    for model in MaterialModel::ALL {
        for viscous in [false, true] {
            let variant = FemVariant { model, viscous };
            let (m, p, g) = setup_variant(variant);
            assert_eq!(m.fem_variant(), variant);
            let mut rng = Rng(1 + viscous as u64 + 10 * model as u64);
            let n3 = 3 * m.n_vertices();
            // Large enough to rotate and stretch elements (|H| up to ~0.2).
            let u = random(n3, 4e-4, &mut rng);
            let v = random(n3, 0.05, &mut rng);
            g.write_f32("displacements", &u).unwrap();
            g.write_f32("velocities", &v).unwrap();
            g.run_stage(Stage::FemForces).unwrap();
            let mut corner = vec![0.0; 12 * m.n_tets()];
            let mut energy = vec![0.0; m.n_tets()];
            cpu::fem_forces(
                &p,
                &u,
                &v,
                &m.tets,
                &m.dm_inv,
                &m.rest_volume,
                &mut corner,
                &mut energy,
                variant,
            );
            let gc = g.read_f32("corner_forces").unwrap();
            let ge = g.read_f32("tet_energy").unwrap();
            let (ec, ee) = (
                rel_err(&gc[..corner.len()], &corner),
                rel_err(&ge[..energy.len()], &energy),
            );
            eprintln!("fem_forces {variant:?}: corner forces rel err {ec:.2e}, energy {ee:.2e}");
            assert!(
                ec <= KERNEL_TOL,
                "{variant:?}: corner forces rel err {ec:.2e}"
            );
            assert!(ee <= KERNEL_TOL, "{variant:?}: tet energy rel err {ee:.2e}");
        }
    }
}

#[test]
fn gather_kernel_matches_cpu_twin() {
    let (m, p, g) = setup(false);
    let mut rng = Rng(5);
    let corner = random(12 * m.n_tets(), 1e-2, &mut rng);
    g.write_f32("corner_forces", &corner).unwrap();
    g.run_stage(Stage::Gather).unwrap();
    let mut f = vec![0.0; 3 * m.n_vertices()];
    cpu::gather(
        &p,
        &corner,
        &m.incidence_offsets,
        &m.incidence,
        &m.mass,
        &m.external_forces,
        &mut f,
    );
    let gf = g.read_f32("forces").unwrap();
    let e = rel_err(&gf[..f.len()], &f);
    eprintln!("gather: rel err {e:.2e}");
    assert!(e <= KERNEL_TOL, "gather rel err {e:.2e}");
}

#[test]
fn integrate_kernel_matches_cpu_twin() {
    let (m, p, g) = setup(false);
    let mut rng = Rng(9);
    let n3 = 3 * m.n_vertices();
    let (mut u, mut v, f) = (
        random(n3, 1e-3, &mut rng),
        random(n3, 0.1, &mut rng),
        random(n3, 1e-2, &mut rng),
    );
    g.write_f32("displacements", &u).unwrap();
    g.write_f32("velocities", &v).unwrap();
    g.write_f32("forces", &f).unwrap();
    g.run_stage(Stage::Integrate).unwrap();
    let mut status = vec![u32::MAX; 4];
    cpu::integrate(&p, &f, &m.inv_mass, &mut u, &mut v, &mut status);
    let (eu, ev) = (
        rel_err(&g.read_f32("displacements").unwrap(), &u),
        rel_err(&g.read_f32("velocities").unwrap(), &v),
    );
    eprintln!("integrate: rel err u {eu:.2e}, v {ev:.2e}");
    assert!(
        eu <= KERNEL_TOL && ev <= KERNEL_TOL,
        "integrate rel err u {eu:.2e}, v {ev:.2e}"
    );
    let gs = g.read_f32("status").unwrap()[0].to_bits();
    assert_eq!(gs, status[0], "both report all finite");
    // A non-finite force is flagged at the lowest offending free vertex, on both.
    let free: Vec<usize> = (0..m.n_vertices())
        .filter(|&i| m.inv_mass[i] > 0.0)
        .collect();
    let (a, b) = (free[3], free[10]);
    let mut bad = f.clone();
    bad[3 * b] = f32::NAN;
    bad[3 * a + 2] = f32::INFINITY;
    g.write_f32("forces", &bad).unwrap();
    g.run_stage(Stage::Integrate).unwrap();
    let mut status = vec![u32::MAX; 4];
    cpu::integrate(&p, &bad, &m.inv_mass, &mut u, &mut v, &mut status);
    assert_eq!(status[0], a.min(b) as u32);
    assert_eq!(g.read_f32("status").unwrap()[0].to_bits(), a.min(b) as u32);
}

#[test]
fn reduce_kernel_matches_cpu_twin() {
    let (m, p, g) = setup(false);
    let mut rng = Rng(13);
    let n3 = 3 * m.n_vertices();
    let (u, v, f) = (
        random(n3, 1e-3, &mut rng),
        random(n3, 0.1, &mut rng),
        random(n3, 1e-2, &mut rng),
    );
    let te: Vec<f32> = (0..m.n_tets())
        .map(|_| (rng.next() * 1e-6) as f32)
        .collect();
    for (name, data) in [
        ("displacements", &u),
        ("velocities", &v),
        ("forces", &f),
        ("tet_energy", &te),
    ] {
        g.write_f32(name, data).unwrap();
    }
    g.run_stage(Stage::Reduce).unwrap();
    let mut partials = vec![0.0; 6 * cpu::reduce::n_partials(&p)];
    let mut stats = vec![0.0; palpate::params::stat::LEN];
    cpu::reduce_partial(
        &p,
        &u,
        &v,
        &m.mass,
        &m.inv_mass,
        &f,
        &m.external_forces,
        &te,
        &mut partials,
        &[],
        &[],
        false,
    );
    cpu::reduce_final(&p, &partials, &mut stats);
    let gs = g.read_f32("stats").unwrap();
    for k in 0..6 {
        let e = ((gs[k] - stats[k]) as f64).abs() / (stats[k] as f64).abs().max(f64::MIN_POSITIVE);
        eprintln!("reduce stat {k}: rel err {e:.2e}");
        assert!(
            e <= KERNEL_TOL,
            "stat {k}: gpu {} cpu {} (rel {e:.2e})",
            gs[k],
            stats[k]
        );
        assert!(
            stats[k] > 0.0,
            "stat {k} is zero: the test would not see a mismatch"
        );
    }
}

fn trajectory(scene: &str, backend: Backend, steps: u32) -> Vec<Vec<f32>> {
    let scene = palpate::Scene::load(scene).unwrap();
    let opts = SimOptions {
        gpu: (backend == Backend::Gpu).then(gpu),
        ..Default::default()
    };
    let mut sim = Simulation::new(&scene, backend, opts).unwrap();
    let mut out = Vec::new();
    for _ in 0..steps / 100 {
        assert!(matches!(sim.advance(100).unwrap(), Advance::Done(_)));
        out.push(sim.state().unwrap().displacements);
    }
    out
}

fn compare_trajectories(scene: &str) {
    let c = trajectory(scene, Backend::Cpu, 500);
    let g = trajectory(scene, Backend::Gpu, 500);
    for (k, (gu, cu)) in g.iter().zip(&c).enumerate() {
        let e = rel_err(gu, cu);
        let umax = cu.iter().map(|x| x.abs()).fold(0.0, f32::max);
        eprintln!(
            "{scene}: step {}: max |u| {umax:.3e}, GPU vs CPU rel err {e:.2e}",
            100 * (k + 1)
        );
        assert!(umax > 0.0, "{scene}: nothing moved");
        assert!(
            e <= 1e-4,
            "{scene}: after {} steps displacement rel err {e:.2e}",
            100 * (k + 1)
        );
    }
}

#[test]
fn beam_trajectory_500_steps_gpu_matches_cpu() {
    compare_trajectories("beam");
}

#[test]
fn ed0_trajectory_500_steps_gpu_matches_cpu() {
    compare_trajectories("ed0");
}

#[test]
fn stage_timestamps_are_positive_where_supported() {
    let (_, _, mut g) = setup(false);
    match g.profile_stages(3).unwrap() {
        Some(t) => {
            eprintln!("stage times: {t:?}");
            assert!(
                t.ns(Stage::FemForces) > 0.0
                    && t.ns(Stage::Gather) > 0.0
                    && t.ns(Stage::Integrate) > 0.0
                    && t.ns(Stage::Reduce) > 0.0,
                "{t:?}"
            );
        }
        None => {
            // No timestamp queries on this adapter: the stages must still run and stay finite.
            assert!(!g
                .context()
                .device
                .features()
                .contains(wgpu::Features::TIMESTAMP_QUERY));
            for stage in [
                Stage::FemForces,
                Stage::Gather,
                Stage::Integrate,
                Stage::Reduce,
            ] {
                g.run_stage(stage).unwrap();
            }
            assert!(g.read_f32("stats").unwrap().iter().all(|x| x.is_finite()));
        }
    }
}

#[test]
fn two_dimensional_dispatch_grid_matches_cpu() {
    // Pretend the adapter allows only 2 workgroups per dimension, so every kernel runs on a
    // (2, n) grid and the linear index and partial-block numbering of the 2-D path are used.
    let mut ctx = (*gpu()).clone();
    ctx.limits.max_compute_workgroups_per_dimension = 2;
    let m = model_of(FemVariant {
        model: MaterialModel::Stvk,
        viscous: true,
    });
    let p = m.step_params(0.5 * m.bounds.dt_bound, 12.0);
    let mut g = GpuStepper::new(Arc::new(ctx), &m, p).unwrap();
    let mut c = cpu::CpuStepper::new(m.clone(), p);
    use palpate::stepper::Stepper;
    let (gs, cs) = (g.run(100).unwrap(), c.run(100).unwrap());
    let (gu, cu) = (
        g.read_state().unwrap().displacements,
        c.read_state().unwrap().displacements,
    );
    let e = rel_err(&gu, &cu);
    eprintln!("2-D grid: displacement rel err {e:.2e}");
    assert!(e <= 1e-4, "{e}");
    for k in 0..6 {
        let d = ((gs.stats[k] - cs.stats[k]) as f64).abs() / (cs.stats[k] as f64).abs().max(1e-30);
        assert!(
            d <= 1e-3,
            "stat {k}: gpu {} cpu {}",
            gs.stats[k],
            cs.stats[k]
        );
    }
}
