//! The hybrid model's mechanics: momentum in free flight, rigid motion and the affine patch
//! test across the tet/particle interface, particle-only against FEM-only deflection,
//! hourglass control, and the paper's HM1 with a pressing tool.

mod common;

use glam::{DMat3, DVec3, Vec3};
use palpate::cpu::CpuStepper;
use palpate::model::Model;
use palpate::particles::params::mode;
use palpate::plan::Stage;
use palpate::stepper::{State, Stepper};
use palpate::Scene;
use std::sync::Arc;

/// A 20 x 10 x 10 mm block: its lower half (z < 5 mm) is tet core (region 1), its upper half
/// the particle zone (region 0, 1 mm lattice) with every unpinned particle dynamic.
/// `extra` adds TOML (fixed sets, loads).
fn two_layer_block(extra: &str, particle_keys: &str) -> Scene {
    layered_block([0.02, 0.01, 0.01], [4, 2, 4], extra, particle_keys)
}

/// A block of `size` on `cells` whose lower half is core and upper half particle zone.
fn layered_block(size: [f64; 3], cells: [usize; 3], extra: &str, particle_keys: &str) -> Scene {
    layered_block_spaced(size, cells, 0.001, extra, particle_keys)
}

/// [`layered_block`] with particle spacing `spacing` (m).
fn layered_block_spaced(
    size: [f64; 3],
    cells: [usize; 3],
    spacing: f64,
    extra: &str,
    particle_keys: &str,
) -> Scene {
    let text = format!(
        "[mesh]\ngenerator = \"beam\"\nsize = {size:?}\ncells = {cells:?}\n\n[material]\nyoungs_modulus = 3.0e4\npoisson_ratio = 0.3\ndensity = 1000.0\n\n[particles]\nregion = 0\nspacing = {spacing}\nactivation_radius = 0.003\nactivation = \"all\"\nactivation_interval = 1\n{particle_keys}\n{extra}\n"
    );
    let mut scene = Scene::from_toml(&text, "layered block", "block", None).unwrap();
    for e in 0..scene.mesh.n_tets() {
        let z: f64 = scene.mesh.corners(e).iter().map(|p| p.z).sum::<f64>() / 4.0;
        scene.mesh.regions[e] = if z < 0.5 * size[2] { 1 } else { 0 };
    }
    scene
}

/// The particles of `s` that are dynamic or blending back.
fn awake(s: &CpuStepper) -> usize {
    s.particle_modes()
        .unwrap()
        .iter()
        .filter(|&&q| q & (mode::DYNAMIC | mode::BLENDING) != 0)
        .count()
}

fn stepper(scene: &Scene, dt_factor: f64) -> (Arc<Model>, CpuStepper) {
    let m = Arc::new(Model::from_scene(scene));
    let p = m.step_params(dt_factor * m.bounds.dt_bound, 0.0);
    let s = CpuStepper::new(m.clone(), p);
    (m, s)
}

/// Linear and angular momentum of vertices (current lumped masses) and dynamic particles.
fn momentum(m: &Model, s: &mut CpuStepper) -> (DVec3, DVec3) {
    let st = s.read_state().unwrap();
    let ps = s.particle_state().unwrap();
    let modes = s.particle_modes().unwrap().to_vec();
    let (mass, inv) = s.vertex_masses();
    let (mass, inv) = (mass.to_vec(), inv.to_vec());
    let pd = m.particles.as_ref().unwrap();
    let v3 =
        |a: &[f32], i: usize| DVec3::new(a[3 * i] as f64, a[3 * i + 1] as f64, a[3 * i + 2] as f64);
    let (mut p, mut l) = (DVec3::ZERO, DVec3::ZERO);
    for i in 0..m.n_vertices() {
        if inv[i] < 0.0 {
            continue; // kinematic: no mass of its own
        }
        let x = v3(&m.rest, i) + v3(&st.displacements, i);
        let mv = v3(&st.velocities, i) * mass[i] as f64;
        p += mv;
        l += x.cross(mv);
    }
    for (k, &md) in modes.iter().enumerate().take(pd.len()) {
        if md & mode::DYNAMIC == 0 {
            continue;
        }
        let x = v3(&pd.rest, k) + v3(&ps.displacements, k);
        let mv = v3(&ps.velocities, k) * pd.mass as f64;
        p += mv;
        l += x.cross(mv);
    }
    (p, l)
}

#[test]
fn free_flight_conserves_linear_and_angular_momentum() {
    let scene = two_layer_block("", "");
    let (m, mut s) = stepper(&scene, 0.5);
    // A translation, a spin about the centre and a random deformation rate.
    let mut rng = common::Rng(11);
    let centre = DVec3::new(0.01, 0.005, 0.005);
    let (vt, w) = (DVec3::new(0.3, -0.2, 0.1), DVec3::new(2.0, -1.0, 3.0));
    let mut v = vec![0.0f32; 3 * m.n_vertices()];
    for i in 0..m.n_vertices() {
        let x = DVec3::new(
            m.rest[3 * i] as f64,
            m.rest[3 * i + 1] as f64,
            m.rest[3 * i + 2] as f64,
        );
        let vi = vt + w.cross(x - centre) + rng.vec() * 0.02;
        v[3 * i..3 * i + 3].copy_from_slice(&vi.as_vec3().to_array());
    }
    s.write_state(&State {
        displacements: vec![0.0; 3 * m.n_vertices()],
        velocities: v,
    })
    .unwrap();
    s.run(1).unwrap();
    let (p0, l0) = momentum(&m, &mut s);
    let dynamic = s
        .particle_modes()
        .unwrap()
        .iter()
        .filter(|&&x| x & mode::DYNAMIC != 0)
        .count();
    assert!(dynamic > 500, "{dynamic} dynamic particles");
    for k in 1..=4 {
        s.run(100).unwrap();
        let (p, l) = momentum(&m, &mut s);
        let (ep, el) = (
            (p - p0).length() / p0.length(),
            (l - l0).length() / l0.length(),
        );
        eprintln!(
            "{} steps: linear momentum rel change {ep:.2e}, angular {el:.2e}",
            1 + 100 * k
        );
        assert!(ep <= 1e-6, "linear momentum changed by {ep:.2e}");
        assert!(el <= 1e-6, "angular momentum changed by {el:.2e}");
    }
}

/// The vertices left without mass (all their particles dynamic) move with their particles:
/// in a free spin of the two-layer block (3.7 rad/s about its long axis, 400 steps, vertices
/// and particles started on the rigid motion), each stays where the weighted linear fit of its
/// dynamic particles' positions puts it (`KinematicFit` over positions instead of
/// velocities), within 10 µm. Measured 2026-11-25: 1.3 µm. With the particles' mean velocity
/// (the rule before the fit: the velocity of their weighted centroid) such vertices were 0.15 mm
/// off the particles' rigid motion per 100 steps (`examples/free_spin`).
#[test]
fn massless_vertices_stay_on_their_particles_in_a_free_spin() {
    use palpate::cpu::activate::KinematicFit;
    let scene = two_layer_block("", "");
    let (m, mut s) = stepper(&scene, 0.5);
    let pd = m.particles.as_ref().unwrap();
    s.run(1).unwrap(); // every free particle wakes, at rest
    let centre = DVec3::new(0.01, 0.005, 0.005);
    let w = DVec3::new(3.7, 0.0, 0.0);
    let spin = |rest: &[f32], n: usize| -> Vec<f32> {
        (0..n)
            .flat_map(|i| {
                let x = DVec3::new(
                    rest[3 * i] as f64,
                    rest[3 * i + 1] as f64,
                    rest[3 * i + 2] as f64,
                );
                w.cross(x - centre).as_vec3().to_array()
            })
            .collect()
    };
    s.set_particle_state(&State {
        displacements: vec![0.0; 3 * pd.len()],
        velocities: spin(&pd.rest, pd.len()),
    });
    s.write_state(&State {
        displacements: vec![0.0; 3 * m.n_vertices()],
        velocities: spin(&m.rest, m.n_vertices()),
    })
    .unwrap();
    s.run(400).unwrap();
    let st = s.read_state().unwrap();
    let ps = s.particle_state().unwrap();
    let (_, inv) = s.vertex_masses();
    let (mut massless, mut worst) = (0, 0.0f32);
    for i in (0..m.n_vertices()).filter(|&i| inv[i] < 0.0) {
        massless += 1;
        let xi = Vec3::from_slice(&m.rest[3 * i..3 * i + 3]);
        let mut fit = KinematicFit::default();
        for k in pd.slot_offsets[i]..pd.slot_offsets[i + 1] {
            let slot = pd.slots[k as usize] as usize;
            let q = slot / 4;
            assert!(
                ps.modes[q] & mode::DYNAMIC != 0,
                "vertex {i} hosts an embedded particle"
            );
            let xq = pd.rest_position(q) + Vec3::from_slice(&ps.displacements[3 * q..3 * q + 3]);
            fit.add(
                pd.weights[slot] * pd.mass,
                (pd.rest_position(q) - xi) / pd.settings.spacing as f32,
                xq,
            );
        }
        let off = (xi + Vec3::from_slice(&st.displacements[3 * i..3 * i + 3])
            - fit.velocity_at_vertex())
        .length();
        assert!(off.is_finite(), "vertex {i}");
        worst = worst.max(off);
    }
    eprintln!("{massless} massless vertices, largest distance from their particles' fitted place {worst:.2e} m");
    assert!(massless >= 10, "only {massless} massless vertices");
    assert!(
        worst <= 1e-5,
        "a massless vertex is {worst:.2e} m from its particles' fitted place"
    );
}

