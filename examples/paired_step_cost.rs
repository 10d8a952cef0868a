//! Step cost of scene variants against a baseline, timed in turns in one process: each scene
//! is pressed along its tool's path to time `t` and held there, then every round times one
//! call of 10 steps of each scene in turn, so a host whose speed drifts slows them all alike.
//! Prints each scene's median µs per step and the median over rounds of its time / the first
//! scene's (paired). The bench's ratio table (`benches/hybrid_step.rs`) does this for hm1's
//! fixed variants; this takes any scene files, e.g. hm1 with another kernel support
//! (BENCHMARKS.md, "hybrid_step").
//!
//! `cargo run --release --example paired_step_cost -- <threads> <t> <rounds> <baseline> <scene>...`

use palpate::sim::{Backend, SimOptions, Simulation};
use palpate::Scene;
use std::time::Instant;

/// Steps per timed call.
const STEPS: u32 = 10;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 4 {
        return Err(
            "usage: paired_step_cost <threads> <t> <rounds> <baseline scene> [scene ...]".into(),
        );
    }
    let threads: usize = args[0]
        .parse()
        .map_err(|e| format!("threads {:?}: {e}", args[0]))?;
    let t: f64 = args[1]
        .parse()
        .map_err(|e| format!("t {:?}: {e}", args[1]))?;
    let rounds: usize = args[2]
        .parse()
        .map_err(|e| format!("rounds {:?}: {e}", args[2]))?;
    if threads == 0 || rounds == 0 || !(t.is_finite() && t >= 0.0) {
        return Err("threads and rounds: at least 1; t: a finite time ≥ 0".into());
    }
    let names = &args[3..];
    let mut sims = Vec::new();
    for name in names {
        let scene = Scene::load(name)?;
        let tool = scene
            .tool
            .as_ref()
            .ok_or(format!("{name}: the scene has no [tool] to hold"))?;
        let hold = tool.position_at(t);
        let options = SimOptions {
            threads: Some(threads),
            ..Default::default()
        };
        let mut sim = Simulation::new(&scene, Backend::Cpu, options)?;
        while sim.time < t {
            sim.advance(STEPS)?;
        }
        sim.tool_target = Some(hold);
        sim.advance(STEPS)?;
        sims.push(sim);
    }
    let mut us = vec![Vec::with_capacity(rounds); sims.len()];
    for _ in 0..rounds {
        for (sim, times) in sims.iter_mut().zip(us.iter_mut()) {
            let start = Instant::now();
            sim.advance(STEPS)?;
            times.push(1e6 * start.elapsed().as_secs_f64() / STEPS as f64);
        }
    }
    let median = |v: &[f64]| {
        let mut v = v.to_vec();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    println!("{threads} threads, tool held at t = {t}, {rounds} rounds of {STEPS} steps:");
    for (k, name) in names.iter().enumerate() {
        let paired: Vec<f64> = us[k].iter().zip(&us[0]).map(|(a, b)| a / b).collect();
        let dynamic = sims[k]
            .last_particles
            .map_or("no particles".to_string(), |p| {
                format!("{} dynamic", p.dynamic)
            });
        println!(
            "  {name}: {:.0} µs a step ({dynamic}); / {}: {:.3} paired",
            median(&us[k]),
            names[0],
            median(&paired)
        );
    }
    Ok(())
}
