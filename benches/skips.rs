//! What the step plan's skips save (DESIGN §1: "each skip is measured in a benchmark"): the
//! beam scene at 15,360 tets as shipped (no viscosity, no tool), with strain-rate viscosity
//! (the viscous variant of `fem_forces`), and with a tool held far above it (the `contact`
//! and `tool_force` stages run, and touch nothing). A ratio above 1 is what a scene without
//! that feature does not pay. The particle layer's skip is in `hybrid_step` (the core alone
//! against HM1), the haptic session's sleep at rest in `palpate bench haptic`. After the
//! criterion groups, a table of the ratios measured in the same run is printed.
//!
//! `PALPATE_BENCH_BACKENDS=cpu` (or `gpu`) limits the backends.

mod common;

use common::{backends, median};
use criterion::{criterion_group, BenchmarkId, Criterion};
use palpate::sim::{Backend, SimOptions, Simulation};
use palpate::Scene;
use std::time::Duration;

/// Steps per timed call (one batch).
const STEPS: u32 = 10;

/// The beam at 40 × 8 × 8 cells (15,360 tets): (label, scene) as shipped, viscous, with a
/// far tool.
fn variants() -> Vec<(&'static str, Scene)> {
    let beam = Scene::builtin_text("beam")
        .expect("beam")
        .replace("cells = [20, 4, 4]", "cells = [40, 8, 8]");
    assert!(
        beam.contains("cells = [40, 8, 8]"),
        "the beam's cells moved"
    );
    let viscous = beam.replace("viscosity = [0.0, 0.0]", "viscosity = [5.0, 5.0]");
    assert!(viscous != beam, "the beam's viscosity line moved");
    let tool = beam.replace(
        "[solver]",
        "[tool]\nradius = 0.005\nstiffness = 1.0e8\npath = [[0.0, 0.05, 0.01, 0.2]]\n\n[solver]",
    );
    let load = |text: &str, label: &str| Scene::from_toml(text, label, "beam", None).unwrap();
    vec![
        ("plain", load(&beam, "beam")),
        ("viscous", load(&viscous, "beam viscous")),
        ("far_tool", load(&tool, "beam with a far tool")),
    ]
}

fn simulation(scene: &Scene, backend: Backend) -> Simulation {
    let mut sim = Simulation::new(scene, backend, SimOptions::default()).expect("simulation");
    sim.advance(STEPS).expect("warm-up");
    sim
}

fn skips(c: &mut Criterion) {
    let mut group = c.benchmark_group("skips");
    group
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3));
    for backend in backends() {
        for (label, scene) in variants() {
            let mut sim = simulation(&scene, backend);
            let name = if backend == Backend::Gpu {
                "gpu"
            } else {
                "cpu"
            };
            group.bench_function(BenchmarkId::new(name, label), |b| {
                b.iter(|| sim.advance(STEPS).expect("batch"))
            });
        }
    }
    group.finish();
}

fn ratio_table() {
    println!("\nskips: µs per step (median of 15 batches of {STEPS}, same run), beam 15,360 tets");
    println!("| backend | plain | viscous | viscous / plain | far tool | far tool / plain |");
    println!("|---|---:|---:|---:|---:|---:|");
    for backend in backends() {
        let t: Vec<f64> = variants()
            .iter()
            .map(|(_, scene)| {
                let mut sim = simulation(scene, backend);
                median(15, || {
                    sim.advance(STEPS).expect("batch");
                }) / STEPS as f64
                    * 1e6
            })
            .collect();
        let name = match backend {
            Backend::Gpu => "gpu",
            _ => "cpu (all threads)",
        };
        println!(
            "| {name} | {:.1} | {:.1} | {:.2} | {:.1} | {:.2} |",
            t[0],
            t[1],
            t[1] / t[0],
            t[2],
            t[2] / t[0]
        );
    }
}

criterion_group!(benches, skips);

fn main() {
    benches();
    ratio_table();
    criterion::Criterion::default()
        .configure_from_args()
        .final_summary();
}
