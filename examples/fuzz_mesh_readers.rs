//! Mutation fuzzer for the mesh readers, for runs longer than the test's.
//!
//!     cargo run --release --example fuzz_mesh_readers -- [ITERATIONS] [SEED]
//!
//! Each iteration reads one mutated copy of every fixture in tests/fixtures/meshes (see
//! tests/mesh_io/fuzz.rs). Inputs that make a reader panic are saved under
//! `$TMPDIR/palpate-fuzz-mesh-readers/findings`; the exit status is 1 when there are any.
//! Run it under `ulimit -v` to turn an oversized allocation into a finding too.

#[path = "../tests/common/mod.rs"]
mod common;
#[path = "../tests/mesh_io/fuzz.rs"]
mod fuzz;

use std::path::Path;
use std::time::Instant;

fn main() {
    let mut args = std::env::args().skip(1);
    let iterations: u64 = args.next().and_then(|a| a.parse().ok()).unwrap_or(1000);
    let seed: u64 = args.next().and_then(|a| a.parse().ok()).unwrap_or(1);
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/meshes");
    let scratch = std::env::temp_dir().join("palpate-fuzz-mesh-readers");
    // Panics are expected to be caught and reported below; keep their messages short.
    std::panic::set_hook(Box::new(|info| eprintln!("panic: {info}")));
    let start = Instant::now();
    let stats = fuzz::run(&fixtures, &scratch, iterations, seed);
    let secs = start.elapsed().as_secs_f64();
    println!(
        "{} executions in {secs:.1} s ({:.0}/s): {} errors, {} accepted, {} panics, {} bad messages; slowest read {:?} ({})",
        stats.executions,
        stats.executions as f64 / secs,
        stats.errors,
        stats.ok,
        stats.panics.len(),
        stats.bad_messages.len(),
        stats.slowest.0,
        stats.slowest.1
    );
    for (dir, what) in &stats.panics {
        println!("panic: {what} — input saved in {}", dir.display());
    }
    for m in stats.bad_messages.iter().take(20) {
        println!("bad message: {m}");
    }
    if !stats.panics.is_empty() || !stats.bad_messages.is_empty() {
        std::process::exit(1);
    }
}
