//! A free spin of the hybrid two-layer block: how far each kind of vertex and the dynamic
//! particles get from the body's best-fit rigid motion, and where the kinetic energy goes. A
//! probe for the slide of the particle layer on the core in `docs/hybrid_coupling.md` (the zone
//! vertices next to the interface, which host a few pinned particles, drift far from the
//! body); not a test, it asserts nothing.
//!
//! `cargo run --release --example free_spin -- [ω rad/s] [steps] [dt/bound]` (defaults: 37 1000
//! 0.5; the last is the core step as a fraction of its stable bound). With `SPIN_PARTS=1` it
//! also fits the core's vertices and the dynamic particles each on their own and prints how
//! far the particles' rigid motion is from the core's, and with `SPIN_GROUPS=1` as well each
//! group's (interface vertices, pinned and dynamic particles, zone vertices with mass) mean
//! offset from the core's motion in the core's frame. The block is 20 × 10 × 10 mm, its lower
//! half tet core, its upper half particle zone (1 mm lattice, every particle dynamic except
//! those pinned beside the core); it spins about its long (x) axis through its centre, every
//! vertex and particle started on the rigid motion. The lumped masses' principal axes are not
//! the block's, so the body precesses; the line says how far its rotation is from the
//! prescribed turn.

use glam::{DMat3, DVec3};
use palpate::cpu::CpuStepper;
use palpate::model::Model;
use palpate::particles::params::mode;
use palpate::stepper::{BatchInput, State, Stepper};
use palpate::Scene;
use std::sync::Arc;

/// The two-layer block (the scene of `tests/hybrid.rs`' free-flight test).
fn two_layer_block() -> Result<Scene, Box<dyn std::error::Error>> {
    let text = "[mesh]\ngenerator = \"beam\"\nsize = [0.02, 0.01, 0.01]\ncells = [4, 2, 4]\n\n\
        [material]\nyoungs_modulus = 3.0e4\npoisson_ratio = 0.3\ndensity = 1000.0\n\n\
        [particles]\nregion = 0\nspacing = 0.001\nactivation_radius = 0.003\n\
        activation = \"all\"\nactivation_interval = 1\n";
    let mut scene = Scene::from_toml(text, "two-layer block", "block", None)?;
    for e in 0..scene.mesh.n_tets() {
        let z: f64 = scene.mesh.corners(e).iter().map(|p| p.z).sum::<f64>() / 4.0;
        scene.mesh.regions[e] = if z < 0.005 { 1 } else { 0 };
    }
    Ok(scene)
}

/// The rigid motion x ≈ c + R (X − C) that best fits `points` (rest X, now x, mass):
/// C, c the mass centres, R the rotation of the polar decomposition of
/// H = Σ m (x − c)(X − C)ᵀ (Newton's iteration R ← (R + R⁻ᵀ)/2, which needs det H > 0:
/// None where the points are no rotated rest shape, which no rotation fits).
fn best_rigid_fit(points: &[(DVec3, DVec3, f64)]) -> Option<(DMat3, DVec3, DVec3)> {
    let total: f64 = points.iter().map(|p| p.2).sum();
    let rest_centre = points.iter().map(|p| p.0 * p.2).sum::<DVec3>() / total;
    let centre = points.iter().map(|p| p.1 * p.2).sum::<DVec3>() / total;
    let mut h = DMat3::ZERO;
    for &(x0, x, mi) in points {
        let (a, b) = (x - centre, x0 - rest_centre);
        h += DMat3::from_cols(a * b.x, a * b.y, a * b.z) * mi;
    }
    let positive = h.determinant() > 0.0; // (false for NaN too)
    if !positive {
        return None;
    }
    let mut r = h * (1.0 / h.determinant().cbrt());
    for _ in 0..30 {
        r = (r + r.inverse().transpose()) * 0.5;
    }
    Some((r, rest_centre, centre))
}

/// The angle of rotation R: acos((tr R − 1)/2).
fn rotation_angle(r: DMat3) -> f64 {
    ((r.x_axis.x + r.y_axis.y + r.z_axis.z - 1.0) / 2.0)
        .clamp(-1.0, 1.0)
        .acos()
}