/// Forces of one step's force stages after imposing u = (A − I)(X − c) on the vertices
/// (particles take the embedded displacement when they become dynamic): the vertex forces,
/// the particle forces, the boundary vertices and the interior dynamic particles.
type ForcesUnder = (Arc<Model>, Vec<Vec3>, Vec<Vec3>, Vec<bool>, Vec<bool>);

fn forces_under(scene: &Scene, a: DMat3) -> ForcesUnder {
    let (m, mut s) = stepper(scene, 0.5);
    let c = DVec3::new(0.015, 0.015, 0.015);
    let u: Vec<f32> = (0..m.n_vertices())
        .flat_map(|i| {
            let x = DVec3::new(
                m.rest[3 * i] as f64,
                m.rest[3 * i + 1] as f64,
                m.rest[3 * i + 2] as f64,
            );
            ((a - DMat3::IDENTITY) * (x - c)).as_vec3().to_array()
        })
        .collect();
    s.write_state(&State {
        displacements: u,
        velocities: vec![0.0; 3 * m.n_vertices()],
    })
    .unwrap();
    // One core step's force stages. The hosts receive the mean particle force over the
    // particle sub-steps, so the sub-step stages run as often as in a step.
    s.run_stage_pooled(Stage::Activate);
    for k in 0..m.particle_substeps(s.dt() as f64) {
        s.run_stage_pooled(Stage::Follow);
        s.run_stage_pooled(Stage::SphStress);
        s.run_stage_pooled(if k == 0 {
            Stage::SphForces
        } else {
            Stage::SphForcesAccumulate
        });
    }
    s.run_stage_pooled(Stage::FemForces);
    s.run_stage_pooled(Stage::GatherCoupled);
    let vf: Vec<Vec3> = s
        .forces()
        .chunks(3)
        .map(|f| Vec3::new(f[0], f[1], f[2]))
        .collect();
    let pf: Vec<Vec3> = s
        .particle_forces()
        .unwrap()
        .chunks(3)
        .map(|f| Vec3::new(f[0], f[1], f[2]))
        .collect();
    let mut boundary = vec![false; m.n_vertices()];
    for v in scene.mesh.boundary_vertices() {
        boundary[v as usize] = true;
    }
    // Interior particles: every dynamic particle two kernel supports from the body's surface
    // (those nearer have a free surface in their sums), however near the tet core it lies.
    let pd = m.particles.as_ref().unwrap();
    let (lo, hi) = scene.mesh.positions.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(a, b), &x| (a.min(x), b.max(x)),
    );
    let margin = 2.0 * pd.support as f64;
    let modes = s.particle_modes().unwrap();
    let interior_particles: Vec<bool> = (0..pf.len())
        .map(|p| {
            let x = pd.rest_position(p).as_dvec3();
            modes[p] & mode::DYNAMIC != 0
                && (x - lo).min_element() > margin
                && (hi - x).min_element() > margin
        })
        .collect();
    // Vertices that carry mass (kinematic ones, with none, take no force).
    let (_, inv) = s.vertex_masses();
    let live: Vec<bool> = inv.iter().map(|&w| w >= 0.0).collect();
    let boundary_or_dead: Vec<bool> = (0..m.n_vertices())
        .map(|i| boundary[i] || !live[i])
        .collect();
    (m, vf, pf, boundary_or_dead, interior_particles)
}

/// The largest residual under an affine stretch and shear of the whole body, relative to the
/// largest boundary-vertex force: (at interior dynamic particles, at interior vertices,
/// their counts, the largest boundary-vertex force in N).
fn affine_residuals(scene: &Scene) -> (f32, f32, usize, usize, f32) {
    let stretch = DMat3::from_cols(
        DVec3::new(1.01, 0.0, 0.002),
        DVec3::new(0.003, 0.995, 0.0),
        DVec3::new(0.0, 0.004, 1.008),
    );
    let (_, vf, pf, edge, interior) = forces_under(scene, stretch);
    let largest = |f: &[Vec3], keep: &dyn Fn(usize) -> bool| {
        (0..f.len())
            .filter(|&i| keep(i))
            .map(|i| f[i].length())
            .fold(0.0f32, f32::max)
    };
    let scale = largest(&vf, &|i| edge[i]);
    assert!(scale > 0.0);
    (
        largest(&pf, &|p| interior[p]) / scale,
        largest(&vf, &|i| !edge[i]) / scale,
        interior.iter().filter(|&&i| i).count(),
        edge.iter().filter(|&&b| !b).count(),
        scale,
    )
}

