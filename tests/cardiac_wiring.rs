//! The cardiac stages wired into the engine (issue 10): the scene keys of the split laws,
//! Guccione and follower pressures with their one-line errors, the step plan's new stages,
//! GPU against CPU over a trajectory, the CPU path's thread-count independence, the volume
//! of a pressurised nearly incompressible ventricle, and the Land 2015 beam reaching a
//! static state.

mod common;

use common::{gpu, rel_err};
use palpate::bench::land::{monitored_mm, LandCase, Problem};
use palpate::model::Model;
use palpate::plan::{Stage, StepPlan};
use palpate::run::{run_with_state, RunLength, RunOptions};
use palpate::sim::{Advance, Backend, SimOptions, Simulation};
use palpate::Scene;

/// A small Guccione beam (fibre oblique to the axis), nearly incompressible (κ = 100 C),
/// with the nodal average and a ramped follower pressure on z = 0; `material` and `loads`
/// lines are appended to their tables.
fn cardiac_beam(material: &str, loads: &str) -> String {
    format!(
        r#"
name = "cardiac_beam"
[mesh]
generator = "beam"
size = [0.01, 0.002, 0.002]
cells = [8, 2, 2]

[material]
model = "guccione"
guccione_c = 2000.0
guccione_bf = 8.0
guccione_bt = 2.0
guccione_bfs = 4.0
density = 1000.0
{material}

[[fixed]]
plane = {{ normal = [1.0, 0.0, 0.0], offset = 0.0 }}

[loads]
gravity = [0.0, 0.0, -9.81]

[[loads.follower_pressure]]
plane = {{ normal = [0.0, 0.0, 1.0], offset = 0.0 }}
pascals = 40.0
ramp_seconds = 0.0003
{loads}
"#
    )
}

const GOOD_MATERIAL: &str = "bulk_modulus = 2.0e5\nfibre = [1.0, 0.3, 0.0]";

fn load(text: &str) -> palpate::error::Result<Scene> {
    Scene::from_toml(text, "test scene", "test", None)
}

/// The scene must fail with one line naming `key`.
fn refuses(text: &str, key: &str) {
    let err = load(text)
        .expect_err("the scene should be refused")
        .to_string();
    eprintln!("error: {err}");
    assert!(!err.contains('\n'), "not one line: {err}");
    assert!(err.contains(key), "'{err}' does not name {key}");
}

/// A direction given with components whose length over- or underflows (1e200, 1e-200) is
/// still that direction: the fixed plane, the follower pressure's plane and the fibre select
/// and orient exactly as the unit vector does (a normal of 1e200 used to normalise to zero
/// and fix every vertex; one of 1e-200 was refused as zero).
#[test]
fn directions_of_any_finite_magnitude_mean_their_direction() {
    let unit = load(&cardiac_beam(GOOD_MATERIAL, "")).unwrap();
    for scale in ["1e200", "1e-200"] {
        let text = cardiac_beam(
            &format!(
                "bulk_modulus = 2.0e5\nfibre = [{scale}, 0.3{}, 0.0]",
                &scale[1..]
            ),
            "",
        )
        .replace(
            "normal = [1.0, 0.0, 0.0]",
            &format!("normal = [{scale}, 0.0, 0.0]"),
        )
        .replace(
            "normal = [0.0, 0.0, 1.0]",
            &format!("normal = [0.0, 0.0, {scale}]"),
        );
        let scaled = load(&text).unwrap();
        assert_eq!(scaled.fixed, unit.fixed, "fixed vertices at {scale}");
        assert!(unit.fixed.iter().any(|&f| f) && !unit.fixed.iter().all(|&f| f));
        let faces = |s: &Scene| s.follower.as_ref().unwrap().faces.clone();
        assert_eq!(faces(&scaled), faces(&unit), "loaded faces at {scale}");
        let fibre = |s: &Scene| {
            let m = Model::from_scene(s);
            m.fibres[..3].to_vec()
        };
        let (a, b) = (fibre(&scaled), fibre(&unit));
        for k in 0..3 {
            assert!(
                (a[k] - b[k]).abs() < 1e-6,
                "fibre at {scale}: {a:?} against {b:?}"
            );
        }
    }
    refuses(
        &cardiac_beam(GOOD_MATERIAL, "")
            .replace("normal = [1.0, 0.0, 0.0]", "normal = [0.0, 0.0, 0.0]"),
        "fixed",
    );
}

