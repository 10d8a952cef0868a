//! Where a CPU step's time goes: run a built-in scene on the CPU stepper with its tool moved
//! along its path to time `t`, hold it there, then time every stage of the plan
//! (`CpuStepper::profile_stages`) and print µs per step.
//!
//! `cargo run --release --example profile_stages -- [scene] [t] [steps] [threads]`
//! (defaults: hm1 3.5 200 1).

use palpate::cpu::CpuStepper;
use palpate::sim::{Backend, SimOptions, Simulation};
use palpate::stepper::{BatchInput, Stepper};
use palpate::Scene;
use std::sync::Arc;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let name = args.first().map_or("hm1", |s| s.as_str());
    let hold_time: f64 = args.get(1).map_or(Ok(3.5), |s| s.parse())?;
    let steps: u32 = args.get(2).map_or(Ok(200), |s| s.parse())?;
    let threads: usize = args.get(3).map_or(Ok(1), |s| s.parse())?;
    let scene = Scene::load(name)?;
    let sim = Simulation::new(&scene, Backend::Cpu, SimOptions::default())?;
    let model: Arc<_> = sim.model.clone();
    let params = model.step_params(sim.dt, sim.damping);
    let mut stepper = CpuStepper::with_threads(model.clone(), params, threads)?;
    let tool = scene.tool.as_ref();
    let batch = 10u32;
    let mut t = 0.0;
    let mut from = tool.map(|t| t.position_at(0.0));
    while t < hold_time {
        let to = tool.map(|tl| tl.position_at((t + batch as f64 * sim.dt).min(hold_time)));
        stepper.submit(batch, &BatchInput { tool: from.zip(to) })?;
        stepper.wait()?;
        from = to;
        t += batch as f64 * sim.dt;
    }
    let times = stepper.profile_stages(steps);
    let total: f64 = times.per_stage.iter().map(|(_, ns)| ns).sum();
    println!(
        "{name}: {} tets, {} threads, tool held at t = {hold_time}; µs per step over {steps} steps",
        model.n_tets(),
        threads
    );
    for (stage, ns) in &times.per_stage {
        println!("  {:<24} {:>9.1}", format!("{stage:?}"), ns / 1e3);
    }
    println!("  {:<24} {:>9.1}", "total", total / 1e3);
    if let Some(modes) = stepper.particle_modes() {
        use palpate::particles::params::mode;
        let count = |bit: u32| modes.iter().filter(|&&m| m & bit != 0).count();
        println!(
            "  particles: {} dynamic, {} in the stress set, {} in the force set, of {}",
            count(mode::DYNAMIC),
            count(mode::IN_S),
            count(mode::IN_F),
            modes.len()
        );
    }
    Ok(())
}
