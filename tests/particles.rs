//! The particle layer: sampling and embedding, and its GPU kernels against their CPU twins
//! (prefix sum, neighbour build).

mod common;

use common::{gpu, Rng};
use palpate::cpu;
use palpate::gpu::buffers::{BufferGroup, BufferSpec, GpuBuffers, Usage};
use palpate::gpu::groups::ScanParams;
use palpate::gpu::setup::{read_u32, run_passes, SetupDispatch, SetupPass};
use palpate::model::Model;
use palpate::particles::params::GridParams;
use palpate::Scene;

/// A 20 × 10 × 10 mm block, every tet in the particle zone, particles every `spacing` m.
pub fn block_scene(spacing: f64, extra: &str) -> Scene {
    let text = format!(
        "[mesh]\ngenerator = \"beam\"\nsize = [0.02, 0.01, 0.01]\ncells = [4, 2, 2]\n\n[material]\nyoungs_modulus = 3.0e4\npoisson_ratio = 0.3\ndensity = 1000.0\n\n[[fixed]]\nplane = {{ normal = [1.0, 0.0, 0.0], offset = 0.0 }}\n\n[particles]\nregion = 0\nspacing = {spacing}\nactivation_radius = 0.004\n{extra}\n"
    );
    Scene::from_toml(&text, "particle block", "block", None).unwrap()
}

#[test]
fn sampling_fills_the_zone_with_embedded_particles_of_the_right_volume_and_mass() {
    let scene = block_scene(1e-3, "");
    let m = Model::from_scene(&scene);
    let p = m.particles.as_ref().unwrap();
    assert_eq!(
        p.len(),
        20 * 10 * 10,
        "a 1 mm lattice in a 20x10x10 mm block"
    );
    let zone_volume = scene.mesh.volume();
    assert!(
        ((p.len() as f64 * p.volume as f64) - zone_volume).abs() <= 1e-6 * zone_volume,
        "volumes add up to the zone"
    );
    assert!((p.mass - 1000.0 * p.volume).abs() <= 1e-6 * p.mass);
    // The zone's mass is carried once: vertex masses sum to the body's mass.
    let total: f64 = m.mass.iter().map(|&x| x as f64).sum();
    assert!(
        (total - 1000.0 * zone_volume).abs() <= 1e-5 * total,
        "mass {total} vs {}",
        1000.0 * zone_volume
    );
    // Each particle is inside its host, and the embedding reproduces its rest position.
    for k in 0..p.len() {
        let w = &p.weights[4 * k..4 * k + 4];
        assert!(w.iter().all(|&c| c >= -1e-6), "particle {k}: weights {w:?}");
        assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        let t = scene.mesh.tets[p.host[k] as usize];
        let x: glam::DVec3 = (0..4)
            .map(|c| scene.mesh.positions[t[c] as usize] * w[c] as f64)
            .sum();
        let d = (x.as_vec3() - p.rest_position(k)).length();
        assert!(d <= 1e-7, "particle {k}: embedding misses by {d} m");
    }
    // Particles are grouped by host, and the tet CSR says so.
    for e in 0..scene.mesh.n_tets() {
        for k in p.tet_offsets[e]..p.tet_offsets[e + 1] {
            assert_eq!(p.host[k as usize] as usize, e);
        }
    }
    // The outer lattice layer is the contact surface: 2000 − 18·8·8 interior particles.
    let surface = p.contact_area.iter().filter(|&&a| a > 0.0).count();
    assert_eq!(surface, 2000 - 18 * 8 * 8);
}

#[test]
fn prefix_sum_kernel_matches_its_twin() {
    let ctx = gpu();
    let mut rng = Rng(3);
    for n in [1u32, 255, 256, 257, 70_001] {
        let data: Vec<u32> = (0..n).map(|_| (rng.next() * 100.0) as u32).collect();
        let params = [ScanParams::new(n)];
        let buffers = GpuBuffers::new(
            &ctx,
            &[BufferGroup {
                name: "scan test",
                specs: vec![
                    BufferSpec::data("scan_params", Usage::Uniform, &params),
                    BufferSpec::data("scan_data", Usage::Storage, &data),
                    BufferSpec::zeroed("scan_blocks", Usage::Storage, ScanParams::blocks_bytes(n)),
                ],
            }],
        )
        .unwrap();
        let pass = |entry, dispatch| SetupPass {
            file: "scan",
            entry,
            dispatch,
            aliases: &[],
        };
        run_passes(
            &ctx,
            &buffers,
            &[
                pass("scan_local", SetupDispatch::Items(n)),
                pass("scan_totals", SetupDispatch::One),
                pass("scan_apply", SetupDispatch::Items(n)),
            ],
        )
        .unwrap();
        let got = read_u32(&ctx, buffers.require("scan_data").unwrap(), 0, n as u64).unwrap();
        let nb = cpu::scan::n_blocks(n as usize) as u64;
        let total = read_u32(&ctx, buffers.require("scan_blocks").unwrap(), 4 * nb, 1).unwrap()[0];
        let mut want = data.clone();
        let want_total = cpu::scan::exclusive_scan(n as usize, &mut want);
        assert_eq!(got, want, "n = {n}");
        assert_eq!(total, want_total, "n = {n}");
        assert_eq!(total, data.iter().sum::<u32>());
    }
}

#[test]
fn neighbour_lists_built_on_the_gpu_equal_the_cpu_twin() {
    let scene = block_scene(1e-3, "");
    let m = Model::from_scene(&scene);
    let p = m.particles.as_ref().unwrap();
    let grid = GridParams::over(&p.rest, p.support);
    let cpu_lists = cpu::neighbours::build(&grid, &p.rest);
    let ctx = gpu();
    let scans = [
        ScanParams::new(grid.n_cells + 1),
        ScanParams::new(grid.n_particles + 1),
    ];
    let mut buffers =
        GpuBuffers::new(&ctx, &[palpate::gpu::groups::particles(p, &grid, &scans)]).unwrap();
    let total = palpate::gpu::setup::build_neighbour_lists(&ctx, &mut buffers, &grid).unwrap();
    let n = p.len() as u64;
    let offsets = read_u32(
        &ctx,
        buffers.require("neighbour_offsets").unwrap(),
        0,
        n + 1,
    )
    .unwrap();
    let lists = read_u32(
        &ctx,
        buffers.require("neighbours").unwrap(),
        0,
        total as u64,
    )
    .unwrap();
    assert_eq!(offsets, cpu_lists.neighbour_offsets);
    assert_eq!(lists, cpu_lists.neighbours);
    // An interior particle of the 1 mm lattice sees every lattice point within 2.4 mm.
    let interior = (0..p.len())
        .map(|k| offsets[k + 1] - offsets[k])
        .max()
        .unwrap();
    let lattice = (-3i32..=3)
        .flat_map(|i| (-3i32..=3).flat_map(move |j| (-3i32..=3).map(move |k| (i, j, k))))
        .filter(|&(i, j, k)| {
            (i * i + j * j + k * k) as f64 <= 2.4f64 * 2.4 && (i, j, k) != (0, 0, 0)
        })
        .count() as u32;
    assert_eq!(interior, lattice, "full neighbourhood");
    eprintln!(
        "{} particles, {total} neighbour entries, {interior} for an interior particle",
        p.len()
    );
}