#[test]
fn bad_cardiac_input_is_one_line_naming_the_key() {
    refuses(
        &cardiac_beam("bulk_modulus = -1.0\nfibre = [1.0, 0.0, 0.0]", ""),
        "material.bulk_modulus",
    );
    refuses(
        &cardiac_beam("bulk_modulus = 0.0\nfibre = [1.0, 0.0, 0.0]", ""),
        "material.bulk_modulus",
    );
    refuses(
        &cardiac_beam(GOOD_MATERIAL, "").replace("guccione_c = 2000.0", "guccione_c = 0.0"),
        "material.guccione_c",
    );
    refuses(
        &cardiac_beam(GOOD_MATERIAL, "").replace("guccione_bt = 2.0", "guccione_bt = -2.0"),
        "material.guccione_bt",
    );
    // An exponent whose e^Q leaves single precision at small strains.
    refuses(
        &cardiac_beam(GOOD_MATERIAL, "").replace("guccione_bf = 8.0", "guccione_bf = 1.0e30"),
        "material.guccione_bf: must be at most 1000",
    );
    // All three exponents 0: one key, named whole (the message used to be cut at
    // "material.guccione_bf,").
    refuses(
        &cardiac_beam(GOOD_MATERIAL, "")
            .replace("guccione_bf = 8.0", "guccione_bf = 0.0")
            .replace("guccione_bt = 2.0", "guccione_bt = 0.0")
            .replace("guccione_bfs = 4.0", "guccione_bfs = 0.0"),
        "material.guccione_bf/bt/bfs: are all 0",
    );
    // Fibred law (b_f, b_t, b_fs differ) on a beam mesh, which has no fibres, and no `fibre`.
    refuses(&cardiac_beam("bulk_modulus = 2.0e5", ""), "material.fibre");
    refuses(
        &cardiac_beam("bulk_modulus = 2.0e5\nfibre = [0.0, 0.0, 0.0]", ""),
        "material.fibre",
    );
    // A follower pressure whose plane touches no boundary face.
    refuses(
        &cardiac_beam(GOOD_MATERIAL, "").replace(
            "normal = [0.0, 0.0, 1.0], offset = 0.0 }",
            "normal = [0.0, 0.0, 1.0], offset = 0.5 }",
        ),
        "loads.follower_pressure[0]",
    );
    refuses(
        &cardiac_beam(GOOD_MATERIAL, "").replace("ramp_seconds = 0.0003", "ramp_seconds = 0.0"),
        "loads.follower_pressure[0].ramp_seconds",
    );
    // A tag on a mesh without tags, and neither tag nor plane.
    refuses(
        &cardiac_beam(
            GOOD_MATERIAL,
            "[[loads.follower_pressure]]\ntag = \"endocardium\"\npascals = 1.0",
        ),
        "loads.follower_pressure[1].tag",
    );
    refuses(
        &cardiac_beam(GOOD_MATERIAL, "[[loads.follower_pressure]]\npascals = 1.0"),
        "loads.follower_pressure[1]",
    );
    refuses(
        &cardiac_beam(GOOD_MATERIAL, "").replace("model = \"guccione\"", "model = \"gucione\""),
        "material.model",
    );
    refuses(
        &cardiac_beam(
            "bulk_modulus = 2.0e5\nfibre = [1.0, 0.0, 0.0]\nvolume_term = \"nodal\"",
            "",
        ),
        "material.volume_term",
    );
    // Split-law keys on a (λ, μ) law, and a split law with the particle layer.
    let beam = Scene::builtin_text("beam").unwrap();
    refuses(
        &beam.replace("density = 1000.0", "density = 1000.0\nbulk_modulus = 1e6"),
        "material.bulk_modulus",
    );
    let lv = Scene::builtin_text("lv").unwrap().replace(
        "model = \"stvk\"\nyoungs_modulus = 2.0e4        # Pa",
        "model = \"stvk_split\"\nyoungs_modulus = 2.0e4",
    );
    assert!(load(&lv).is_ok(), "{:?}", load(&lv).err());
    refuses(
        &format!("{lv}\n[particles]\nregion = 0\nspacing = 0.002\nactivation_radius = 0.004\n"),
        "particles",
    );
    // The good scene loads.
    let s = load(&cardiac_beam(GOOD_MATERIAL, "")).unwrap();
    let h = s.hyperelastic.unwrap();
    assert_eq!(h.volume_term, palpate::material::VolumeTerm::NodalAverage);
    // μ = C max(b)/2, λ = κ − 2μ/3: the P-wave modulus is κ + 4μ/3.
    assert_eq!(s.material.mu, 8000.0);
    assert!((s.material.lambda + 2.0 * s.material.mu - (2.0e5 + 4.0 / 3.0 * 8000.0)).abs() < 1e-6);
    assert_eq!(s.follower.as_ref().unwrap().faces.len(), 2 * 8 * 2);
}

