//! Helpers shared by the integration tests.
#![allow(dead_code)]

use glam::DVec3;
use palpate::material::MaterialParams;
use palpate::mesh::{generators, TetMesh};
use palpate::model::Model;
use std::sync::Arc;

/// Small deterministic PRNG (xorshift64*), uniform in [0, 1).
pub struct Rng(pub u64);

impl Rng {
    pub fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545F4914F6CDD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Uniform in [-1, 1).
    pub fn sym(&mut self) -> f64 {
        2.0 * self.next() - 1.0
    }
    pub fn vec(&mut self) -> DVec3 {
        DVec3::new(self.sym(), self.sym(), self.sym())
    }
}

/// A soft-tissue material, SI.
pub fn tissue() -> MaterialParams {
    MaterialParams::elastic(3.0e5, 0.4, 1000.0)
}

/// A beam mesh with interior vertices jittered by up to 15 % of a cell, so that tets are
/// not all alike.
pub fn jittered_beam(cells: [usize; 3], seed: u64) -> TetMesh {
    let size = [0.03, 0.02, 0.02];
    let mut mesh = generators::beam(size, cells);
    let h = size[0] / cells[0] as f64;
    let mut rng = Rng(seed);
    let boundary = mesh.boundary_vertices();
    for (i, p) in mesh.positions.iter_mut().enumerate() {
        if boundary.binary_search(&(i as u32)).is_err() {
            *p += rng.vec() * 0.15 * h;
        }
    }
    mesh.validate("jittered beam").expect("valid jittered mesh");
    mesh
}

/// A model with no fixed vertex and no gravity.
pub fn free_model(mesh: &TetMesh, material: MaterialParams) -> Arc<Model> {
    Arc::new(Model::new(
        mesh,
        &vec![false; mesh.n_vertices()],
        material,
        [0.0; 3],
    ))
}

/// max |a − b| / max |b|.
pub fn rel_err(a: &[f32], b: &[f32]) -> f64 {
    assert_eq!(a.len(), b.len());
    let num = a
        .iter()
        .zip(b)
        .map(|(x, y)| (*x as f64 - *y as f64).abs())
        .fold(0.0, f64::max);
    let den = b.iter().map(|y| (*y as f64).abs()).fold(0.0, f64::max);
    num / den.max(f64::MIN_POSITIVE)
}

/// One batch's end of a coupled run: vertex displacements, particle displacements and the
/// tool's force.
pub type RunPoint<'a> = (&'a [f32], &'a [f32], DVec3);

/// How far run `b` is from run `a`, batch by batch: (vertices, particles, tool force), each
/// as the largest difference over the largest value `a` reaches over the whole run (floored
/// at f64::MIN_POSITIVE, and 1e-30 N for the force, so a run at rest stays finite); and that
/// force scale.
pub fn run_offsets(a: &[RunPoint], b: &[RunPoint]) -> (Vec<[f64; 3]>, f64) {
    let largest = |x: &[f32]| x.iter().fold(0.0f64, |m, &v| m.max((v as f64).abs()));
    let off = |x: &[f32], y: &[f32]| {
        x.iter()
            .zip(y)
            .fold(0.0f64, |m, (&p, &q)| m.max((p as f64 - q as f64).abs()))
    };
    let scale_u = a
        .iter()
        .map(|s| largest(s.0))
        .fold(f64::MIN_POSITIVE, f64::max);
    let scale_p = a
        .iter()
        .map(|s| largest(s.1))
        .fold(f64::MIN_POSITIVE, f64::max);
    let scale_f = a.iter().map(|s| s.2.length()).fold(1e-30, f64::max);
    let offsets = a
        .iter()
        .zip(b)
        .map(|(aa, bb)| {
            [
                off(bb.0, aa.0) / scale_u,
                off(bb.1, aa.1) / scale_p,
                (bb.2 - aa.2).length() / scale_f,
            ]
        })
        .collect();
    (offsets, scale_f)
}

/// The test binary's GPU context ([`open_gpu`]).
///
/// Every test of a binary shares one device (opened on first use, never torn down before the
/// process ends): on an NVIDIA H200 (driver 580.159.04) `gpu_vs_cpu` on 8 test threads, each
/// opening and dropping its own device, hung in 6 of 10 runs on 2026-11-27 and in 4 of 8 and
/// 4 of 6 on 2026-11-28 with one instance per process. `PALPATE_TEST_DEVICE=per-test` gives
/// each call a device of its own, as before (to compare). A test may then find another test's
/// uncaptured GPU error when it checks; the error names the thread, so the test, that raised it
/// (`GpuContext::check_errors`, tests/gpu_errors.rs).
pub fn gpu() -> Arc<palpate::gpu::GpuContext> {
    static SHARED: std::sync::Mutex<Option<Arc<palpate::gpu::GpuContext>>> =
        std::sync::Mutex::new(None);
    if std::env::var("PALPATE_TEST_DEVICE").is_ok_and(|v| v == "per-test") {
        return open_gpu();
    }
    let mut shared = SHARED.lock().unwrap_or_else(|p| p.into_inner());
    shared.get_or_insert_with(open_gpu).clone()
}

/// A new GPU context, or a failure that says how to get a software adapter.
fn open_gpu() -> Arc<palpate::gpu::GpuContext> {
    palpate::gpu::GpuContext::new().map(Arc::new).unwrap_or_else(|e| {
        panic!("GPU tests need an adapter: {e}. On Debian/Ubuntu install the software Vulkan adapter with `sudo apt-get install -y mesa-vulkan-drivers` (lavapipe), or set PALPATE_BACKEND=gl to use llvmpipe through EGL.")
    })
}

/// The values of a binary (base64, UInt64 header) point-data array `name` of a `.vtu` file
/// palpate wrote, as f32.
pub fn vtu_point_vectors(text: &str, name: &str) -> Vec<f32> {
    let tag = format!("Name=\"{name}\"");
    let start = text.find(&tag).unwrap_or_else(|| panic!("no array {name}"));
    let body_start = start + text[start..].find('>').unwrap() + 1;
    let body_end = body_start + text[body_start..].find('<').unwrap();
    let bytes = base64_decode(text[body_start..body_end].trim());
    bytes[8..]
        .chunks(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

fn base64_decode(s: &str) -> Vec<u8> {
    const B64: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let val = |c: u8| B64.iter().position(|&b| b == c).map(|v| v as u32);
    let mut out = Vec::new();
    for chunk in s.as_bytes().chunks(4) {
        let v: Vec<u32> = chunk.iter().filter_map(|&c| val(c)).collect();
        let n = v
            .iter()
            .enumerate()
            .fold(0u32, |a, (i, x)| a | x << (18 - 6 * i));
        for k in 0..v.len().saturating_sub(1) {
            out.push((n >> (16 - 8 * k)) as u8);
        }
    }
    out
}

/// One batch of `steps` steps of `dt` from time `t`, the tool moving along its path over it;
/// the batch's report.
pub fn batch_along_path(
    s: &mut dyn palpate::stepper::Stepper,
    tool: &palpate::scene::Tool,
    t: f64,
    steps: u32,
    dt: f64,
) -> palpate::stepper::BatchReport {
    let (a, b) = (tool.position_at(t), tool.position_at(t + steps as f64 * dt));
    s.submit(steps, &palpate::stepper::BatchInput::moving(a, b))
        .unwrap();
    s.wait().unwrap()
}