/// Rigid motion: no force on any vertex or particle. Affine stretch (patch test), 10 mm tets
/// (four kernel supports): no residual on the dynamic particles away from the body's surface,
/// and 2.4 % of a boundary vertex's force at the interface vertices. That remainder is the
/// energy blend's ghost force: where the stress-carrying particles end (at the zone's edge or
/// inside a tet), their traction is spread over a kernel support and sampled by the lattice,
/// while the tets' partition-of-unity weights are constant per tet, so the two integrate the
/// tets' hat functions differently. It is first order in Δx/h (particle spacing over tet
/// size): at a vertex away from the body's surface it halves with the spacing (checked below;
/// measured 4.9, 3.4, 1.8, 0.94 % at Δx/h = 0.2, 0.1, 0.05, 0.025), while vertices one tet
/// from the free surface stay near 3 % down to Δx/h = 0.075 (docs/hybrid_coupling.md). With
/// 2.5 mm tets and 1 mm spacing (Δx/h = 0.4) it is 37 %, and the dynamic particles that come
/// within a support of the core, whose sums are cut where the lattice ends, keep 6.4 % (27 and
/// 5.6 % while zone tets too thin to hold a lattice point still pinned the particles around
/// them: half the zone was embedded, the dynamic particles farther from the core). An
/// integration correction (Fernández-Méndez, Bonet & Huerta, Comput. Struct. 83, 2005) would
/// remove both; not built. (A band of massless lattice particles continuing into the core
/// removed the 6.4 % but made the core's kink modes soft: the zig-zag test below failed, so it
/// is not shipped.) The bounds guard what is measured.
#[test]
fn rigid_motion_gives_no_force_and_an_affine_stretch_no_interior_residual() {
    // 30 mm cube, 10 mm cells (tets four kernel supports across).
    let coarse = layered_block([0.03, 0.03, 0.03], [3, 3, 3], "", "");
    let (particles, vertices, n_p, n_v, scale) = affine_residuals(&coarse);
    eprintln!(
        "affine stretch, 10 mm tets: largest residual at {n_p} interior particles {particles:.2e}, at {n_v} interior vertices {vertices:.2e} (of the largest boundary-vertex force)"
    );
    assert!(n_p > 500 && n_v > 0);
    assert!(particles <= 1e-4, "interior particles: {particles:.2e}");
    assert!(vertices <= 0.05, "interface vertices: {vertices:.2e}");
    // 2.5 mm cells: the dynamic particles come within a kernel support of the core (without
    // the overlap band they kept 5 % of the scale there).
    let fine = layered_block([0.03, 0.03, 0.03], [12, 12, 12], "", "");
    let (particles, vertices, n_p, n_v, _) = affine_residuals(&fine);
    eprintln!(
        "affine stretch, 2.5 mm tets: largest residual at {n_p} interior particles {particles:.2e}, at {n_v} interior vertices {vertices:.2e}"
    );
    assert!(n_p > 500 && n_v > 0);
    assert!(particles <= 0.1, "interior particles: {particles:.2e}");
    assert!(vertices <= 0.45, "interface vertices: {vertices:.2e}");
    // First order in Δx/h: a 20 mm cube of 10 mm cells, its one interior vertex on the
    // planar interface, at 1 mm and 0.5 mm spacing (measured 3.4 % and 1.8 %).
    let at = |spacing| {
        let b = layered_block_spaced([0.02, 0.02, 0.02], [2, 2, 2], spacing, "", "");
        let (particles, vertices, _, n_v, _) = affine_residuals(&b);
        assert!(
            n_v == 1 && particles <= 1e-4,
            "{n_v} vertices, particles {particles:.2e}"
        );
        vertices
    };
    let (coarse_dx, fine_dx) = (at(0.001), at(0.0005));
    eprintln!(
        "planar interface, 10 mm tets: residual at the interface vertex {coarse_dx:.2e} (1 mm spacing), {fine_dx:.2e} (0.5 mm)"
    );
    assert!(
        coarse_dx <= 0.04 && fine_dx <= 0.025,
        "{coarse_dx:.2e}, {fine_dx:.2e}"
    );
    assert!(
        fine_dx <= 0.65 * coarse_dx,
        "halving the spacing took the interface residual from {coarse_dx:.2e} to {fine_dx:.2e}"
    );
    // A rigid rotation of 30 degrees: no force anywhere.
    let rot = DMat3::from_axis_angle(
        DVec3::new(1.0, 2.0, 3.0).normalize(),
        std::f64::consts::FRAC_PI_6,
    );
    let (_, vf, pf, _, _) = forces_under(&coarse, rot);
    let worst = vf
        .iter()
        .chain(&pf)
        .map(|f| f.length())
        .fold(0.0f32, f32::max);
    eprintln!(
        "rigid rotation: largest force {worst:.3e} N ({:.2e} of the stretch's scale)",
        worst / scale
    );
    assert!(
        worst <= 1e-4 * scale,
        "rigid rotation gives {:.2e} of the scale",
        worst / scale
    );
}

/// A 30 x 10 x 10 mm bar clamped at x = 0, stretched by its own weight along +x (g = 9.81
/// m/s² along the bar): u_x(x) = ρ g (L x − x²/2)/E for a slender bar (ν only thins it).
/// `particles`: the whole bar is particle zone with every unpinned particle dynamic.
fn hanging_bar(particles: Option<&str>) -> Scene {
    let mut text = String::from(
        "[mesh]\ngenerator = \"beam\"\nsize = [0.03, 0.01, 0.01]\ncells = [6, 2, 2]\n\n[material]\nyoungs_modulus = 3.0e4\npoisson_ratio = 0.3\ndensity = 1000.0\n\n[[fixed]]\nplane = { normal = [1.0, 0.0, 0.0], offset = 0.0 }\n\n[loads]\ngravity = [9.81, 0.0, 0.0]\n\n[solver]\nstatic_tolerance = 1e-4\n",
    );
    if let Some(model) = particles {
        text.push_str(&format!(
            "\n[particles]\nregion = 0\nspacing = 0.001\nactivation_radius = 0.003\nactivation = \"all\"\nmodel = \"{model}\"\n"
        ));
    }
    Scene::from_toml(&text, "hanging bar", "bar", None).unwrap()
}

/// Mean u_x of the particles (or, FEM-only, of the FEM field at the particles' places) in the
/// last 1 mm of the bar, after relaxing to a static state.
fn tip_displacement(scene: &Scene, sample: &Scene) -> (f64, u64) {
    try_tip_displacement(scene, sample).unwrap_or_else(|status| panic!("{status}"))
}

/// [`tip_displacement`], or the run's status when it did not reach a static state.
fn try_tip_displacement(scene: &Scene, sample: &Scene) -> Result<(f64, u64), String> {
    let out = std::env::temp_dir().join(format!(
        "palpate-bar-{}-{}",
        std::process::id(),
        scene.particles.as_ref().map_or("fem", |p| p.model.name())
    ));
    let s = palpate::run::run(
        scene,
        &palpate::run::RunOptions {
            backend: palpate::sim::Backend::Cpu,
            length: palpate::run::RunLength::UntilStatic { max_steps: 400_000 },
            out: out.clone(),
            ..Default::default()
        },
    )
    .unwrap();
    if s.status != "ok" {
        return Err(s.status.to_string());
    }
    let m = Model::from_scene(sample);
    let pd = m.particles.as_ref().unwrap();
    let tip: Vec<usize> = (0..pd.len()).filter(|&p| pd.rest[3 * p] > 0.029).collect();
    let text = std::fs::read_to_string(out.join(if scene.particles.is_some() {
        "particles_final.vtu"
    } else {
        "final.vtu"
    }))
    .unwrap();
    let u = common::vtu_point_vectors(&text, "displacement");
    let ux = if scene.particles.is_some() {
        tip.iter().map(|&p| u[3 * p] as f64).sum::<f64>() / tip.len() as f64
    } else {
        // The FEM field at the particles' places: Σ w u over their host tets.
        tip.iter()
            .map(|&p| {
                let t = sample.mesh.tets[pd.host[p] as usize];
                (0..4)
                    .map(|c| pd.weights[4 * p + c] as f64 * u[3 * t[c] as usize] as f64)
                    .sum::<f64>()
            })
            .sum::<f64>()
            / tip.len() as f64
    };
    Ok((ux, s.steps))
}

#[test]
fn particle_only_and_fem_only_bars_agree_on_their_static_stretch() {
    let (l, e, rho, g) = (0.03, 3.0e4, 1000.0, 9.81);
    let x = 0.0295;
    let exact = rho * g * (l * x - 0.5 * x * x) / e;
    let sample = hanging_bar(Some("tlsph"));
    let (fem, fem_steps) = tip_displacement(&hanging_bar(None), &sample);
    let (tlsph, tlsph_steps) = tip_displacement(&sample, &sample);
    let paper = match try_tip_displacement(&hanging_bar(Some("paper")), &sample) {
        Ok((u, _)) => format!("{u:.4e} m ({:+.1} % from FEM)", 100.0 * (u - fem) / fem),
        Err(status) => format!("no static state: {status}"),
    };
    eprintln!(
        "tip u_x: 1-D bar theory {exact:.4e} m; FEM-only {fem:.4e} m ({fem_steps} steps); tlsph particles {tlsph:.4e} m ({tlsph_steps} steps, {:+.1} % from FEM); paper model {paper}",
        100.0 * (tlsph - fem) / fem
    );
    assert!(
        fem > 0.8 * exact && fem < 1.2 * exact,
        "FEM {fem} vs theory {exact}"
    );
    assert!(
        (tlsph - fem).abs() <= 0.1 * fem,
        "tlsph {tlsph:.4e} vs FEM {fem:.4e}: {:+.1} %",
        100.0 * (tlsph - fem) / fem
    );
}

