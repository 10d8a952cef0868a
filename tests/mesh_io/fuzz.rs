//! A deterministic mutation fuzzer for the mesh readers, shared by `tests/mesh_io.rs` (a
//! short run) and `examples/fuzz_mesh_readers.rs` (long runs).
//!
//! Each execution copies the files of one fixture mesh into a scratch folder, mutates one of
//! them (bit flips, byte writes, truncation, deleted or duplicated spans, numbers replaced by
//! huge, negative or non-finite values, inserted garbage) and reads it with
//! `palpate::mesh::io::read` inside `catch_unwind`. A panic is a finding: its input is saved.
//! Randomness comes from the shared test PRNG (`tests/common`), so runs are reproducible.
#![allow(dead_code)]

use crate::common::Rng;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Integers and bytes from the shared test PRNG.
trait Draw {
    /// Uniform in 0..n (n > 0).
    fn below(&mut self, n: usize) -> usize;
    /// A uniform byte.
    fn byte(&mut self) -> u8;
}

impl Draw for Rng {
    fn below(&mut self, n: usize) -> usize {
        (self.next() * n.max(1) as f64) as usize
    }

    fn byte(&mut self) -> u8 {
        (self.next() * 256.0) as u8
    }
}

/// Replacement numbers that stress count and index handling.
const NASTY: [&str; 16] = [
    "0",
    "-1",
    "1000000000000",
    "18446744073709551615",
    "9223372036854775807",
    "-9223372036854775808",
    "4294967295",
    "4294967296",
    "2147483648",
    "NaN",
    "inf",
    "-inf",
    "1e308",
    "1e-320",
    "3.5",
    "",
];

/// Apply 1 to 4 random mutations to `data`.
pub fn mutate(rng: &mut Rng, data: &[u8]) -> Vec<u8> {
    let mut d = data.to_vec();
    for _ in 0..1 + rng.below(4) {
        let n = d.len();
        match rng.below(9) {
            0 if n > 0 => {
                let i = rng.below(n);
                d[i] ^= 1 << rng.below(8);
            }
            1 if n > 0 => {
                let i = rng.below(n);
                d[i] = rng.byte();
            }
            2 => d.truncate(rng.below(n + 1)),
            3 if n > 0 => {
                let a = rng.below(n);
                let b = (a + 1 + rng.below(64)).min(n);
                d.drain(a..b);
            }
            4 if n > 0 => {
                let a = rng.below(n);
                let b = (a + 1 + rng.below(256)).min(n);
                let span = d[a..b].to_vec();
                let at = rng.below(n + 1);
                d.splice(at..at, span);
            }
            5..=7 => replace_number(rng, &mut d),
            _ => {
                let at = rng.below(n + 1);
                let junk: Vec<u8> = (0..1 + rng.below(16)).map(|_| rng.byte()).collect();
                d.splice(at..at, junk);
            }
        }
    }
    d
}

/// Replace a random number token (a run of digits, signs, dots, 'e') by a nasty value.
fn replace_number(rng: &mut Rng, d: &mut Vec<u8>) {
    let n = d.len();
    if n == 0 {
        return;
    }
    let start = rng.below(n);
    let Some(k) = d[start..].iter().position(u8::is_ascii_digit) else {
        return;
    };
    let is_num = |b: &u8| b.is_ascii_digit() || b"+-.eE".contains(b);
    let mut a = start + k;
    while a > 0 && is_num(&d[a - 1]) {
        a -= 1;
    }
    let mut b = start + k;
    while b < n && is_num(&d[b]) {
        b += 1;
    }
    let with = NASTY[rng.below(NASTY.len())].as_bytes().to_vec();
    d.splice(a..b, with);
}

/// One fixture mesh: its files (all copied, one mutated per execution) and the file to read.
pub struct Target {
    /// Files making up the mesh.
    pub files: Vec<PathBuf>,
    /// Index in `files` of the path passed to `read`.
    pub read: usize,
}

