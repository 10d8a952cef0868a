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

/// The backends `PALPATE_BENCH_BACKENDS` (`cpu`, `gpu` or both, comma-separated, any case,
/// spaces ignored; default both) asks for. An unknown name stops the bench with a message
/// (it used to time no backend and print a table of dashes).
#[allow(dead_code)] // not every bench that includes this module uses it
pub fn backends() -> Vec<palpate::sim::Backend> {
    use palpate::sim::Backend;
    let want: Vec<String> = std::env::var("PALPATE_BENCH_BACKENDS")
        .unwrap_or_default()
        .split(',')
        .map(|w| w.trim().to_ascii_lowercase())
        .filter(|w| !w.is_empty())
        .collect();
    if let Some(bad) = want.iter().find(|w| !matches!(w.as_str(), "cpu" | "gpu")) {
        panic!(
            "PALPATE_BENCH_BACKENDS: unknown backend {bad:?} (cpu, gpu, or both comma-separated)"
        );
    }
    [(Backend::Cpu, "cpu"), (Backend::Gpu, "gpu")]
        .into_iter()
        .filter(|(_, n)| want.is_empty() || want.iter().any(|w| w == n))
        .map(|(b, _)| b)
        .collect()
}