/// Particle displacements as the outputs place them (embedded ones on their host).
fn placed(m: &Model, s: &mut CpuStepper) -> (Vec<f32>, Vec<u32>) {
    let nodes = s.read_state().unwrap();
    let snap = s.particle_state().unwrap();
    (
        palpate::output::particles::particle_displacements(m, &nodes, &snap),
        snap.modes,
    )
}

#[test]
fn hm1_activates_a_few_hundred_particles_under_the_tool_and_releases_them_without_pops() {
    let scene = Scene::load("hm1").unwrap();
    let spacing = scene.particles.as_ref().unwrap().spacing as f32;
    let m = Arc::new(Model::from_scene(&scene));
    let n = m.particles.as_ref().unwrap().len();
    assert!(
        (27_000..29_000).contains(&n),
        "{n} particles (the paper has 27,988)"
    );
    let dt = scene.solver.dt.unwrap();
    let mut s = CpuStepper::new(m.clone(), m.step_params(dt, scene.solver.damping));
    let tool = scene.tool.clone().unwrap();
    let interval = scene.particles.as_ref().unwrap().activation_interval;
    let (mut max_dynamic, mut max_force, mut switched) = (0u32, 0.0f64, 0usize);
    let mut worst_jump = 0.0f32;
    let mut t = 0.0;
    // 10 time units (1430 steps at the paper's dt), batches of one activation interval.
    while t < 10.0 {
        let r = common::batch_along_path(&mut s, &tool, t, interval, dt);
        assert!(
            r.stats.non_finite_vertex.is_none(),
            "hm1 diverged at t = {t}"
        );
        t += interval as f64 * dt;
        max_dynamic = max_dynamic.max(r.particles.unwrap().dynamic);
        max_force = max_force.max(r.tool.unwrap().force.length());
        // The switch itself: an activation update with no time step in between.
        let (before, modes_before) = placed(&m, &mut s);
        s.run_stage_pooled(Stage::Activate);
        let (after, modes_after) = placed(&m, &mut s);
        for k in 0..modes_before.len() {
            if (modes_before[k] ^ modes_after[k]) & mode::DYNAMIC != 0 {
                switched += 1;
                let d = Vec3::from_slice(&after[3 * k..]) - Vec3::from_slice(&before[3 * k..]);
                worst_jump = worst_jump.max(d.length());
            }
        }
    }
    let left = awake(&s);
    eprintln!(
        "hm1: {n} particles; at most {max_dynamic} dynamic; largest tool force {max_force:.3}; {switched} switches, largest jump at a switch {worst_jump:.2e} ({:.1e} of the spacing); after the tool left {left} still dynamic or blending",
        worst_jump / spacing
    );
    assert!(
        (50..=600).contains(&max_dynamic),
        "{max_dynamic} dynamic particles"
    );
    assert!(max_force > 0.0, "the tool never touched");
    assert!(switched > 100, "only {switched} switches");
    assert_eq!(left, 0, "particles still dynamic after the tool left");
    assert!(
        worst_jump <= 1e-3 * spacing,
        "a particle jumped {worst_jump} (> 0.1 % of the spacing) when it switched"
    );
}

/// A checkpoint copies only the particles written since the one before (`cpu/touched.rs`:
/// the force set between activations, what each activation visits). On hm1's press, hold and
/// release and on lv_touch pressed, held and withdrawn, in batches of uneven length (so a batch
/// holds none, one or two activations) and with every fourth batch restored and run again,
/// each checkpoint equals the whole particle state and activation products, and each restore
/// brings back the whole particle state of its checkpoint, bit for bit.
#[test]
fn checkpoints_of_the_touched_particles_equal_the_whole_state() {
    // hm1 along its path; lv_touch pressed along its path for 1 s, then withdrawn over 0.5 s
    // (its path ends held) and left to release its particles.
    let hm1 = |tool: &palpate::scene::Tool, t: f64| tool.position_at(t);
    let lv_touch = |tool: &palpate::scene::Tool, t: f64| {
        // Its home is within the activation radius of the surface: withdraw 10 mm past it.
        let away = tool.position_at(0.0) + DVec3::new(0.01, 0.0, 0.0);
        if t < 1.0 {
            tool.position_at(t)
        } else {
            tool.position_at(1.0).lerp(away, ((t - 1.0) / 0.5).min(1.0))
        }
    };
    type ToolAt<'a> = &'a dyn Fn(&palpate::scene::Tool, f64) -> DVec3;
    let cases: [(&str, f64, ToolAt); 2] = [("hm1", 8.0, &hm1), ("lv_touch", 2.0, &lv_touch)];
    for (name, end, at) in cases {
        let scene = Scene::load(name).unwrap();
        // The step and damping a run of the scene takes (automatic dt, mass scaling).
        let sim = palpate::sim::Simulation::new(
            &scene,
            palpate::sim::Backend::Cpu,
            palpate::sim::SimOptions::default(),
        )
        .unwrap();
        let (m, dt) = (sim.model.clone(), sim.dt);
        let mut s = CpuStepper::new(m.clone(), m.step_params(dt, sim.damping));
        let tool = scene.tool.clone().unwrap();
        let bits = |a: &[f32]| a.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
        let whole = |s: &CpuStepper| {
            let p = s.particle_state().unwrap();
            (
                bits(&p.displacements),
                bits(&p.velocities),
                bits(&p.offsets),
                bits(&p.timers),
                p.modes,
            )
        };
        // Activations every 10 steps: some batches hold one or two, some none.
        let lengths = [4u32, 3, 13, 2, 9, 5, 17];
        let (mut t, mut batch, mut restores, mut most_dynamic) = (0.0, 0usize, 0, 0);
        while t < end {
            s.checkpoint().unwrap();
            assert!(
                s.checkpoint_matches_state(),
                "{name}: the checkpoint at t = {t:.4} (batch {batch}) is not the whole state"
            );
            let saved = whole(&s);
            let n = lengths[batch % lengths.len()];
            let input =
                palpate::stepper::BatchInput::moving(at(&tool, t), at(&tool, t + n as f64 * dt));
            s.submit(n, &input).unwrap();
            let r = s.wait().unwrap();
            assert!(
                r.stats.non_finite_vertex.is_none(),
                "{name} diverged at t = {t}"
            );
            most_dynamic = most_dynamic.max(r.particles.unwrap().dynamic);
            if batch % 4 == 3 {
                s.restore().unwrap();
                assert!(
                    whole(&s) == saved,
                    "{name}: the restore at t = {t:.4} (batch {batch}) did not bring back the particle state"
                );
                assert!(s.checkpoint_matches_state());
                s.submit(n, &input).unwrap();
                s.wait().unwrap();
                restores += 1;
            }
            t += n as f64 * dt;
            batch += 1;
        }
        let c = s.activation_counts().unwrap();
        let left = awake(&s);
        eprintln!("{name}: {batch} batches, {restores} restores, at most {most_dynamic} dynamic, {left} left at the end; activations {c:?}");
        assert!(
            most_dynamic > 50,
            "{name}: {most_dynamic} dynamic particles: the tool never pressed"
        );
        assert_eq!(left, 0, "{name}: the withdrawn tool left particles awake");
        assert!(
            c.region > 10 && c.unchanged > 10 && c.full > restores,
            "{name}: activations {c:?}: the press should change sets, hold them unchanged and restart full after each restore"
        );
    }
}