fn v3(a: &[f32], i: usize) -> DVec3 {
    DVec3::new(a[3 * i] as f64, a[3 * i + 1] as f64, a[3 * i + 2] as f64)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let omega: f64 = args.first().map_or(Ok(37.0), |s| s.parse())?;
    let steps: u32 = args.get(1).map_or(Ok(1000), |s| s.parse())?;
    let dt_fraction: f64 = args.get(2).map_or(Ok(0.5), |s| s.parse())?;
    let scene = two_layer_block()?;
    let m = Arc::new(Model::from_scene(&scene));
    let pd = m.particles.as_ref().ok_or("the block has particles")?;
    let params = m.step_params(dt_fraction * m.bounds.dt_bound, 0.0);
    let mut s = CpuStepper::new(m.clone(), params);

    let w = DVec3::new(omega, 0.0, 0.0);
    // One step at rest makes the particles dynamic and lumps the vertex masses; the spin
    // is about the centre of mass of those masses and the dynamic particles'.
    s.run(1)?;
    let (mut mass_sum, mut moment) = (0.0f64, DVec3::ZERO);
    let (mass, inv) = s.vertex_masses();
    for i in (0..m.n_vertices()).filter(|&i| inv[i] >= 0.0) {
        mass_sum += mass[i] as f64;
        moment += v3(&m.rest, i) * mass[i] as f64;
    }
    let modes = s.particle_modes().ok_or("particle modes")?;
    for p in (0..pd.len()).filter(|&p| modes[p] & mode::DYNAMIC != 0) {
        mass_sum += pd.mass as f64;
        moment += v3(&pd.rest, p) * pd.mass as f64;
    }
    let centre = moment / mass_sum;
    println!("centre of mass {centre:?} m");
    let rigid = |x: DVec3| w.cross(x - centre).as_vec3().to_array();
    let v: Vec<f32> = (0..m.n_vertices())
        .flat_map(|i| rigid(v3(&m.rest, i)))
        .collect();
    let zero = vec![0.0f32; 3 * m.n_vertices()];
    let pv: Vec<f32> = (0..pd.len()).flat_map(|p| rigid(v3(&pd.rest, p))).collect();
    s.set_particle_state(&State {
        displacements: vec![0.0; pv.len()],
        velocities: pv,
    });
    s.write_state(&State {
        displacements: zero,
        velocities: v,
    })?;
    s.run(1)?;
    println!(
        "free spin at {omega} rad/s, dt {:.2e} s ({} particle sub-steps); largest distance from the rigid motion, m, and \
         kinetic energy, J (vertices: core, interface z = 5 mm, zone with mass, massless), each \
         from the body's best-fit rigid motion",
        s.dt(),
        m.particle_substeps(s.dt() as f64)
    );
    let batch = (steps / 10).max(1);
    let mut done = 1u32;
    while done < steps {
        s.submit(batch, &BatchInput::default())?;
        let report = s.wait()?;
        done += batch;
        let angle = omega * done as f64 * s.dt() as f64;
        let rot = DMat3::from_axis_angle(w.normalize(), angle);
        let st = s.read_state()?;
        let ps = s.particle_state().ok_or("particle state")?;
        let modes = s.particle_modes().ok_or("particle modes")?;
        let (mass, inv) = s.vertex_masses();
        // The body's own rigid motion: the best fit (mass-weighted) of the vertices that carry
        // mass and the dynamic particles. (The lumped masses' principal axes are not the
        // block's: a spin about x precesses, so the prescribed turn is no reference.)
        let vertex_points: Vec<(DVec3, DVec3, f64)> = (0..m.n_vertices())
            .filter(|&i| inv[i] > 0.0)
            .map(|i| {
                let x0 = v3(&m.rest, i);
                (x0, x0 + v3(&st.displacements, i), mass[i] as f64)
            })
            .collect();
        let particle_points: Vec<(DVec3, DVec3, f64)> = (0..pd.len())
            .filter(|&p| modes[p] & mode::DYNAMIC != 0)
            .map(|p| {
                let x0 = v3(&pd.rest, p);
                (x0, x0 + v3(&ps.displacements, p), pd.mass as f64)
            })
            .collect();
        let points = [&vertex_points[..], &particle_points[..]].concat();
        let Some((body_rot, rest_centre, centre_now)) = best_rigid_fit(&points) else {
            // At 37 rad/s the particle layer turns far against the core (by step 600 the two
            // rigid motions are 11 mm apart): the whole body is then no rotated rest shape.
            println!("step {done:5}: no rotation fits the whole body");
            continue;
        };
        if std::env::var("SPIN_PARTS").is_ok() {
            // The core's vertices and the dynamic particles, each fitted on its own: how far
            // each is from its own rigid motion, and how far the particles' motion is from the
            // core's (at the particles).
            let core: Vec<_> = vertex_points
                .iter()
                .copied()
                .filter(|p| p.0.z < 0.0049)
                .collect();
            let layer = &particle_points;
            let (rc, cc0, cc1) = best_rigid_fit(&core).ok_or("no rotation fits the core")?;
            let (rl, cl0, cl1) = best_rigid_fit(layer).ok_or("no rotation fits the particles")?;
            let own = |pts: &[(DVec3, DVec3, f64)], r: DMat3, c0: DVec3, c1: DVec3| {
                pts.iter()
                    .map(|&(x0, x, _)| (x - (c1 + r * (x0 - c0))).length())
                    .fold(0.0, f64::max)
            };
            let between = layer
                .iter()
                .map(|&(x0, _, _)| ((cc1 + rc * (x0 - cc0)) - (cl1 + rl * (x0 - cl0))).length())
                .fold(0.0, f64::max);
            let massless = (0..m.n_vertices())
                .filter(|&i| inv[i] < 0.0)
                .map(|i| {
                    let x0 = v3(&m.rest, i);
                    (x0 + v3(&st.displacements, i) - (cl1 + rl * (x0 - cl0))).length()
                })
                .fold(0.0, f64::max);
            if std::env::var("SPIN_GROUPS").is_ok() {
                // Mean offset from the core's rigid motion, in the core's frame, by group.
                let to_core = |x0: DVec3, x: DVec3| rc.transpose() * (x - (cc1 + rc * (x0 - cc0)));
                // The mean of `to_core` over the points of (rest, displacements) that `keep`.
                let mean = |rest: &[f32], u: &[f32], keep: &dyn Fn(usize) -> bool| {
                    let (sum, n) = (0..rest.len() / 3)
                        .filter(|&i| keep(i))
                        .map(|i| to_core(v3(rest, i), v3(rest, i) + v3(u, i)))
                        .fold((DVec3::ZERO, 0usize), |(s, n), o| (s + o, n + 1));
                    sum / n.max(1) as f64
                };
                let (u, pu) = (&st.displacements, &ps.displacements);
                let interface = mean(&m.rest, u, &|i| (m.rest[3 * i + 2] - 0.005).abs() < 1e-4);
                let pinned = mean(&pd.rest, pu, &|p| modes[p] & mode::PINNED != 0);
                let dynamic = mean(&pd.rest, pu, &|p| modes[p] & mode::DYNAMIC != 0);
                let light = mean(&m.rest, u, &|i| inv[i] > 0.0 && m.rest[3 * i + 2] > 0.0051);
                let f = |v: DVec3| format!("({:+.1e}, {:+.1e}, {:+.1e})", v.x, v.y, v.z);
                println!(
                    "  in the core's frame: interface {}, pinned {}, dynamic {}, zone vertices with mass {}",
                    f(interface),
                    f(pinned),
                    f(dynamic),
                    f(light)
                );
            }
            let turn = rotation_angle(rc.transpose() * rl);
            let centre_off = (cl1 - cl0) - (cc1 + rc * (cl0 - cc0) - cl0);
            println!(
                "  massless vertices off the particles' rigid motion {massless:.2e} m; the particles turned {turn:.2e} rad against the core, their centre {:.2e} m off ({:?} in the core's frame)",
                centre_off.length(),
                (rc.transpose() * centre_off).to_array()
            );
            println!(
                "  core ({}) off its own rigid motion {:.2e} m, particles ({}) {:.2e} m; the particles' rigid motion off the core's {:.2e} m",
                core.len(),
                own(&core, rc, cc0, cc1),
                layer.len(),
                own(layer, rl, cl0, cl1),
                between
            );
        }
        let precession = rotation_angle(rot.transpose() * body_rot);
        let off = |rest: &[f32], u: &[f32], i: usize| {
            let x0 = v3(rest, i);
            (x0 + v3(u, i) - (centre_now + body_rot * (x0 - rest_centre))).length()
        };
        let (mut dev, mut ke) = ([0.0f64; 4], [0.0f64; 4]);
        for i in 0..m.n_vertices() {
            let z = m.rest[3 * i + 2];
            let class = if inv[i] < 0.0 {
                3
            } else if z < 0.0049 {
                0
            } else if z < 0.0051 {
                1
            } else {
                2
            };
            dev[class] = dev[class].max(off(&m.rest, &st.displacements, i));
            if inv[i] >= 0.0 {
                ke[class] += 0.5 * mass[i] as f64 * v3(&st.velocities, i).length_squared();
            }
        }
        let particles = (0..pd.len())
            .filter(|&p| modes[p] & mode::DYNAMIC != 0)
            .map(|p| off(&pd.rest, &ps.displacements, p))
            .fold(0.0f64, f64::max);
        let pr = report.particles.unwrap_or_default();
        let total = report.stats.kinetic_energy()
            + report.stats.elastic_energy()
            + pr.kinetic_energy
            + pr.elastic_energy;
        println!(
            "step {done:5} ({angle:5.2} rad, body {precession:.2e} rad off the prescribed turn): vertices {:.2e} {:.2e} {:.2e} {:.2e}, particles \
             {particles:.2e}; KE {:.2e} {:.2e} {:.2e} + particles {:.2e}; total energy {total:.5e}",
            dev[0], dev[1], dev[2], dev[3], ke[0], ke[1], ke[2], pr.kinetic_energy
        );
    }
    Ok(())
}
