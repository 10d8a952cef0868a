//! Trace design 8 under a tool-driven dynamic set (`particles.coupling = "exact"` with
//! `activation = "tool"`): run a scene in batches along its tool path and print, per batch,
//! the dynamic and slaved counts, what the activations changed, the largest vertex speed, the
//! largest δ (a dynamic particle off its embedded place) and the largest slaved-vertex offset.
//!
//! `cargo run --release --example exact_tool_trace -- <scene> [duration] [batch]`.

use palpate::cpu::CpuStepper;
use palpate::particles::params::mode;
use palpate::sim::{Backend, SimOptions, Simulation};
use palpate::stepper::{BatchInput, Stepper};
use palpate::Scene;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let name = args
        .first()
        .ok_or("usage: exact_tool_trace <scene> [duration] [batch]")?;
    let scene = Scene::load(name)?;
    let duration: f64 = args
        .get(1)
        .map_or(Ok(scene.solver.duration.unwrap_or(10.0)), |s| s.parse())?;
    let batch: u32 = args.get(2).map_or(Ok(10), |s| s.parse())?;
    let sim = Simulation::new(&scene, Backend::Cpu, SimOptions::default())?;
    let model = sim.model.clone();
    let p = model.particles.as_ref().ok_or("no [particles]")?;
    let mut c = CpuStepper::with_threads(model.clone(), model.step_params(sim.dt, sim.damping), 2)?;
    let tool = scene.tool.as_ref();
    let mut t = 0.0;
    let mut from = tool.map(|tl| tl.position_at(0.0));
    while t < duration {
        let to = tool.map(|tl| tl.position_at(t + batch as f64 * sim.dt));
        c.submit(
            batch,
            &BatchInput {
                tool: from.zip(to),
                tool_slice: None,
            },
        )?;
        let report = c.wait()?;
        from = to;
        t += batch as f64 * sim.dt;
        let st = c.read_state()?;
        let ps = c.particle_state().ok_or("no particle state")?;
        let vmax = st
            .velocities
            .chunks_exact(3)
            .map(|v| glam::Vec3::from_slice(v).length())
            .fold(0.0f32, f32::max);
        let dynamic: Vec<usize> = (0..p.len())
            .filter(|&q| ps.modes[q] & mode::DYNAMIC != 0)
            .collect();
        let blending = (0..p.len())
            .filter(|&q| ps.modes[q] & mode::BLENDING != 0)
            .count();
        let delta = dynamic
            .iter()
            .map(|&q| {
                (glam::Vec3::from_slice(&ps.displacements[3 * q..3 * q + 3])
                    - p.embed(&model.tets, &st.displacements, q))
                .length()
            })
            .fold(0.0f32, f32::max);
        let (sl, off, counts) = c.exact_slaving().ok_or("not the exact coupling")?;
        let slaved = sl.slaved.iter().filter(|&&s| s).count();
        let offset = (0..sl.slaved.len())
            .filter(|&v| sl.slaved[v])
            .map(|v| {
                off.left(v, c.particle_params().map_or(0.0, |pp| pp.blend))
                    .length()
            })
            .fold(0.0f32, f32::max);
        let spread = (0..sl.slaved.len())
            .filter(|&v| sl.slaved[v])
            .map(|v| sl.fit[v].iter().map(|&(_, s)| s.abs()).sum::<f32>())
            .fold(0.0f32, f32::max);
        println!(
            "t {t:6.3} max Σ|s| {spread:7.2} dynamic {:5} blending {blending:5} slaved {slaved:4} closed {:6} newly slaved {:5} freed {:5} | max |v| {vmax:.3e} max δ {delta:.3e} max offset {offset:.3e} KE {:.4e}",
            dynamic.len(),
            counts.closed,
            counts.newly_slaved,
            counts.freed,
            report.stats.kinetic_energy(),
        );
    }
    Ok(())
}
