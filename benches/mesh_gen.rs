//! Generation of the idealised LV at ~1M tets (resolution 22: 96·22³ = 1,022,208 tets),
//! alone and with validation + boundary + stats as `palpate mesh` does; peak memory printed.

use criterion::{criterion_group, Criterion};
use palpate::mesh::generators::{lv, LvGeometry};
use std::time::Duration;

fn peak_rss_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .map(|l| l.to_string())
        })
        .and_then(|l| {
            l.split_whitespace()
                .nth(1)
                .and_then(|k| k.parse::<f64>().ok())
        })
        .map(|kib| kib / 1024.0)
        .unwrap_or(f64::NAN)
}

fn mesh_gen(c: &mut Criterion) {
    let mut g = c.benchmark_group("mesh_gen");
    g.sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(15));
    g.bench_function("lv_1M_generate", |b| {
        b.iter(|| lv(LvGeometry::default(), 22, 88))
    });
    g.bench_function("lv_1M_generate_validate", |b| {
        b.iter(|| {
            let mut m = lv(LvGeometry::default(), 22, 88);
            m.validate("bench").expect("valid");
            m.boundary_faces().len()
        })
    });
    g.finish();
    println!(
        "peak resident memory after the 1M-tet LV benchmarks: {:.0} MiB",
        peak_rss_mib()
    );
}

criterion_group!(benches, mesh_gen);

fn main() {
    benches();
    criterion::Criterion::default()
        .configure_from_args()
        .final_summary();
}