#[test]
fn the_plan_has_the_cardiac_stages_only_when_needed() {
    let model = |text: &str| Model::from_scene(&load(text).unwrap());
    let stages = |m: &Model| -> Vec<Stage> {
        StepPlan::for_model(m)
            .stages
            .iter()
            .map(|p| p.stage)
            .collect()
    };
    let beam = Model::from_scene(&Scene::load("beam").unwrap());
    let plain = stages(&beam);
    for s in [
        Stage::FollowerPressure,
        Stage::NodalPressure,
        Stage::FemForcesSplit,
    ] {
        assert!(!plain.contains(&s), "beam plan has {s:?}");
    }
    let full = stages(&model(&cardiac_beam(GOOD_MATERIAL, "")));
    assert_eq!(
        &full[..4],
        &[
            Stage::FollowerPressure,
            Stage::NodalPressure,
            Stage::FemForcesSplit,
            Stage::Gather
        ]
    );
    assert!(!full.contains(&Stage::FemForces));
    let element = stages(&model(&cardiac_beam(
        &format!("{GOOD_MATERIAL}\nvolume_term = \"element\""),
        "",
    )));
    assert_eq!(
        &element[..2],
        &[Stage::FollowerPressure, Stage::FemForcesSplit]
    );
    // A split law with no follower: no follower stage.
    let text = cardiac_beam(GOOD_MATERIAL, "");
    let cut = text.find("[[loads.follower_pressure]]").unwrap();
    let no_follower = stages(&model(&text[..cut]));
    assert_eq!(
        &no_follower[..2],
        &[Stage::NodalPressure, Stage::FemForcesSplit]
    );
}

fn trajectory(
    scene: &Scene,
    backend: Backend,
    threads: Option<usize>,
    steps: u32,
) -> Vec<Vec<f32>> {
    let opts = SimOptions {
        gpu: (backend == Backend::Gpu).then(gpu),
        threads,
        ..Default::default()
    };
    let mut sim = Simulation::new(scene, backend, opts).unwrap();
    let mut out = Vec::new();
    for _ in 0..steps / 50 {
        assert!(matches!(sim.advance(50).unwrap(), Advance::Done(_)));
        out.push(sim.state().unwrap().displacements);
    }
    out
}

#[test]
fn gpu_matches_cpu_over_200_steps_of_a_guccione_nodal_average_follower_scene() {
    // Viscous too, so every pipeline constant of fem_forces_split differs from its default.
    let scene = load(&cardiac_beam(
        &format!("{GOOD_MATERIAL}\nviscosity = [0.0, 0.02]\nvolumetric = \"log_squared\""),
        "",
    ))
    .unwrap();
    let c = trajectory(&scene, Backend::Cpu, None, 200);
    let g = trajectory(&scene, Backend::Gpu, None, 200);
    for (k, (gu, cu)) in g.iter().zip(&c).enumerate() {
        let e = rel_err(gu, cu);
        let umax = cu.iter().map(|x| x.abs()).fold(0.0, f32::max);
        eprintln!(
            "step {}: max |u| {umax:.3e} m, GPU vs CPU {e:.2e}",
            50 * (k + 1)
        );
        assert!(umax > 0.0, "nothing moved");
        assert!(e <= 1e-4, "after {} steps: rel err {e:.2e}", 50 * (k + 1));
    }
}

#[test]
fn cpu_cardiac_stages_are_bit_identical_for_any_thread_count() {
    let scene = load(&cardiac_beam(GOOD_MATERIAL, "")).unwrap();
    let one = trajectory(&scene, Backend::Cpu, Some(1), 200);
    let two = trajectory(&scene, Backend::Cpu, Some(2), 200);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(one.last().unwrap()), bits(two.last().unwrap()));
}

