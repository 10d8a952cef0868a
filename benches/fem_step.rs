//! One full FEM step (the step plan: fem_forces + gather + integrate) at about 10k, 100k and
//! 1M tets, as tet-steps per second, on the CPU path with 1 thread, the CPU path with all
//! threads, and the GPU path. After the criterion groups, a table with the ratios measured
//! in the same run is printed (the parallel CPU speed-up and GPU/CPU), then per-stage GPU
//! times from timestamp queries.
//!
//! GPU steps are recorded 20 to a command buffer (as the engine runs them) and the time
//! includes submit and wait. `PALPATE_BENCH_SIZES=10k,100k` limits the sizes and
//! `PALPATE_BENCH_BACKENDS=cpu` (or `gpu`) the backends (the table's other columns are `-`).

mod common;

use common::{backends, median};
use criterion::{criterion_group, BenchmarkId, Criterion, Throughput};
use palpate::cpu::stepper::available_cores;
use palpate::cpu::CpuStepper;
use palpate::gpu::{GpuContext, GpuStepper};
use palpate::material::MaterialParams;
use palpate::mesh::generators;
use palpate::model::Model;
use palpate::sim::Backend;
use std::sync::Arc;
use std::time::Duration;

const SIZES: [(&str, [usize; 3]); 3] = [
    ("10k", [25, 8, 8]),
    ("100k", [50, 18, 18]),
    ("1M", [100, 40, 42]),
];
const GPU_BATCH: u32 = 20;

fn sizes() -> Vec<(&'static str, [usize; 3])> {
    let want = std::env::var("PALPATE_BENCH_SIZES").unwrap_or_default();
    SIZES
        .into_iter()
        .filter(|(n, _)| want.is_empty() || want.split(',').any(|w| w == *n))
        .collect()
}

fn model(cells: [usize; 3]) -> Arc<Model> {
    let mesh = generators::beam([0.1, 0.04, 0.04], cells);
    let fixed: Vec<bool> = mesh.positions.iter().map(|p| p.x == 0.0).collect();
    let material = MaterialParams::elastic(3.0e5, 0.4, 1000.0);
    Arc::new(Model::new(&mesh, &fixed, material, [0.0, 0.0, -9.81]))
}

fn cpu(m: &Arc<Model>, threads: usize) -> CpuStepper {
    let params = m.step_params(0.5 * m.bounds.dt_bound, 0.0);
    CpuStepper::with_threads(m.clone(), params, threads).expect("CPU threads")
}

/// The GPU context when `PALPATE_BENCH_BACKENDS` asks for the GPU.
fn gpu_context() -> Option<Arc<GpuContext>> {
    backends().contains(&Backend::Gpu).then(|| {
        Arc::new(
            GpuContext::new()
                .expect("a GPU adapter (apt-get install mesa-vulkan-drivers for lavapipe, or PALPATE_BENCH_BACKENDS=cpu)"),
        )
    })
}

/// The CPU thread counts to time: 1 and all cores, none when `PALPATE_BENCH_BACKENDS` leaves
/// the CPU out.
fn cpu_threads() -> Vec<usize> {
    if backends().contains(&Backend::Cpu) {
        vec![1, available_cores()]
    } else {
        Vec::new()
    }
}

fn fem_step(c: &mut Criterion) {
    let ctx = gpu_context();
    let mut group = c.benchmark_group("fem_step");
    group
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(4));
    for (name, cells) in sizes() {
        let m = model(cells);
        let params = m.step_params(0.5 * m.bounds.dt_bound, 0.0);
        group.throughput(Throughput::Elements(m.n_tets() as u64));
        for threads in cpu_threads() {
            let mut s = cpu(&m, threads);
            group.bench_function(BenchmarkId::new(format!("cpu_{threads}t"), name), |b| {
                b.iter(|| s.step(false))
            });
        }
        if let Some(ctx) = &ctx {
            let mut gpu = GpuStepper::new(ctx.clone(), &m, params).expect("GPU stepper");
            group.throughput(Throughput::Elements(m.n_tets() as u64 * GPU_BATCH as u64));
            group.bench_function(BenchmarkId::new(format!("gpu_x{GPU_BATCH}"), name), |b| {
                b.iter(|| gpu.run_no_readback(GPU_BATCH).expect("GPU batch"))
            });
        }
    }
    group.finish();
}