/// Released particles fade back onto their hosts step by step: on hm1, as the tool withdraws,
/// particles leave the press up to 1.5 spacings off their hosts' field and blend back over
/// `blend`. Where the SPH sees them (in the force set), the offset's change from one step to
/// the next stays below a tenth of a spacing (measured 0.05 of it). The fade used to advance
/// only at an activation (every 10 steps on hm1): 0.54 spacings at once.
#[test]
fn released_particles_fade_back_onto_their_hosts_without_a_jump() {
    let scene = Scene::load("hm1").unwrap();
    let spacing = scene.particles.as_ref().unwrap().spacing as f32;
    let m = Arc::new(Model::from_scene(&scene));
    let dt = scene.solver.dt.unwrap();
    let mut s = CpuStepper::new(m.clone(), m.step_params(dt, scene.solver.damping));
    let tool = scene.tool.clone().unwrap();
    let interval = scene.particles.as_ref().unwrap().activation_interval;
    let st = palpate::cpu::activate::ParticleStatic::of(&m).unwrap();
    // Each particle's place off its host's field (the blend offset as the outputs see it).
    let off_host = |s: &mut CpuStepper| {
        let nodes = s.read_state().unwrap();
        let (placed, modes) = placed(&m, s);
        let off: Vec<Vec3> = (0..modes.len())
            .map(|k| Vec3::from_slice(&placed[3 * k..]) - st.embed(&nodes.displacements, k))
            .collect();
        (off, modes)
    };
    let mut t = 0.0;
    let mut steps = 0u32;
    let (mut worst_step, mut largest, mut watched) = (0.0f32, 0.0f32, 0usize);
    let mut last = off_host(&mut s);
    while t < 8.0 {
        // Whole intervals until the tool withdraws (t = 6), then single steps.
        let n = if t < 6.0 { interval } else { 1 };
        let (a, b) = (tool.position_at(t), tool.position_at(t + n as f64 * dt));
        s.submit(n, &palpate::stepper::BatchInput::moving(a, b))
            .unwrap();
        assert!(s.wait().unwrap().stats.non_finite_vertex.is_none());
        t += n as f64 * dt;
        steps += n;
        let now = off_host(&mut s);
        if n == 1 {
            let seen = mode::BLENDING | mode::IN_F;
            for k in 0..now.1.len() {
                if now.1[k] & seen == seen && last.1[k] & seen == seen {
                    watched += 1;
                    largest = largest.max(now.0[k].length());
                    worst_step = worst_step.max((now.0[k] - last.0[k]).length());
                }
            }
        }
        last = now;
    }
    eprintln!(
        "hm1 release ({steps} steps): largest blend offset {:.2} spacings, largest change in one step {:.3} spacings ({watched} particle-steps watched)",
        largest / spacing,
        worst_step / spacing
    );
    assert!(
        watched > 100 && largest > 0.5 * spacing,
        "too little blending to test"
    );
    assert!(
        worst_step <= 0.1 * spacing,
        "a blending particle moved {:.2} spacings off its host in one step",
        worst_step / spacing
    );
}

/// The CPU stepper's activation visits only the region it can change (`cpu/active_region.rs`):
/// live particles and those of tets near the tool, tets that host stress-set particles and
/// vertices that host force-set or released particles, now or at the last activation; and the
/// steps between activations weigh only the tets whose weight is not 1 and gather the particle
/// forces through the coupled vertices' slot lists. On hm1 through the tool's press, hold and
/// withdrawal (activation, dwell, blending back, all released), with a checkpoint restored on
/// the way between two activations, it must leave every vertex and particle, tet weight,
/// coupling flag and contact weight bit-equal to the reference path (everything over
/// everything) after every batch.
#[test]
fn the_cpu_activation_over_its_region_equals_the_activation_over_everything() {
    let scene = Scene::load("hm1").unwrap();
    let m = Arc::new(Model::from_scene(&scene));
    let dt = scene.solver.dt.unwrap();
    let params = m.step_params(dt, scene.solver.damping);
    let mut region = CpuStepper::with_threads(m.clone(), params, 2).unwrap();
    let mut everything = CpuStepper::with_threads(m.clone(), params, 2).unwrap();
    everything.set_full_activation(true);
    let tool = scene.tool.clone().unwrap();
    let interval = scene.particles.as_ref().unwrap().activation_interval;
    let (mut t, mut batch) = (0.0, 0u32);
    let (mut dynamic_max, mut released) = (0u32, 0usize);
    // (checkpoint, restore) batches: while pressing (t ≈ 2.1–2.3) and while releasing (6.4–6.65).
    let mut replays = [(30u32, 33u32), (92, 95)].into_iter().peekable();
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
    // Press (t 1–3), hold, withdraw (6–7) and let the particles settle and blend back.
    while t < 7.8 {
        let input = palpate::stepper::BatchInput {
            tool: Some((
                tool.position_at(t),
                tool.position_at(t + interval as f64 * dt),
            )),
            tool_slice: None,
        };
        let mut counts = Vec::new();
        for s in [&mut region, &mut everything] {
            s.submit(interval, &input).unwrap();
            let r = s.wait().unwrap().particles.unwrap();
            counts.push((r.dynamic, r.stress, r.force));
        }
        assert_eq!(counts[0], counts[1], "batch {batch}: particle counts");
        batch += 1;
        t += interval as f64 * dt;
        let (a, b) = (
            region.particle_state().unwrap(),
            everything.particle_state().unwrap(),
        );
        let (sa, sb) = (
            region.read_state().unwrap(),
            everything.read_state().unwrap(),
        );
        let (ma, mb) = (region.vertex_masses(), everything.vertex_masses());
        let same = a.modes == b.modes
            && bits(&a.displacements) == bits(&b.displacements)
            && bits(&a.velocities) == bits(&b.velocities)
            && bits(&a.timers) == bits(&b.timers)
            && bits(&a.offsets) == bits(&b.offsets)
            && bits(&sa.displacements) == bits(&sb.displacements)
            && bits(&sa.velocities) == bits(&sb.velocities)
            && bits(ma.0) == bits(mb.0)
            && bits(ma.1) == bits(mb.1);
        let (oa, ob) = (
            region.activation_outputs().unwrap(),
            everything.activation_outputs().unwrap(),
        );
        let same = same && bits(oa.0) == bits(ob.0) && oa.1 == ob.1 && bits(oa.2) == bits(ob.2);
        assert!(
            same,
            "batch {batch} (t = {t:.3}): the region's activation differs from the full one"
        );
        dynamic_max =
            dynamic_max.max(a.modes.iter().filter(|&&x| x & mode::DYNAMIC != 0).count() as u32);
        released += a.modes.iter().filter(|&&x| x & mode::RELEASED != 0).count();
        let Some(&(saved, replay)) = replays.peek() else {
            continue;
        };
        if batch == saved {
            for s in [&mut region, &mut everything] {
                s.checkpoint().unwrap();
            }
        }
        // Both run a few more steps and go back to their checkpoint three batches earlier and
        // replay: the activations then fall 3 steps later into each batch, so the first steps
        // after the restore run on the restored modes with what the last activation left (the
        // coupled vertices' slot lists must not be used then).
        if batch == replay {
            replays.next();
            let input = palpate::stepper::BatchInput {
                tool: Some((tool.position_at(t), tool.position_at(t + 3.0 * dt))),
                tool_slice: None,
            };
            for s in [&mut region, &mut everything] {
                s.submit(3, &input).unwrap();
                s.wait().unwrap();
                s.restore().unwrap();
            }
            batch = saved;
            t = saved as f64 * interval as f64 * dt;
        }
    }
    let left = awake(&region);
    let counts = region.activation_counts().unwrap();
    let reference = everything.activation_counts().unwrap();
    eprintln!("region vs full activation: equal over {batch} batches; up to {dynamic_max} dynamic, {released} releases, {left} left active; activations {counts:?} (reference {reference:?})");
    // Both kinds of region activation ran and were compared: with a set changed, and with
    // none (only the mode machine and the massless vertices' velocities).
    assert!(counts.region > 10 && counts.unchanged > 10, "{counts:?}");
    assert_eq!(reference.region + reference.unchanged, 0, "{reference:?}");
    assert!(dynamic_max > 100, "{dynamic_max} dynamic");
    assert!(released > 100, "{released} releases");
    assert_eq!(left, 0);
}