/// The fixtures in `dir`: every file a reader takes, grouped with its siblings.
pub fn targets(dir: &Path) -> Vec<Target> {
    let mut names: Vec<PathBuf> = std::fs::read_dir(dir)
        .expect("fixture folder")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    names.sort();
    let ext = |p: &Path| {
        p.extension()
            .and_then(|e| e.to_str())
            .unwrap_or("")
            .to_string()
    };
    let mut out = Vec::new();
    for p in &names {
        match ext(p).as_str() {
            "msh" | "vtk" | "vtu" => out.push(Target {
                files: vec![p.clone()],
                read: 0,
            }),
            "node" => out.push(Target {
                files: vec![p.clone(), p.with_extension("ele")],
                read: 0,
            }),
            "pts" => {
                let mut files = vec![p.clone(), p.with_extension("elem")];
                if p.with_extension("lon").exists() {
                    files.push(p.with_extension("lon"));
                }
                out.push(Target { files, read: 1 });
            }
            _ => {}
        }
    }
    out
}

/// What a fuzzing run found.
#[derive(Default, Debug)]
pub struct Stats {
    /// Reads performed.
    pub executions: u64,
    /// Reads that returned Ok (a mutation the format tolerates, e.g. in a comment).
    pub ok: u64,
    /// Reads that returned Err.
    pub errors: u64,
    /// Saved inputs that made a reader panic, with the panic message.
    pub panics: Vec<(PathBuf, String)>,
    /// Errors whose message is not one line or does not name the file.
    pub bad_messages: Vec<String>,
    /// The slowest read and its input.
    pub slowest: (Duration, String),
}

/// Run `iterations` mutated reads per fixture in `fixtures`, using `scratch` for inputs and
/// saving panicking inputs under `scratch/findings`.
pub fn run(fixtures: &Path, scratch: &Path, iterations: u64, seed: u64) -> Stats {
    let targets = targets(fixtures);
    let mut stats = Stats::default();
    let mut rng = Rng(seed | 1);
    let work = scratch.join("work");
    std::fs::create_dir_all(&work).expect("scratch folder");
    let originals: Vec<Vec<Vec<u8>>> = targets
        .iter()
        .map(|t| {
            t.files
                .iter()
                .map(|f| std::fs::read(f).expect("fixture"))
                .collect()
        })
        .collect();
    for it in 0..iterations {
        for (t, target) in targets.iter().enumerate() {
            let victim = rng.below(target.files.len());
            let paths: Vec<PathBuf> = target
                .files
                .iter()
                .map(|f| work.join(f.file_name().expect("file name")))
                .collect();
            let mut mutated = Vec::new();
            for (k, p) in paths.iter().enumerate() {
                let bytes = if k == victim {
                    mutated = mutate(&mut rng, &originals[t][k]);
                    &mutated
                } else {
                    &originals[t][k]
                };
                std::fs::write(p, bytes).expect("write input");
            }
            let path = &paths[target.read];
            let start = Instant::now();
            let result = std::panic::catch_unwind(|| palpate::mesh::io::read(path));
            let took = start.elapsed();
            stats.executions += 1;
            let label = format!("{} (iteration {it})", paths[victim].display());
            if took > stats.slowest.0 {
                stats.slowest = (took, label.clone());
            }
            match result {
                Ok(Ok(_)) => stats.ok += 1,
                Ok(Err(e)) => {
                    stats.errors += 1;
                    let msg = e.to_string();
                    let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("");
                    if msg.contains('\n') || !msg.contains(stem) {
                        stats.bad_messages.push(format!("{label}: {msg}"));
                    }
                }
                Err(panic) => {
                    let what = panic
                        .downcast_ref::<String>()
                        .cloned()
                        .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                        .unwrap_or_default();
                    let dir = scratch.join("findings").join(format!("{it}-{t}"));
                    std::fs::create_dir_all(&dir).expect("findings folder");
                    for (k, p) in paths.iter().enumerate() {
                        let bytes = if k == victim {
                            &mutated
                        } else {
                            &originals[t][k]
                        };
                        std::fs::write(dir.join(p.file_name().expect("name")), bytes)
                            .expect("save finding");
                    }
                    stats.panics.push((dir, what));
                }
            }
        }
    }
    stats
}