fn ratio_table() {
    let ctx = gpu_context();
    let threads = cpu_threads();
    let all = available_cores();
    println!(
        "\nfem_step: CPU 1 thread, CPU {all} threads and GPU '{}' (median of 15, same run; - where PALPATE_BENCH_BACKENDS left a backend out)",
        ctx.as_ref().map_or("-".to_string(), |c| c.describe())
    );
    println!(
        "| tets | CPU 1t tet-steps/s | CPU {all}t tet-steps/s | {all}t/1t | GPU tet-steps/s | GPU/CPU 1t | GPU/CPU {all}t |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|");
    let mut stages = Vec::new();
    let cell = |v: Option<f64>, precision: usize| {
        v.map_or("-".to_string(), |v| {
            if precision == 0 {
                format!("{v:.3e}")
            } else {
                format!("{v:.2}")
            }
        })
    };
    for (_, cells) in sizes() {
        let m = model(cells);
        let params = m.step_params(0.5 * m.bounds.dt_bound, 0.0);
        let (mut t1, mut tn) = (None, None);
        if !threads.is_empty() {
            // Warm up past the first steps from rest (first-touch page faults), then time
            // each pool on its own with the other idle.
            let mut one = cpu(&m, 1);
            let mut many = cpu(&m, all);
            for _ in 0..10 {
                one.step(false);
                many.step(false);
            }
            t1 = Some(median(15, || one.step(false)));
            std::thread::sleep(Duration::from_millis(200));
            tn = Some(median(15, || many.step(false)));
        }
        let mut tg = None;
        if let Some(ctx) = &ctx {
            let mut gpu = GpuStepper::new(ctx.clone(), &m, params).expect("GPU stepper");
            // Warm up for a second, not one batch: a real GPU idles at a low clock after the
            // CPU rows (an NVIDIA H200 read 345 MHz idle; its 1M row gave 1.4e9 tet-steps/s
            // after one warm-up batch against criterion's 4.7e9, 2026-11-27).
            let warm = std::time::Instant::now();
            while warm.elapsed() < Duration::from_secs(1) {
                gpu.run_no_readback(GPU_BATCH).expect("warm-up");
            }
            tg = Some(
                median(9, || gpu.run_no_readback(GPU_BATCH).expect("GPU batch")) / GPU_BATCH as f64,
            );
            stages.push((m.n_tets(), gpu.profile_stages(20).expect("profile")));
        }
        let n = m.n_tets() as f64;
        let ratio = |a: Option<f64>, b: Option<f64>| a.zip(b).map(|(a, b)| a / b);
        println!(
            "| {} | {} | {} | {} | {} | {} | {} |",
            m.n_tets(),
            cell(t1.map(|t| n / t), 0),
            cell(tn.map(|t| n / t), 0),
            cell(ratio(t1, tn), 2),
            cell(tg.map(|t| n / t), 0),
            cell(ratio(t1, tg), 2),
            cell(ratio(tn, tg), 2)
        );
    }
    if ctx.is_none() {
        return;
    }
    println!("\nGPU time per stage (timestamp queries, mean of 20 runs, one pass per stage):");
    for (n, t) in stages {
        match t {
            Some(t) => {
                let cols: Vec<String> = t
                    .per_stage
                    .iter()
                    .map(|(s, ns)| format!("{} {:.1} µs", s.name(), ns / 1e3))
                    .collect();
                println!("| {n} | {} |", cols.join(" | "));
            }
            None => println!("| {n} | no timestamp queries on this adapter |"),
        }
    }
}

criterion_group!(benches, fem_step);

fn main() {
    benches();
    ratio_table();
    criterion::Criterion::default()
        .configure_from_args()
        .final_summary();
}