/// An activation that changes no set still moves the massless vertices: with every particle
/// of a layered block's zone woken by the tool (activation radius 20 mm), the zone's own
/// vertices have no mass left and take their dynamic particles' mean velocity at every
/// activation. Through a press and hold, the region path (whose activations after the first
/// change nothing) must leave every vertex and particle bit-equal to the reference path.
#[test]
fn an_unchanged_activation_still_moves_the_massless_vertices() {
    let text = "[mesh]\ngenerator = \"beam\"\nsize = [0.02, 0.01, 0.01]\ncells = [4, 2, 4]\n\n[material]\nyoungs_modulus = 3.0e4\npoisson_ratio = 0.3\ndensity = 1000.0\n\n[particles]\nregion = 0\nspacing = 0.001\nactivation_radius = 0.02\nactivation_interval = 5\n\n[[fixed]]\nplane = { normal = [0.0, 0.0, 1.0], offset = 0.0 }\n\n[tool]\nradius = 0.003\nstiffness = 1.0e8\npath = [[0.0, 0.01, 0.005, 0.0135], [0.02, 0.01, 0.005, 0.012], [0.05, 0.01, 0.005, 0.012]]\n";
    let mut scene = Scene::from_toml(text, "layered block", "block", None).unwrap();
    for e in 0..scene.mesh.n_tets() {
        let z: f64 = scene.mesh.corners(e).iter().map(|p| p.z).sum::<f64>() / 4.0;
        scene.mesh.regions[e] = if z < 0.005 { 1 } else { 0 };
    }
    let m = Arc::new(Model::from_scene(&scene));
    let dt = 0.5 * m.bounds.dt_bound;
    let params = m.step_params(dt, 0.0);
    let mut region = CpuStepper::with_threads(m.clone(), params, 2).unwrap();
    let mut everything = CpuStepper::with_threads(m.clone(), params, 2).unwrap();
    everything.set_full_activation(true);
    let tool = scene.tool.clone().unwrap();
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
    let (batch, mut t, mut massless) = (20u32, 0.0, 0usize);
    while t < 0.04 {
        let (a, b) = (tool.position_at(t), tool.position_at(t + batch as f64 * dt));
        for s in [&mut region, &mut everything] {
            s.submit(batch, &palpate::stepper::BatchInput::moving(a, b))
                .unwrap();
            let r = s.wait().unwrap();
            assert!(r.stats.non_finite_vertex.is_none(), "diverged at t = {t}");
        }
        t += batch as f64 * dt;
        let (sa, sb) = (
            region.read_state().unwrap(),
            everything.read_state().unwrap(),
        );
        let (pa, pb) = (
            region.particle_state().unwrap(),
            everything.particle_state().unwrap(),
        );
        let (ma, mb) = (region.vertex_masses(), everything.vertex_masses());
        let (oa, ob) = (
            region.activation_outputs().unwrap(),
            everything.activation_outputs().unwrap(),
        );
        assert!(
            bits(&sa.velocities) == bits(&sb.velocities)
                && bits(&sa.displacements) == bits(&sb.displacements)
                && bits(&pa.velocities) == bits(&pb.velocities)
                && bits(&pa.displacements) == bits(&pb.displacements)
                && bits(&pa.timers) == bits(&pb.timers)
                && pa.modes == pb.modes
                && bits(ma.0) == bits(mb.0)
                && bits(ma.1) == bits(mb.1)
                && bits(oa.0) == bits(ob.0)
                && oa.1 == ob.1
                && bits(oa.2) == bits(ob.2),
            "t = {t:.4}: the region's activation differs from the full one"
        );
        massless = region
            .vertex_masses()
            .1
            .iter()
            .filter(|&&w| w < 0.0)
            .count();
    }
    let counts = region.activation_counts().unwrap();
    let modes = region.particle_modes().unwrap();
    let count = |bit: u32| modes.iter().filter(|&&x| x & bit != 0).count();
    let (dynamic, pinned) = (count(mode::DYNAMIC), count(mode::PINNED));
    eprintln!("{dynamic} dynamic particles ({pinned} pinned beside the core), {massless} massless vertices, activations {counts:?}");
    assert_eq!(
        dynamic + pinned,
        modes.len(),
        "not every free particle woke"
    );
    assert!(massless > 0, "no massless vertex");
    assert!(counts.unchanged > 10, "{counts:?}");
}

/// The tet-level bound that picks the particles an activation visits
/// (`ActiveRegion::candidates`) must hold every particle the tool can reach. On hm1, with the
/// tool at 12 places around the epicardium and every vertex displaced up to 0.75 straight
/// towards the tool's centre (so the particles approach it as far as the bound allows), every
/// particle left out lies farther than the activation radius from the tool's surface.
#[test]
fn the_activation_region_holds_every_particle_the_tool_can_reach() {
    use palpate::cpu::activate::{ModeInputs, ParticleStatic};
    use palpate::cpu::active_region::ActiveRegion;
    let scene = Scene::load("hm1").unwrap();
    let m = Model::from_scene(&scene);
    let pd = m.particles.as_ref().unwrap();
    let params = m.step_params(scene.solver.dt.unwrap(), 0.0);
    let pp = m.particle_params(&params).unwrap();
    let tp = m.tool_params();
    let st = ParticleStatic::of(&m).unwrap();
    let node_fixed: Vec<u32> = m.inv_mass.iter().map(|&w| (w == 0.0) as u32).collect();
    let region = ActiveRegion::new(pd, &node_fixed);
    let (n, nv) = (pd.len(), m.n_vertices());
    let rest =
        |a: &[f32], i: usize| DVec3::new(a[3 * i] as f64, a[3 * i + 1] as f64, a[3 * i + 2] as f64);
    let (mut closest, mut visited, mut reachable) = (f64::INFINITY, 0usize, 0usize);
    for k in 0..12 {
        let theta = 0.5 * k as f64;
        let c = DVec3::new(
            11.0 * theta.cos(),
            11.0 * theta.sin(),
            -10.0 + 1.2 * k as f64,
        );
        let reach = 0.25 * (k % 4) as f64;
        let u: Vec<f32> = (0..nv)
            .flat_map(|i| {
                let x = rest(&m.rest, i);
                ((c - x).normalize() * reach).as_vec3().to_array()
            })
            .collect();
        let v = vec![0.0f32; 3 * nv];
        let state = palpate::contact::ToolState {
            position: c.as_vec3().to_array(),
            step: 0,
        };
        let inp = ModeInputs::new(&pp, &tp, &state, true, &st, &u, &v);
        let candidates = region.candidates(&inp, &pd.tet_offsets);
        let mut listed = vec![false; n];
        for &p in &candidates {
            listed[p as usize] = true;
        }
        for (p, &listed) in listed.iter().enumerate() {
            let x = rest(&pd.rest, p) + st.embed(&u, p).as_dvec3();
            let gap = (x - c).length() - tp.radius as f64 - pp.activation_radius as f64;
            if gap < 0.0 {
                reachable += 1;
            }
            if !listed {
                closest = closest.min(gap);
            }
        }
        visited += candidates.len();
    }
    eprintln!(
        "activation region: {visited} particle visits of {} over 12 tool places ({reachable} within reach); the nearest particle left out is {closest:.3} beyond the activation radius",
        12 * n
    );
    assert!(reachable > 100, "the tool never came near: {reachable}");
    assert!(
        closest > 0.0,
        "a particle within reach was left out ({closest})"
    );
    assert!(
        visited < 12 * n / 5,
        "the region is no region: {visited} of {} visits",
        12 * n
    );
}

