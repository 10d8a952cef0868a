//! Helpers shared by the benches' same-run ratio tables.

use std::time::Instant;

/// Median of `reps` wall-clock timings of `f`, seconds.
#[allow(dead_code)] // not every bench that includes this module uses it
pub fn median(reps: usize, mut f: impl FnMut()) -> f64 {
    let mut t: Vec<f64> = (0..reps)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[reps / 2]
}

/// The backends `PALPATE_BENCH_BACKENDS` (`cpu`, `gpu` or both, comma-separated; default
/// both) asks for.
#[allow(dead_code)] // not every bench that includes this module uses it
pub fn backends() -> Vec<palpate::sim::Backend> {
    use palpate::sim::Backend;
    let want = std::env::var("PALPATE_BENCH_BACKENDS").unwrap_or_default();
    [(Backend::Cpu, "cpu"), (Backend::Gpu, "gpu")]
        .into_iter()
        .filter(|(_, n)| want.is_empty() || want.split(',').any(|w| w == *n))
        .map(|(b, _)| b)
        .collect()
}
