//! One full FEM step (fem_forces + gather + integrate) at about 10k, 100k and 1M tets, on the
//! CPU reference path and the GPU path, as tet-steps per second. After the criterion groups,
//! a table with the GPU/CPU ratio measured in the same run is printed.
//!
//! GPU steps are recorded 20 to a command buffer (as the engine runs them) and the time
//! includes submit and wait; the CPU path is the single-thread reference twin.

use criterion::{criterion_group, BenchmarkId, Criterion, Throughput};
use palpate::cpu::CpuStepper;
use palpate::gpu::{GpuContext, GpuStepper};
use palpate::material::MaterialParams;
use palpate::mesh::generators;
use palpate::model::Model;
use std::sync::Arc;
use std::time::{Duration, Instant};

const SIZES: [(&str, [usize; 3]); 3] = [
    ("10k", [25, 8, 8]),
    ("100k", [50, 18, 18]),
    ("1M", [100, 40, 42]),
];
const GPU_BATCH: u32 = 20;

fn model(cells: [usize; 3]) -> Arc<Model> {
    let mesh = generators::beam([0.1, 0.04, 0.04], cells);
    let fixed: Vec<bool> = mesh.positions.iter().map(|p| p.x == 0.0).collect();
    let material = MaterialParams::elastic(3.0e5, 0.4, 1000.0);
    Arc::new(Model::new(&mesh, &fixed, material, [0.0, 0.0, -9.81]))
}

fn fem_step(c: &mut Criterion) {
    let ctx = Arc::new(
        GpuContext::new()
            .expect("a GPU adapter (apt-get install mesa-vulkan-drivers for lavapipe)"),
    );
    let mut group = c.benchmark_group("fem_step");
    group
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(4));
    for (name, cells) in SIZES {
        let m = model(cells);
        let params = m.step_params(0.5 * m.bounds.dt_bound, 0.0);
        group.throughput(Throughput::Elements(m.n_tets() as u64));
        let mut cpu = CpuStepper::new(m.clone(), params);
        group.bench_function(BenchmarkId::new("cpu", name), |b| {
            b.iter(|| cpu.step(false))
        });
        let mut gpu = GpuStepper::new(ctx.clone(), &m, params).expect("GPU stepper");
        group.throughput(Throughput::Elements(m.n_tets() as u64 * GPU_BATCH as u64));
        group.bench_function(BenchmarkId::new(format!("gpu_x{GPU_BATCH}"), name), |b| {
            b.iter(|| gpu.run_no_readback(GPU_BATCH).expect("GPU batch"))
        });
    }
    group.finish();
}

/// Best of `reps` timings of `f`, seconds.
fn best(reps: usize, mut f: impl FnMut()) -> f64 {
    (0..reps)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

fn ratio_table() {
    let ctx = Arc::new(GpuContext::new().expect("GPU adapter"));
    println!(
        "\nfem_step on '{}' vs CPU reference (1 thread)",
        ctx.describe()
    );
    println!("| tets | CPU tet-steps/s | GPU tet-steps/s | GPU/CPU |");
    println!("|---:|---:|---:|---:|");
    let mut stages: Vec<(usize, Option<palpate::gpu::stepper::StageTimes>)> = Vec::new();
    for (_, cells) in SIZES {
        let m = model(cells);
        let params = m.step_params(0.5 * m.bounds.dt_bound, 0.0);
        let mut cpu = CpuStepper::new(m.clone(), params);
        let t_cpu = best(5, || cpu.step(false));
        let mut gpu = GpuStepper::new(ctx.clone(), &m, params).expect("GPU stepper");
        gpu.run_no_readback(GPU_BATCH).expect("warm-up");
        let t_gpu =
            best(5, || gpu.run_no_readback(GPU_BATCH).expect("GPU batch")) / GPU_BATCH as f64;
        let n = m.n_tets() as f64;
        println!(
            "| {} | {:.3e} | {:.3e} | {:.2} |",
            m.n_tets(),
            n / t_cpu,
            n / t_gpu,
            t_cpu / t_gpu
        );
        stages.push((m.n_tets(), gpu.profile_stages(20).expect("profile")));
    }
    println!("\nGPU time per stage (timestamp queries, mean of 20 steps, one pass per stage):");
    println!("| tets | fem_forces µs | gather µs | integrate µs | reduce µs |");
    println!("|---:|---:|---:|---:|---:|");
    for (n, t) in stages {
        match t {
            Some(t) => println!(
                "| {n} | {:.1} | {:.1} | {:.1} | {:.1} |",
                t.fem_forces_ns / 1e3,
                t.gather_ns / 1e3,
                t.integrate_ns / 1e3,
                t.reduce_ns / 1e3
            ),
            None => println!("| {n} | no timestamp queries on this adapter | | | |"),
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