/// The zig-zag (hourglass) measure of a particle layer: for each particle a, the least-squares
/// affine map F_a of its first-shell neighbours (|X_ab| ≤ 1.5 spacing), and the non-affine
/// remainder √(Σ_b |x_ab − F_a X_ab|² / Σ_b |X_ab|²). A smooth motion leaves only a
/// curvature-sized remainder; a zero-energy (hourglass) mode lives entirely in it. Returns the
/// largest value over the particles with a full shell (interior ones), and the largest
/// affine strain |F_a − I| (Frobenius) over the same particles, for scale.
fn zigzag_measure(rest: &[f32], displacement: &[f32], spacing: f64) -> (f64, f64) {
    let n = rest.len() / 3;
    let p =
        |a: &[f32], i: usize| DVec3::new(a[3 * i] as f64, a[3 * i + 1] as f64, a[3 * i + 2] as f64);
    let (mut worst, mut strain) = (0.0f64, 0.0f64);
    for a in 0..n {
        let (xa, ua) = (p(rest, a), p(displacement, a));
        let mut pairs = Vec::new();
        for b in 0..n {
            let d = p(rest, b) - xa;
            if b != a && d.length() <= 1.5 * spacing {
                pairs.push((d, d + p(displacement, b) - ua));
            }
        }
        if pairs.len() < 18 {
            continue; // on the boundary: the shell is not full
        }
        // F = (Σ x Xᵀ)(Σ X Xᵀ)⁻¹.
        let (mut xx, mut yx) = (DMat3::ZERO, DMat3::ZERO);
        for &(d, e) in &pairs {
            xx += outer(d, d);
            yx += outer(e, d);
        }
        let f = yx * xx.inverse();
        let (mut num, mut den) = (0.0, 0.0);
        for &(d, e) in &pairs {
            num += (e - f * d).length_squared();
            den += d.length_squared();
        }
        worst = worst.max((num / den).sqrt());
        let g = f - DMat3::IDENTITY;
        strain = strain.max(
            (g.x_axis.length_squared() + g.y_axis.length_squared() + g.z_axis.length_squared())
                .sqrt(),
        );
    }
    (worst, strain)
}

fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

/// Press the particle half of a layered block with a 3 mm sphere (1 mm deep), withdraw it and
/// let the block ring for three times as long: the largest zig-zag measure while pressed, and
/// after the release the largest zig-zag measure and the largest strain.
fn pressed_and_released_zigzag(particle_keys: &str) -> (f64, f64, f64) {
    let extra = "[[fixed]]\nplane = { normal = [0.0, 0.0, 1.0], offset = 0.0 }\n\n[tool]\nradius = 0.003\nstiffness = 1.0e8\npath = [[0.0, 0.01, 0.005, 0.0135], [0.02, 0.01, 0.005, 0.012], [0.03, 0.01, 0.005, 0.012], [0.031, 0.01, 0.005, 0.02]]\n";
    let scene = layered_block([0.02, 0.01, 0.01], [4, 2, 4], extra, particle_keys);
    let spacing = scene.particles.as_ref().unwrap().spacing;
    let m = Arc::new(Model::from_scene(&scene));
    let dt = 0.5 * m.bounds.dt_bound;
    let mut s = CpuStepper::new(m.clone(), m.step_params(dt, 0.0));
    let tool = scene.tool.clone().unwrap();
    let rest = m.particles.as_ref().unwrap().rest.clone();
    let (batch, mut t) = (20u32, 0.0);
    let (mut loaded, mut released, mut strain) = (0.0f64, 0.0f64, 0.0f64);
    while t < 0.12 {
        let (a, b) = (tool.position_at(t), tool.position_at(t + batch as f64 * dt));
        s.submit(batch, &palpate::stepper::BatchInput::moving(a, b))
            .unwrap();
        let r = s.wait().unwrap();
        assert!(r.stats.non_finite_vertex.is_none(), "diverged at t = {t}");
        t += batch as f64 * dt;
        let (u, _) = placed(&m, &mut s);
        let (z, e) = zigzag_measure(&rest, &u, spacing);
        if t < 0.03 {
            loaded = loaded.max(z);
        } else if t > 0.035 {
            released = released.max(z);
            strain = strain.max(e);
        }
    }
    (loaded, released, strain)
}

#[test]
fn a_pressed_and_released_tlsph_block_shows_no_hourglass_mode() {
    let (loaded, released, strain) = pressed_and_released_zigzag("hourglass = 0.1\n");
    let (loaded0, released0, strain0) = pressed_and_released_zigzag("hourglass = 0.0\n");
    // hm1's kernel: the first lattice shell only (support 1.95 spacings, 26 neighbours).
    let (_, released2, strain2) =
        pressed_and_released_zigzag("hourglass = 0.1\nkernel_radius = 1.95\n");
    let (_, released20, strain20) =
        pressed_and_released_zigzag("hourglass = 0.0\nkernel_radius = 1.95\n");
    eprintln!(
        "zig-zag measure (non-affine remainder of the first shell): hourglass 0.1: pressed {loaded:.2e}, after release {released:.2e} (strain {strain:.2e}); hourglass 0: pressed {loaded0:.2e}, after release {released0:.2e} (strain {strain0:.2e})"
    );
    // Measured (2026-11-23): ratio non-affine / strain after release 0.72 with the default
    // coefficient 0.1, 1.59 without control; 0.54 at 0.3 and 0.39 at 1.0. What remains at
    // 0.1 is the real curvature of a 3 mm indentation sampled at 1 mm, not a zig-zag mode.
    // With hm1's support of 1.95 spacings (2026-11-24): 0.49 at 0.1, 0.68 without control
    // (at exactly 2.0, on the 2Δx shell: 0.54 and 0.76).
    assert!(
        loaded > 0.0 && loaded0 > 0.0,
        "the tool never deformed the particles"
    );
    let (ratio, ratio0) = (released / strain, released0 / strain0);
    let (ratio2, ratio20) = (released2 / strain2, released20 / strain20);
    eprintln!("with a support of 1.95 spacings (hm1): after release ratio {ratio2:.2}, {ratio20:.2} without control");
    assert!(
        ratio2 <= 0.8 && ratio2 <= 0.85 * ratio20,
        "support 1.95: after release the non-affine remainder is {:.0} % of the strain ({:.0} % without control)",
        100.0 * ratio2,
        100.0 * ratio20
    );
    assert!(
        ratio <= 0.8,
        "after release the non-affine remainder is {:.0} % of the strain (zig-zag mode)",
        100.0 * ratio
    );
    assert!(
        ratio <= 0.5 * ratio0,
        "hourglass control barely changes the non-affine remainder: {ratio:.2} vs {ratio0:.2} without"
    );
}

/// The built-in haptic scene with the tool's path `path` (a TOML array of [t, x, y, z]).
fn lv_touch_along(path: &str) -> Scene {
    let text = Scene::builtin_text("lv_touch").unwrap();
    let (start, end) = (
        text.find("\npath = ").unwrap() + 1,
        text.find("\n[solver]").unwrap(),
    );
    let text = format!("{}path = {path}\n{}", &text[..start], &text[end..]);
    Scene::from_toml(&text, "lv_touch along a path", "lv_touch", None).unwrap()
}

/// What pressing `scene` on the CPU for `seconds` did: the tool's travel from home (or the
/// step it diverged at), the sub-steps (now, most; None with the count fixed) and the
/// largest stiffening measured. Batches of `batch` steps, ended early where the run ends
/// them for the sub-step checks; `adapt` false holds the scene's sub-step count.
fn press(
    scene: &Scene,
    seconds: f64,
    batch: u32,
    adapt: bool,
) -> (Result<f64, u64>, Option<(u32, u32)>, f32) {
    let (outcome, counts, stiffening, _) =
        press_on(scene, palpate::sim::Backend::Cpu, (seconds, batch, adapt));
    (outcome, counts, stiffening)
}

