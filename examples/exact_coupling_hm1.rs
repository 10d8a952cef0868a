//! Design 8 on a real press (docs/hybrid_coupling.md, "Design 8 in Rust"): run a built-in
//! scene with the shipped coupling to time `t` with its tool pressed along its path, take its
//! dynamic set, and report what design 8 would make of it: how many vertices it slaves,
//! whether every follower's mass finds a corner that is not slaved, how much mass the other
//! vertices lose (their step bound scales with √m), and what one reference evaluation costs.
//!
//! `cargo run --release --example exact_coupling_hm1 -- [scene] [t]` (defaults: hm1 3.5).

#[path = "shared/press.rs"]
mod press;

use palpate::cpu::exact_coupling::{ExactCoupling, Slaving};
use palpate::cpu::CpuStepper;
use palpate::particles::params::mode;
use palpate::sim::{Backend, SimOptions, Simulation};
use palpate::stepper::Stepper;
use palpate::Scene;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let name = args.first().map_or("hm1", |s| s.as_str());
    let hold_time: f64 = args.get(1).map_or(Ok(3.5), |s| s.parse())?;
    let scene = Scene::load(name)?;
    let sim = Simulation::new(&scene, Backend::Cpu, SimOptions::default())?;
    let model = sim.model.clone();
    let params = model.step_params(sim.dt, sim.damping);
    let mut c = CpuStepper::with_threads(model.clone(), params, 2)?;
    press::press(&mut c, &scene, sim.dt, hold_time)?;
    let particles = model
        .particles
        .as_ref()
        .ok_or("the scene has no [particles]")?;
    let snapshot = c.particle_state().ok_or("no particle state")?;
    let vertex_u = c.read_state()?.displacements;
    let dynamic: Vec<bool> = snapshot
        .modes
        .iter()
        .map(|&m| m & mode::DYNAMIC != 0)
        .collect();
    let n_dynamic = dynamic.iter().filter(|&&d| d).count();
    println!(
        "{name} at t = {hold_time}: {n_dynamic} dynamic of {} particles",
        particles.len()
    );
    let slaving = match Slaving::new(&model, particles, &dynamic) {
        Ok(s) => s,
        Err(e) => {
            println!("design 8 cannot slave this set: {e:?}");
            return Ok(());
        }
    };
    // What a re-slave costs (the activation's when the set changes), and the one sum over
    // every particle its lumping avoids (its vertices outside the set's reach are copied).
    let time = |f: &mut dyn FnMut()| {
        let start = std::time::Instant::now();
        for _ in 0..20 {
            f();
        }
        start.elapsed().as_secs_f64() * 1e6 / 20.0
    };
    let per_call = time(&mut || {
        std::hint::black_box(Slaving::new(&model, particles, &dynamic).ok());
    });
    let one_sum = time(&mut || {
        std::hint::black_box(Slaving::lumped_over_every_particle(
            &model,
            particles,
            &slaving.dynamic,
            &slaving.slaved,
        ));
    });
    println!("Slaving::new: {per_call:.0} µs a call; a lumping summed over every particle instead: {one_sum:.0} µs");
    let added = slaving.dynamic.iter().filter(|&&d| d).count() - n_dynamic;
    let dynamic = slaving.dynamic.clone();
    println!("followers made dynamic because their four corners are slaved: {added}");
    let embedded = particles.embedded_mass();
    let slaved = slaving.slaved.iter().filter(|&&s| s).count();
    // Vertices that keep their place but lose mass to the dynamic particles.
    let mut ratios: Vec<f32> = (0..model.n_vertices())
        .filter(|&v| !slaving.slaved[v] && slaving.vertex_mass[v] < embedded[v] * (1.0 - 1e-5))
        .map(|v| slaving.vertex_mass[v] / embedded[v])
        .collect();
    ratios.sort_by(f32::total_cmp);
    let smallest = ratios.first().copied().unwrap_or(1.0);
    println!(
        "slaved vertices: {slaved}; vertices that lose more than 1e-5 of their mass but keep their place: {} (smallest mass left {:.4} of the embedded, so a step bound of {:.4} of theirs)",
        ratios.len(),
        smallest,
        smallest.sqrt()
    );
    let coupling = ExactCoupling::new(&model).map_err(|e| e.to_string())?;
    let start = std::time::Instant::now();
    let f = coupling.forces(&model, &dynamic, &vertex_u, &snapshot.displacements);
    let ms = start.elapsed().as_secs_f64() * 1e3;
    let in_s = coupling.stress_set(&dynamic).iter().filter(|&&s| s).count();
    println!(
        "one reference evaluation (serial, unoptimised): {ms:.1} ms; {in_s} particles in S; energy {:.4e}",
        f.energy
    );
    Ok(())
}
