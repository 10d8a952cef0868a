//! Where a step's time goes: run a built-in scene with its tool moved along its path to time
//! `t`, hold it there, then time every stage of the plan and print µs per step: on the CPU
//! stepper (`CpuStepper::profile_stages`), or with `gpu` for the threads argument on the GPU
//! stepper (`GpuStepper::profile_stages`: timestamp queries, one compute pass per stage as a batch records them (a fused dispatch is one, shown as host+rider), at
//! most 100 runs; every stage runs once per run, including those planned every k steps). On
//! the CPU it then times one batch of whole steps as the stepper runs them (on more than one
//! thread the particle stages run beside the element forces there); on the GPU, batches of 10
//! steps each waited for, and where design 8's activations run on a CPU twin
//! (`hm1_exact`), what their round trips cost.
//!
//! `cargo run --release --example profile_stages -- [scene] [t] [steps] [threads | gpu]`
//! (defaults: hm1 3.5 200 1).

use palpate::cpu::CpuStepper;
use palpate::gpu::stepper::{GpuStepper, StageTimes};
use palpate::sim::{Backend, SimOptions, Simulation};
use palpate::stepper::{BatchInput, Stepper};
use palpate::Scene;
use std::sync::Arc;

#[path = "shared/press.rs"]
mod press;
use press::press;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let name = args.first().map_or("hm1", |s| s.as_str());
    let hold_time: f64 = args.get(1).map_or(Ok(3.5), |s| s.parse())?;
    let steps: u32 = args.get(2).map_or(Ok(200), |s| s.parse())?;
    if steps == 0 {
        return Err("steps: at least 1".into());
    }
    let on_gpu = args.get(3).is_some_and(|s| s == "gpu");
    let scene = Scene::load(name)?;
    let sim = Simulation::new(&scene, Backend::Cpu, SimOptions::default())?;
    let model: Arc<_> = sim.model.clone();
    let params = model.step_params(sim.dt, sim.damping);
    let (times, modes, on): (StageTimes, Option<Vec<u32>>, String) = if on_gpu {
        let ctx = Arc::new(palpate::gpu::GpuContext::new()?);
        let mut g = GpuStepper::new(ctx, &model, params)?;
        let held = press(&mut g, &scene, sim.dt, hold_time)?;
        let (full, skipped) = g.activation_counts()?;
        println!("activations during the press: {full} full, {skipped} skipped by the gate (no particle became or stopped being dynamic)");
        if let Some(trips) = g.take_exact_round_trips() {
            print_round_trips("during the press", &trips);
        }
        // Whole steps as batches run them (the CPU twin's round trips included), after one
        // batch of warm-up.
        let tool = held.map(|p| (p, p));
        let input = BatchInput {
            tool,
            tool_slice: None,
        };
        g.submit(10, &input)?;
        g.wait()?;
        g.take_exact_round_trips();
        let batches = steps.div_ceil(10);
        let start = std::time::Instant::now();
        let mut submitting = 0.0;
        for _ in 0..batches {
            let t = std::time::Instant::now();
            g.submit(10, &input)?;
            submitting += t.elapsed().as_secs_f64();
            g.wait()?;
        }
        let per_step = |s: f64| s * 1e6 / (10 * batches) as f64;
        println!(
            "whole steps, batches of 10 each submitted and waited for: {:.1} µs per step, of which {:.1} in submit on the CPU (recording and submitting; with batches recorded ahead, recording the next while the GPU runs this one)",
            per_step(start.elapsed().as_secs_f64()),
            per_step(submitting)
        );
        if let Some(trips) = g.take_exact_round_trips() {
            print_round_trips("during those steps", &trips);
        }
        let times = g
            .profile_stages(steps)?
            .ok_or("the adapter has no timestamp queries")?;
        let modes = g.read_particle_state()?.map(|s| s.modes);
        (times, modes, g.name())
    } else {
        let threads: usize = args.get(3).map_or(Ok(1), |s| s.parse())?;
        let mut c = CpuStepper::with_threads(model.clone(), params, threads)?;
        let held = press(&mut c, &scene, sim.dt, hold_time)?;
        let before = c.activation_counts().unwrap_or_default();
        let times = c.profile_stages(steps);
        if let Some(after) = c.activation_counts() {
            println!(
                "activations while profiled: {} full, {} over the region with a set changed, {} with none changed",
                after.full - before.full,
                after.region - before.region,
                after.unchanged - before.unchanged
            );
        }
        // Whole steps as the stepper runs them (on more than one thread the particle chain
        // runs beside the element forces, which the stage-by-stage profile cannot show).
        let tool = held.map(|p| (p, p));
        let start = std::time::Instant::now();
        c.submit(
            steps,
            &BatchInput {
                tool,
                tool_slice: None,
            },
        )?;
        c.wait()?;
        let whole = start.elapsed().as_secs_f64() * 1e6 / steps as f64;
        println!("whole steps, stages overlapped as the stepper runs them: {whole:.1} µs per step");
        let modes = c.particle_modes().map(|m| m.to_vec());
        if let (Some(m), Some(l)) = (&modes, c.neighbour_lists()) {
            println!(
                "pairs that carry a force (both in the force set, one in the stress set), each once: {}",
                force_pairs(m, &l.neighbour_offsets, &l.neighbours)
            );
        }
        (times, modes, format!("{threads} threads"))
    };
    let total: f64 = times.per_stage.iter().map(|(_, ns)| ns).sum();
    println!(
        "{name}: {} tets, {on}, tool held at t = {hold_time}; µs per step over {steps} steps",
        model.n_tets(),
    );
    for (stage, ns) in &times.per_stage {
        let riders: Vec<String> = times
            .carried
            .iter()
            .filter(|(_, host)| host == stage)
            .map(|(rider, _)| format!("{rider:?}"))
            .collect();
        let name = match riders.is_empty() {
            true => format!("{stage:?}"),
            false => format!("{stage:?}+{}", riders.join("+")),
        };
        println!("  {name:<34} {:>9.1}", ns / 1e3);
    }
    println!("  {:<34} {:>9.1}", "total", total / 1e3);
    if let Some(modes) = modes {
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

/// Median and largest of each part of design 8's round trips to the CPU twin, in µs.
fn print_round_trips(when: &str, trips: &[palpate::gpu::stepper::RoundTrip]) {
    if trips.is_empty() {
        println!("no activation round trips {when}");
        return;
    }
    let stat = |f: &dyn Fn(&palpate::gpu::stepper::RoundTrip) -> f64| {
        let mut v: Vec<f64> = trips.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        (v[v.len() / 2] * 1e6, v[v.len() - 1] * 1e6)
    };
    let changed = trips.iter().filter(|t| t.changed).count();
    println!(
        "{} activation round trips to the CPU twin {when} ({changed} changed a set); µs, median / largest:",
        trips.len()
    );
    for (name, (median, largest)) in [
        ("drain (the GPU's steps)", stat(&|t| t.drain)),
        ("read back", stat(&|t| t.read)),
        ("activate on the twin", stat(&|t| t.activate)),
        ("queue the writes", stat(&|t| t.write)),
        ("round trip (read + activate + write)", stat(&|t| t.cost())),
    ] {
        println!("  {name:<38} {median:>9.1} {largest:>9.1}");
    }
}

/// The neighbour pairs whose ends are both in the force set and at least one in the stress
/// set, each counted once (what the CPU's pair forces evaluate a step).
fn force_pairs(modes: &[u32], offsets: &[u32], neighbours: &[u32]) -> usize {
    use palpate::particles::params::mode;
    let has = |p: usize, bit: u32| modes[p] & bit != 0;
    (0..modes.len())
        .flat_map(|c| {
            (offsets[c]..offsets[c + 1]).map(move |k| (c, neighbours[k as usize] as usize))
        })
        .filter(|&(c, b)| {
            c < b
                && has(c, mode::IN_F)
                && has(b, mode::IN_F)
                && (has(c, mode::IN_S) || has(b, mode::IN_S))
        })
        .count()
}