/// [`press`] on `backend` (seconds, batch, adapt), also giving the final state (vertex and
/// particle displacements, the tool's force, the stressed particles' largest κ now).
#[allow(clippy::type_complexity)]
fn press_on(
    scene: &Scene,
    backend: palpate::sim::Backend,
    (seconds, batch, adapt): (f64, u32, bool),
) -> (
    Result<f64, u64>,
    Option<(u32, u32)>,
    f32,
    (Vec<f32>, Vec<f32>, DVec3, f32),
) {
    let mut sim = palpate::sim::Simulation::new(
        scene,
        backend,
        palpate::sim::SimOptions {
            gpu: (backend == palpate::sim::Backend::Gpu).then(common::gpu),
            ..Default::default()
        },
    )
    .unwrap();
    let base = sim.model.particle_substeps(sim.dt);
    assert_eq!(base, 1, "lv_touch steps its particles at the core's rate");
    if !adapt {
        sim.fix_particle_substeps(base).unwrap();
    }
    let steps = (seconds / sim.dt).ceil() as u64;
    while sim.steps_done < steps {
        let n = sim.substep_batch_limit().unwrap_or(batch).min(batch) as u64;
        match sim.advance(n.min(steps - sim.steps_done) as u32).unwrap() {
            palpate::sim::Advance::Done(_) => {}
            palpate::sim::Advance::Diverged { step, .. } => {
                return (Err(step), sim.particle_substeps(), 0.0, Default::default())
            }
        }
    }
    let most = sim.max_particle_stiffening().unwrap_or(1.0);
    let state = (
        sim.state().unwrap().displacements,
        sim.particle_state().unwrap().unwrap().displacements,
        sim.last_tool.unwrap().force,
        sim.particle_stiffening() as f32,
    );
    (
        Ok(0.0147 - sim.tool_position.x),
        sim.particle_substeps(),
        most,
        state,
    )
}

/// The deep press's first 0.25 s (12 mm of travel, the layer stiffened about 30-fold) on the
/// GPU, in `run`'s 8-step batches: its sub-step count, adapted from the stiffening its
/// `particle_reduce` reports, rises as the CPU's does (the same count now and at most, the
/// same largest κ within 1e-3), and the two end in the same state within 1e-3 relative
/// (vertices, particles; the tool's force within 1e-2; κ there within 1e-3).
#[test]
fn the_gpu_adapts_its_particle_substeps_as_the_cpu_does() {
    let scene = lv_touch_along("[[0.0, 0.0147, 0.0, -0.005], [0.42, -0.0053, 0.0, -0.005]]");
    let run = |backend| press_on(&scene, backend, (0.25, 8, true));
    let (c, c_counts, c_most, (cu, cp, cf, c_k)) = run(palpate::sim::Backend::Cpu);
    let (g, g_counts, g_most, (gu, gp, gf, g_k)) = run(palpate::sim::Backend::Gpu);
    eprintln!("CPU {c:?} {c_counts:?} κ {c_k}; GPU {g:?} {g_counts:?} κ {g_k}; force {cf} / {gf}");
    assert!(c.is_ok() && g.is_ok(), "diverged: CPU {c:?}, GPU {g:?}");
    let (_, most) = c_counts.unwrap();
    assert!(most >= 3, "the CPU's count rose only to {most}");
    assert_eq!(c_counts, g_counts, "sub-steps (now, most)");
    assert!(c_k > 10.0, "the layer stiffened only {c_k}x");
    assert!((c_k / g_k - 1.0).abs() < 1e-3, "κ CPU {c_k} GPU {g_k}");
    assert!(
        (c_most / g_most - 1.0).abs() < 1e-3,
        "largest κ CPU {c_most} GPU {g_most}"
    );
    let rel = |a: &[f32], b: &[f32]| {
        let scale = a.iter().fold(0.0f32, |m, x| m.max(x.abs()));
        a.iter()
            .zip(b)
            .fold(0.0f32, |m, (x, y)| m.max((x - y).abs()))
            / scale
    };
    let (eu, ep) = (rel(&cu, &gu), rel(&cp, &gp));
    let ef = (cf - gf).length() / cf.length();
    eprintln!("rel err vertices {eu:.2e}, particles {ep:.2e}, tool force {ef:.2e}");
    assert!(eu < 1e-3 && ep < 1e-3 && ef < 1e-2);
}

/// The built-in haptic scene pressed 20 mm (far past its 3.1 mm wall) at 47.6 mm/s, just
/// under its haptic speed limit, for 0.42 s of its path, as `palpate run` steps it. The
/// particles under the tool stiffen (their largest ‖cof F‖²/3 passes 16) and one particle
/// sub-step per core step diverges on the way (before the end of the path: the step it
/// diverged at is printed); with the count adapted to the measured stiffening
/// (`palpate::substeps`) the same press stays finite to the end, at more sub-steps than
/// the scene's at the most.
#[test]
fn a_deep_press_stays_stable_with_particle_substeps_adapted_to_the_layers_stiffening() {
    let scene = lv_touch_along("[[0.0, 0.0147, 0.0, -0.005], [0.42, -0.0053, 0.0, -0.005]]");
    let (fixed, fixed_counts, _) = press(&scene, 0.42, 200, false);
    eprintln!("one sub-step: {fixed:?}");
    assert!(fixed.is_err(), "the press did not diverge at one sub-step");
    assert_eq!(fixed_counts, None, "a fixed count is not adapted");
    let (adapted, counts, stiffening) = press(&scene, 0.42, 200, true);
    let (now, most) = counts.unwrap();
    eprintln!("adapted: {adapted:?}; sub-steps now {now}, at most {most}; largest κ {stiffening}");
    let depth = adapted.expect("the adapted press diverged");
    assert!((depth - 0.020).abs() < 1e-4, "the tool reached {depth} m");
    assert!(stiffening > 16.0, "the layer stiffened only {stiffening}x");
    assert!(most >= 3, "at most {most} sub-steps");
}

/// The same scene pressed 6 mm (5 mm into the wall) in 12 ms, ten times its haptic speed
/// limit, and held, in one-step batches as a haptic session steps it: the sub-step count
/// is checked after every batch, and follows a layer crushed that fast (it diverges at one
/// sub-step, and in `run`'s 8-step batches, whose checks come too late).
#[test]
fn a_press_at_ten_times_the_speed_limit_in_one_step_batches_stays_stable() {
    let scene = lv_touch_along(
        "[[0.0, 0.0147, 0.0, -0.005], [0.012, 0.0087, 0.0, -0.005], [0.2, 0.0087, 0.0, -0.005]]",
    );
    let (fixed, _, _) = press(&scene, 0.2, 1, false);
    let (eight, _, _) = press(&scene, 0.2, 8, true);
    eprintln!("one sub-step: {fixed:?}; checked every 8 steps: {eight:?}");
    assert!(
        fixed.is_err(),
        "the fast press did not diverge at one sub-step"
    );
    assert!(
        eight.is_err(),
        "8-step batches no longer diverge: the case tells nothing"
    );
    let (adapted, counts, stiffening) = press(&scene, 0.2, 1, true);
    let (now, most) = counts.unwrap();
    eprintln!("adapted: {adapted:?}; sub-steps now {now}, at most {most}; largest κ {stiffening}");
    let travel = adapted.expect("the fast press diverged in one-step batches");
    assert!((travel - 0.006).abs() < 1e-6, "the tool reached {travel} m");
    assert!(most >= 4, "at most {most} sub-steps");
}

/// `palpate run` of the built-in haptic scene pressed 20 mm at 95 mm/s from 3.6 mm clear of
/// the wall: before any particle is dynamic the run ends its batches where the path has
/// moved the tool half the activation radius, so the count is watched from the first woken
/// particles on (in 200-step batches the tool pressed far past them before the first check
/// and the run diverged with the count never raised).
#[test]
fn a_run_watches_the_substeps_from_the_first_woken_particles() {
    let scene = lv_touch_along("[[0.0, 0.0173, 0.0, -0.005], [0.237395, -0.0053, 0.0, -0.005]]");
    let out = std::env::temp_dir().join(format!("palpate-fast-approach-{}", std::process::id()));
    let s = palpate::run::run(
        &scene,
        &palpate::run::RunOptions {
            backend: palpate::sim::Backend::Cpu,
            length: palpate::run::RunLength::Duration(0.237395),
            out: out.clone(),
            ..Default::default()
        },
    )
    .unwrap();
    let _ = std::fs::remove_dir_all(&out);
    eprintln!(
        "{:?}; sub-steps at most {:?}, κ {:?}",
        s.status, s.particle_substeps_max, s.max_particle_stiffening
    );
    assert!(
        matches!(s.status, palpate::run::RunStatus::Ok),
        "{:?}",
        s.status
    );
    assert!(s.particle_substeps_max.unwrap() >= 4);
}