fn until_static(scene: &Scene) -> (palpate::run::RunSummary, palpate::stepper::State) {
    let dir = std::env::temp_dir().join(format!(
        "palpate-cardiac-wiring-{}-{}",
        scene.name,
        std::process::id()
    ));
    let out = run_with_state(
        scene,
        &RunOptions {
            backend: Backend::Cpu,
            length: RunLength::UntilStatic {
                max_steps: 1_000_000,
            },
            out: dir.clone(),
            batch: 500,
            ..Default::default()
        },
    )
    .unwrap();
    let _ = std::fs::remove_dir_all(dir);
    out
}

#[test]
fn a_pressurised_nearly_incompressible_ventricle_keeps_its_wall_volume() {
    // Land problem 2 on the coarsest mesh with κ = 1000 C: 10 kPa inflates the cavity by
    // ~50 % while the wall's volume changes by about p/κ ≈ 1e-3 at most, on average less.
    let case = LandCase {
        problem: Problem::P2,
        level: 1,
        kappa_ratio: 1000.0,
        volume_term: "nodal_average",
    };
    let scene = case.scene().unwrap();
    let (summary, state) = until_static(&scene);
    assert!(summary.status.is_ok(), "{}", summary.status);
    let model = Model::from_scene(&scene);
    let (mut v0, mut v) = (0.0f64, 0.0f64);
    for (e, t) in model.tets.iter().enumerate() {
        let x = t.map(|i| {
            let r = palpate::cpu::load3(&model.rest, i as usize).as_dvec3();
            r + palpate::cpu::load3(&state.displacements, i as usize).as_dvec3()
        });
        v += (x[1] - x[0]).cross(x[2] - x[0]).dot(x[3] - x[0]) / 6.0;
        v0 += model.rest_volume[e] as f64;
    }
    let z = monitored_mm(Problem::P2, &scene.mesh, &state.displacements).unwrap();
    let change = (v - v0) / v0;
    eprintln!(
        "wall volume change {change:.2e}, apex z {z:?} mm, {} steps, {:.1} s",
        summary.steps, summary.wall_seconds
    );
    assert!(
        z[0] < -18.0,
        "the cavity did not inflate: endo apex z {} mm",
        z[0]
    );
    assert!(change.abs() <= 1e-3, "wall volume change {change:.2e}");
}

#[test]
fn land_p1_reaches_a_static_state_converging_toward_the_reference() {
    // Coarse linear tets are stiff in bending even with the nodal average (docs/cardiac.md):
    // the two coarsest meshes give 2.0 and 3.15 mm against the consensus 4.17 mm. Asserted:
    // both reach the static state, the value rises with refinement and stays below the
    // reference plus the spread of the submissions.
    let mut values = Vec::new();
    for level in [1, 2] {
        let case = LandCase {
            problem: Problem::P1,
            level,
            kappa_ratio: 100.0,
            volume_term: "nodal_average",
        };
        let scene = case.scene().unwrap();
        let (summary, state) = until_static(&scene);
        assert!(summary.status.is_ok(), "level {level}: {}", summary.status);
        let z = monitored_mm(Problem::P1, &scene.mesh, &state.displacements).unwrap()[0];
        eprintln!(
            "land_p1 level {level}: z = {z:.3} mm, {} steps, {:.1} s",
            summary.steps, summary.wall_seconds
        );
        values.push(z);
    }
    assert!(values[0] > 1.5 && values[0] < values[1], "{values:?}");
    assert!(values[1] > 2.8 && values[1] < 4.19, "{values:?}");
}

/// A split law's Young's modulus for the overload warning comes from K and μ, 9Kμ/(3K + μ):
/// through λ = K − 2μ/3 it cancelled to 0 at K = 1e-30 Pa, and the warning read "4 Pa is inf
/// x the material's Young's modulus (0 Pa)".
#[test]
fn the_overload_warning_of_a_split_law_takes_its_bulk_modulus() {
    let text = Scene::builtin_text("land_p1")
        .unwrap()
        .replace("bulk_modulus = 2.0e5", "bulk_modulus = 1e-30");
    assert!(text.contains("bulk_modulus = 1e-30"));
    let scene = load(&text).unwrap();
    assert!(
        scene.load_warnings.len() == 1
            && scene.load_warnings[0].contains("Young's modulus (9e-30 Pa)")
            && !scene.load_warnings[0].contains("inf x"),
        "{:?}",
        scene.load_warnings
    );
    // As shipped (K = 2e5 Pa), no warning.
    let shipped = load(Scene::builtin_text("land_p1").unwrap()).unwrap();
    assert!(
        shipped.load_warnings.is_empty(),
        "{:?}",
        shipped.load_warnings
    );
}
