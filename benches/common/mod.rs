//! Helpers shared by the benches' same-run ratio tables.

use std::time::Instant;

/// Median of `reps` wall-clock timings of `f`, seconds.
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
