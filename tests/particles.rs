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

/// A zone of two small tets 3 m apart at 1 mm spacing: few particles, but a neighbour grid
/// of about 2e9 cells over their bounding box (it would wrap a u32 cell count). Sampling
/// refuses it with an error naming the spacing; a compact zone's grid is counted exactly.
#[test]
fn a_particle_zone_too_spread_out_for_its_grid_is_an_error_naming_the_spacing() {
    let tet = |o: DVec3| {
        [
            o,
            o + DVec3::new(0.01, 0.0, 0.0),
            o + DVec3::new(0.0, 0.01, 0.0),
            o + DVec3::new(0.0, 0.0, 0.01),
        ]
    };
    let positions: Vec<DVec3> = tet(DVec3::ZERO)
        .into_iter()
        .chain(tet(DVec3::splat(3.0)))
        .collect();
    let (mesh, _) = palpate::mesh::TetMesh::new(
        "two tets",
        positions,
        vec![[0, 1, 2, 3], [4, 5, 6, 7]],
        None,
    )
    .unwrap();
    let settings = block_scene(1e-3, "").particles.unwrap();
    let err = palpate::particles::Particles::sample(&mesh, &settings, 1000.0, "two tets")
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("particles.spacing") && err.contains("cells") && !err.contains('\n'),
        "{err}"
    );
    // The compact block: the grid spans its lattice plus about a cell of margin on each side.
    let m = Model::from_scene(&block_scene(1e-3, ""));
    let p = m.particles.as_ref().unwrap();
    let (grid, cells) = GridParams::layout(&p.rest, p.support);
    assert_eq!(cells, grid.n_cells as u64);
    assert!(
        grid.dims.iter().all(|&d| (5..=14).contains(&d)),
        "{:?}",
        grid.dims
    );
}

#[test]
fn prefix_sum_kernel_matches_its_twin() {
    // The twin's blocks are the kernel's runs: one constant on each side, kept equal.
    let source = palpate::gpu::kernel_source("scan").unwrap();
    let run = format!("const RUN: u32 = {}u;", cpu::scan::SCAN_BLOCK);
    assert!(source.contains(&run), "scan.wgsl must say `{run}`");
    let ctx = gpu();
    let mut rng = Rng(3);
    // Run (64 values) and run-total (256 runs per scan_totals round) boundaries.
    for n in [1u32, 63, 64, 65, 255, 256, 257, 16_384, 16_385, 70_001] {
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
                pass("scan_local", SetupDispatch::Items(cpu::scan::n_runs(n))),
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

use glam::DVec3;
use palpate::cpu::activate::ParticleStatic;
use palpate::gpu::stepper::Stage;
use palpate::gpu::GpuStepper;
use palpate::particles::params::mode;
use palpate::stepper::{BatchInput, Stepper};
use std::sync::Arc;

const KERNEL_TOL: f64 = 1e-5;

/// The tolerance of `sph_forces` against its twin. Each particle's force is a sum over its
/// neighbours of pair terms V²(A_a + A_b)∇W that nearly cancel (the net force is a difference
/// of stresses across one spacing), so the rounding of the terms, which WGSL lets a GPU fuse
/// into FMAs, shows in the net force magnified by the cancellation. Measured 2026-11-27: ≤ 1e-7
/// on lavapipe (LLVM rounds as the Rust twin does), 2.45e-5 and 1.70e-5 on an NVIDIA H200
/// (Vulkan, driver 580.159.04) where the other particle kernels agree to ≤ 3.5e-7.
const SPH_FORCES_TOL: f64 = 1e-4;

/// A 20 x 20 x 10 mm block on a fixed bottom, all of it particle zone (1 mm lattice), with a
/// 3 mm tool pressing its top centre.
const PRESSED_BLOCK: &str = "name = \"hybrid block\"\n[mesh]\ngenerator = \"beam\"\nsize = [0.02, 0.02, 0.01]\ncells = [4, 4, 2]\n[material]\nyoungs_modulus = 3.0e4\npoisson_ratio = 0.3\ndensity = 1000.0\n[[fixed]]\nplane = { normal = [0.0, 0.0, 1.0], offset = 0.0 }\n[particles]\nregion = 0\nspacing = 0.001\nactivation_radius = 0.003\n[tool]\nradius = 0.003\nstiffness = 1.0e8\npath = [[0.0, 0.01, 0.01, 0.0135], [0.02, 0.01, 0.01, 0.0120]]\n[solver]\ndamping = 50.0\n";

/// The [`PRESSED_BLOCK`] scene (its automatic core step needs 2 particle sub-steps).
fn pressed_block() -> Scene {
    Scene::from_toml(PRESSED_BLOCK, "hybrid block", "hybrid_block", None).unwrap()
}

/// The [`PRESSED_BLOCK`] with viscosity φ = 2, ψ = 5 Pa·s and `particles` (TOML lines) added
/// to its `[particles]`.
fn viscous_pressed_block(particles: &str) -> Scene {
    let text = PRESSED_BLOCK
        .replace(
            "density = 1000.0\n",
            "density = 1000.0\nviscosity = [2.0, 5.0]\n",
        )
        .replace(
            "spacing = 0.001\n",
            &format!("spacing = 0.001\n{particles}"),
        );
    Scene::from_toml(&text, "viscous block", "viscous_block", None).unwrap()
}

/// The [`PRESSED_BLOCK`] model and its step parameters (half the stable step, damping 50/s).
fn pressed_block_model() -> (Arc<Model>, palpate::params::StepParams) {
    let m = Arc::new(Model::from_scene(&pressed_block()));
    let params = m.step_params(0.5 * m.bounds.dt_bound, 50.0);
    (m, params)
}

/// The tool's press into the [`PRESSED_BLOCK`]: from 3.5 mm above its top face to 1.8 mm.
fn press_segment() -> (DVec3, DVec3) {
    (
        DVec3::new(0.01, 0.01, 0.0135),
        DVec3::new(0.01, 0.01, 0.0118),
    )
}

/// The tool's path over the [`PRESSED_BLOCK`] in four legs of `per_leg` batches each: the
/// press, a hold, a 1 cm withdrawal and a wait.
fn press_hold_withdraw_wait(per_leg: u32) -> Vec<BatchInput> {
    let (a, b) = press_segment();
    let up = a + DVec3::new(0.0, 0.0, 0.01);
    [(a, b), (b, b), (b, up), (up, up)]
        .into_iter()
        .flat_map(|(from, to)| {
            let at = move |j: u32| from + (to - from) * (j as f64 / per_leg as f64);
            (0..per_leg).map(move |j| BatchInput::moving(at(j), at(j + 1)))
        })
        .collect()
}

/// Assert that `a` and `b` hold the same bits in each buffer of `names` (`when` says at
/// which point).
fn assert_same_buffers(a: &GpuStepper, b: &GpuStepper, names: &[&str], when: &str) {
    for name in names {
        assert_eq!(bits_u32(a, name), bits_u32(b, name), "{name} {when}");
    }
}

/// The bit patterns of f32 values (for bit-for-bit comparisons).
fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn bits_u32(g: &GpuStepper, name: &str) -> Vec<u32> {
    bits(&g.read_f32(name).unwrap())
}

/// The xyz of the particles of `list`, in list order.
fn on_particles(list: &[u32], x: &[f32]) -> Vec<f32> {
    list.iter()
        .flat_map(|&p| (0..3).map(move |k| x[3 * p as usize + k]))
        .collect()
}

fn rel(a: &[f32], b: &[f32]) -> f64 {
    common::rel_err(a, b)
}

/// The vertex arrays `cpu::activate::relump` writes besides the velocities.
struct Relumped {
    mass: Vec<f32>,
    inv_mass: Vec<f32>,
    flags: Vec<u32>,
    contact_weight: Vec<f32>,
}

/// The CPU relump of `m`'s vertices from these particle modes and velocities, fixed-vertex
/// flags and tet weights; `velocities` (the vertices') are updated in place.
#[allow(clippy::too_many_arguments)]
fn cpu_relump(
    m: &Model,
    params: &palpate::params::StepParams,
    pp: &palpate::particles::params::ParticleParams,
    particle_mode: &[u32],
    particle_velocities: &[f32],
    node_fixed: &[u32],
    tet_weight: &[f32],
    velocities: &mut [f32],
) -> Relumped {
    let pd = m.particles.as_ref().unwrap();
    let nv = m.n_vertices();
    let mut out = Relumped {
        mass: vec![0.0; nv],
        inv_mass: vec![0.0; nv],
        flags: vec![0; nv],
        contact_weight: vec![0.0; nv],
    };
    cpu::activate::relump(
        params,
        &cpu::activate::RelumpInputs {
            pp,
            slot_offsets: &pd.slot_offsets,
            slots: &pd.slots,
            weights: &pd.weights,
            particle_mode,
            particle_velocities,
            particle_rest: &pd.rest,
            rest: &m.rest,
            core_mass: &pd.core_mass,
            node_fixed,
            incidence_offsets: &m.incidence_offsets,
            incidence: &m.incidence,
            tet_weight,
        },
        &mut out.mass,
        &mut out.inv_mass,
        velocities,
        &mut out.flags,
        &mut out.contact_weight,
    );
    out
}

/// The activate stage's inputs and outputs, as the GPU stepper's buffers hold them.
struct ActivateIo {
    u: Vec<f32>,
    v: Vec<f32>,
    pu: Vec<f32>,
    pv: Vec<f32>,
    pmode: Vec<u32>,
    ptimer: Vec<f32>,
    poffset: Vec<f32>,
}

impl ActivateIo {
    fn read(g: &GpuStepper) -> ActivateIo {
        ActivateIo {
            u: g.read_f32("displacements").unwrap(),
            v: g.read_f32("velocities").unwrap(),
            pu: g.read_f32("particle_displacements").unwrap(),
            pv: g.read_f32("particle_velocities").unwrap(),
            pmode: bits_u32(g, "particle_mode"),
            ptimer: g.read_f32("particle_timer").unwrap(),
            poffset: g.read_f32("particle_offset").unwrap(),
        }
    }

    /// The CPU mode machine (`cpu::activate::activate`) on these arrays.
    fn run_twin(
        &mut self,
        pp: &palpate::particles::params::ParticleParams,
        tp: &palpate::contact::ToolParams,
        state: &palpate::contact::ToolState,
        st: &ParticleStatic,
    ) {
        let inp = cpu::activate::ModeInputs::new(pp, tp, state, true, st, &self.u, &self.v);
        cpu::activate::activate(
            &inp,
            cpu::activate::ModeArrays {
                displacements: &mut self.pu,
                velocities: &mut self.pv,
                mode: &mut self.pmode,
                timer: &mut self.ptimer,
                offset: &mut self.poffset,
            },
        );
    }
}

#[test]
fn particle_kernels_match_their_cpu_twins() {
    let (m, params) = pressed_block_model();
    check_particle_kernels(m, params);
}

/// The same with a viscous material: `follow` gives the embedded particles their host's
/// velocity and `sph_stress` adds the strain-rate stress F·S_v from the particles'
/// velocities, on both backends; the viscous part must matter in the compared stress.
#[test]
fn viscous_particle_kernels_match_their_cpu_twins() {
    let scene = viscous_pressed_block("");
    let m = Arc::new(Model::from_scene(&scene));
    assert!(m.fem_variant().viscous);
    let params = m.step_params(0.5 * m.bounds.dt_bound, 50.0);
    check_particle_kernels(m, params);
}

/// tlsph's viscous stress is the tets': every particle of a viscous block (each one, to the
/// surface, by the corrected kernel gradients) given the velocity field v = L X at rest gets
/// P = φ tr(sym L) I + 2ψ sym L, what `fem_forces` gives a tet (`viscous_stress` at F = I);
/// a rigid spin (L antisymmetric) gives none.
#[test]
fn the_particle_viscous_stress_is_the_tets_under_a_uniform_velocity_gradient() {
    let scene = viscous_pressed_block("");
    let m = Model::from_scene(&scene);
    let params = m.step_params(0.5 * m.bounds.dt_bound, 0.0);
    let pd = m.particles.as_ref().unwrap();
    let pp = m.particle_params(&params).unwrap();
    let n = pd.len();
    let lists = cpu::neighbours::build(&GridParams::over(&pd.rest, pd.support), &pd.rest);
    let (noff, nbrs) = (&lists.neighbour_offsets, &lists.neighbours);
    let mut correction = vec![0.0f32; 9 * n];
    cpu::sph_setup::sph_setup(&pp, &pd.rest, noff, nbrs, &mut correction);
    let all: Vec<u32> = (0..n as u32).collect();
    // The one-walk sum of displacements and velocities is each one's own sum, bit for bit.
    let mut rng = Rng(7);
    let (a, b): (Vec<f32>, Vec<f32>) = (0..3 * n)
        .map(|_| (rng.sym() as f32, rng.sym() as f32))
        .unzip();
    for p in (0..n).step_by(37) {
        let one = |x: &[f32]| cpu::sph_setup::gradient_sum(&pp, &pd.rest, x, noff, nbrs, None, p);
        assert_eq!(
            cpu::sph_setup::gradient_sums(&pp, &pd.rest, [&a[..], &b[..]], noff, nbrs, None, p),
            [one(&a), one(&b)],
            "particle {p}"
        );
    }
    let mut paper_correction = vec![0.0f32; 9 * n];
    let paper = palpate::particles::params::ParticleParams { model: 1, ..pp };
    cpu::sph_setup::sph_setup(&paper, &pd.rest, noff, nbrs, &mut paper_correction);
    let stress_for = |l: glam::Mat3, pp: &palpate::particles::params::ParticleParams| {
        let correction = if pp.model == 1 {
            &paper_correction
        } else {
            &correction
        };
        let mut v = vec![0.0f32; 3 * n];
        for p in 0..n {
            let x = glam::Vec3::from_slice(&pd.rest[3 * p..3 * p + 3]);
            v[3 * p..3 * p + 3].copy_from_slice(&(l * x).to_array());
        }
        let (mut stress, mut grad, mut energy) =
            (vec![0.0f32; 9 * n], vec![0.0f32; 9 * n], vec![0.0f32; n]);
        cpu::sph_stress::sph_stress(
            &params,
            pp,
            m.material.model,
            &all,
            &pd.rest,
            &vec![0.0f32; 3 * n],
            Some(&v),
            noff,
            nbrs,
            correction,
            None,
            &mut stress,
            &mut grad,
            &mut energy,
        );
        // P = A G⁻ᵀ per particle.
        (0..n)
            .map(|p| {
                let a = glam::Mat3::from_cols_slice(&stress[9 * p..9 * p + 9]);
                let g = glam::Mat3::from_cols_slice(&correction[9 * p..9 * p + 9]);
                a * g.transpose().inverse()
            })
            .collect::<Vec<_>>()
    };
    // A stretch rate with shear (1/s).
    let l = glam::Mat3::from_cols_array(&[2.0, 0.5, -0.3, 0.1, -1.0, 0.4, 0.2, 0.7, 0.5]);
    let expected = cpu::fem_forces::viscous_stress(&params, glam::Mat3::IDENTITY, l);
    let scale = expected
        .abs()
        .to_cols_array()
        .into_iter()
        .fold(0.0f32, f32::max);
    assert!(scale > 1.0, "the expected viscous stress is {scale} Pa");
    let worst = stress_for(l, &pp)
        .iter()
        .map(|p| {
            (*p - expected)
                .abs()
                .to_cols_array()
                .into_iter()
                .fold(0.0f32, f32::max)
        })
        .fold(0.0f32, f32::max);
    eprintln!("viscous stress under v = L X: worst error {worst:.2e} Pa of {scale:.2e} Pa");
    assert!(
        worst <= 1e-4 * scale,
        "worst error {worst:.2e} Pa of {scale:.2e}"
    );
    // A rigid spin about an axis through the block: no strain rate, no viscous stress.
    let spin = glam::Mat3::from_cols_array(&[0.0, 3.0, -1.0, -3.0, 0.0, 2.0, 1.0, -2.0, 0.0]);
    let worst = stress_for(spin, &pp)
        .iter()
        .map(|p| p.abs().to_cols_array().into_iter().fold(0.0f32, f32::max))
        .fold(0.0f32, f32::max);
    eprintln!("viscous stress under a rigid spin: worst {worst:.2e} Pa");
    assert!(worst <= 1e-4 * scale, "a rigid spin gives {worst:.2e} Pa");
    // The paper model: eq. (3)–(4) on the rate of its strain FᵀF − I, 2 sym L at rest, so
    // twice the tets' S_v there.
    let worst = stress_for(l, &paper)
        .iter()
        .map(|p| {
            (*p - expected * 2.0)
                .abs()
                .to_cols_array()
                .into_iter()
                .fold(0.0f32, f32::max)
        })
        .fold(0.0f32, f32::max);
    eprintln!(
        "paper model under v = L X: worst error {worst:.2e} Pa of {:.2e} Pa",
        2.0 * scale
    );
    assert!(
        worst <= 2e-4 * scale,
        "paper model: worst error {worst:.2e} Pa"
    );
}

/// The same for the paper's particle model, whose viscous stress is eq. (3)–(4) on its own
/// strain's rate.
#[test]
fn viscous_paper_particle_kernels_match_their_cpu_twins() {
    let scene = viscous_pressed_block("model = \"paper\"\n");
    let m = Arc::new(Model::from_scene(&scene));
    assert_eq!(
        m.particle_params(&m.step_params(1e-5, 0.0)).unwrap().model,
        1
    );
    let params = m.step_params(0.5 * m.bounds.dt_bound, 50.0);
    check_particle_kernels(m, params);
}

/// A viscous pressed block's 300 steps agree between the backends (the CPU stepper's wiring
/// of the velocities: a side that left the viscous stress out would part from the other),
/// the viscosity changes the trajectory well beyond that agreement, and the GPU's fused
/// passes (`fem_forces_follow`, `contact_sph_stress`) hold the bits of the plain ones.
#[test]
fn a_viscous_hybrid_trajectory_matches_between_backends_and_fused_passes() {
    let scene = viscous_pressed_block("");
    let (c, _) = run_batches(&scene, palpate::sim::Backend::Cpu, None, 3, 100);
    let (g, _) = run_batches(&scene, palpate::sim::Backend::Gpu, None, 3, 100);
    backends_agree("viscous: ", &c, &g);
    // The elastic block at the viscous one's step (viscosity shortens the automatic step).
    let m = Arc::new(Model::from_scene(&scene));
    let dt = scene.solver.safety * m.bounds.dt_bound;
    let (elastic, _) = run_batches(
        &pressed_block(),
        palpate::sim::Backend::Cpu,
        Some(dt),
        3,
        100,
    );
    let (last_v, last_e) = (&c[c.len() - 1].1, &elastic[elastic.len() - 1].1);
    let e = rel(last_v, last_e);
    eprintln!("viscous against elastic particle displacements after 300 steps: {e:.2e}");
    assert!(
        e > 1e-2,
        "the viscosity moved the particles by only {e:.2e}"
    );
    let k = m.particles.as_ref().unwrap().settings.activation_interval;
    let (dynamic, _) = fused_against_plain(&m, m.step_params(0.5 * m.bounds.dt_bound, 50.0), k, 3);
    assert!(dynamic > 10, "the press woke {dynamic} particles");
}

/// Every particle kernel against its CPU twin on `m`'s pressed block (see
/// [`particle_kernels_match_their_cpu_twins`]).
fn check_particle_kernels(m: Arc<Model>, params: palpate::params::StepParams) {
    let viscous = m.fem_variant().viscous;
    let pd = m.particles.as_ref().unwrap();
    let pp = m.particle_params(&params).unwrap();
    let mut g = GpuStepper::new(gpu(), &m, params).unwrap();
    // Press for 60 steps so that particles are dynamic, stressed and touching.
    let (a, b) = press_segment();
    g.submit(60, &BatchInput::moving(a, b)).unwrap();
    g.wait().unwrap();
    let grid = GridParams::over(&pd.rest, pd.support);
    let lists = cpu::neighbours::build(&grid, &pd.rest);
    let (noff, nbrs) = (&lists.neighbour_offsets, &lists.neighbours);
    let st = ParticleStatic::of(&m).unwrap();
    let n = pd.len();
    let tp = m.tool_params();
    let tool_input = palpate::contact::batch_input(a, b, 60);
    let tool_state: palpate::contact::ToolState = *bytemuck::from_bytes(bytemuck::cast_slice(
        &g.read_f32("tool_state").unwrap()[..4],
    ));

    // activate (mode machine, sets, compaction, tet weights, relump)
    let mut io = ActivateIo::read(&g);
    let node_fixed = bits_u32(&g, "node_fixed");
    g.run_stage(Stage::Activate).unwrap();
    io.run_twin(&pp, &tp, &tool_state, &st);
    let ActivateIo {
        u,
        mut v,
        mut pu,
        pv,
        mut pmode,
        mut ptimer,
        poffset,
    } = io;
    cpu::activate::mark_set(n, mode::DYNAMIC, mode::IN_S, noff, nbrs, &mut pmode);
    cpu::activate::mark_set(n, mode::IN_S, mode::IN_F, noff, nbrs, &mut pmode);
    let (mut dl, mut sl, mut fl) = (Vec::new(), Vec::new(), Vec::new());
    let (mut counts, mut dispatch) = ([0u32; 4], [0u32; 9]);
    cpu::compact::compact(
        &pmode,
        &mut dl,
        &mut sl,
        &mut fl,
        &mut counts,
        &mut dispatch,
    );
    let mut tw = vec![0.0f32; m.n_tets()];
    cpu::activate::tet_weights(&params, &pd.tet_offsets, &pmode, &mut tw);
    let Relumped {
        mass,
        inv_mass,
        flags,
        contact_weight: cw,
    } = cpu_relump(&m, &params, &pp, &pmode, &pv, &node_fixed, &tw, &mut v);
    assert_eq!(bits_u32(&g, "particle_mode")[..n], pmode[..], "modes");
    assert!(
        counts[0] >= 20 && counts[1] > counts[0] && counts[2] > counts[1],
        "{counts:?}"
    );
    assert_eq!(&bits_u32(&g, "particle_counts")[..4], &counts[..]);
    assert_eq!(&bits_u32(&g, "particle_dispatch")[..9], &dispatch[..]);
    // The fourth grid (the fused contact + sph_stress dispatch's): the larger of S's and the
    // tool's surface's.
    let items = counts[1].max(tp.n_surface);
    let (x, y) = cpu::compact::grid(items.div_ceil(cpu::compact::PARTICLE_WORKGROUP));
    assert_eq!(&bits_u32(&g, "particle_dispatch")[9..12], &[x, y, 1]);
    assert_eq!(&bits_u32(&g, "dynamic_list")[..dl.len()], &dl[..]);
    assert_eq!(&bits_u32(&g, "stress_list")[..sl.len()], &sl[..]);
    assert_eq!(&bits_u32(&g, "force_list")[..fl.len()], &fl[..]);
    assert_eq!(&bits_u32(&g, "node_flags")[..flags.len()], &flags[..]);
    for (name, gpu_v, cpu_v) in [
        (
            "particle_displacements",
            g.read_f32("particle_displacements").unwrap(),
            pu.clone(),
        ),
        (
            "particle_velocities",
            g.read_f32("particle_velocities").unwrap(),
            pv.clone(),
        ),
        ("tet_weight", g.read_f32("tet_weight").unwrap(), tw.clone()),
        ("mass", g.read_f32("mass").unwrap(), mass.clone()),
        (
            "inv_mass",
            g.read_f32("inv_mass").unwrap(),
            inv_mass.clone(),
        ),
        ("velocities", g.read_f32("velocities").unwrap(), v.clone()),
        (
            "contact_weight",
            g.read_f32("contact_weight").unwrap(),
            cw.clone(),
        ),
    ] {
        let e = rel(&gpu_v[..cpu_v.len()], &cpu_v);
        eprintln!("activate: {name} rel err {e:.2e}");
        assert!(e <= KERNEL_TOL, "activate: {name} rel err {e:.2e}");
    }
    eprintln!(
        "activate: dynamic {}, stress {}, force {}",
        counts[0], counts[1], counts[2]
    );

    // follow, with every third embedded particle of the force set blending back (timers
    // spread over the blend time, offsets of a few spacings' thousandths): the kernel fades
    // their offsets and advances their blend clocks by a sub-step, as the twin does.
    let mut poffset = poffset;
    let mut blending = 0;
    for (j, &q) in fl.iter().enumerate() {
        let q = q as usize;
        if pmode[q] & (mode::DYNAMIC | mode::PINNED) == 0 && j % 3 == 0 {
            pmode[q] |= mode::BLENDING;
            ptimer[q] = pp.blend * (j % 7) as f32 / 8.0;
            for (c, o) in poffset[3 * q..3 * q + 3].iter_mut().enumerate() {
                *o = 1e-3 * pp.spacing * (1.0 + c as f32 + (j % 5) as f32);
            }
            blending += 1;
        }
    }
    assert!(
        blending > 10,
        "only {blending} blending particles to follow"
    );
    g.write_f32("particle_mode", bytemuck::cast_slice(&pmode))
        .unwrap();
    g.write_f32("particle_timer", &ptimer).unwrap();
    g.write_f32("particle_offset", &poffset).unwrap();
    g.run_stage(Stage::Follow).unwrap();
    let timers_before = ptimer.clone();
    let mut pv_follow = pv.clone();
    cpu::follow::follow(
        &pp,
        &fl,
        &pmode,
        &st,
        &u,
        &mut ptimer,
        &poffset,
        &mut pu,
        viscous.then_some((&v[..], &mut pv_follow[..])),
    );
    if viscous {
        // The embedded particles of F took their host's velocity (less a fading offset's
        // rate): on both backends alike, and not what they had.
        let moved = fl
            .iter()
            .filter(|&&q| pmode[q as usize] & mode::DYNAMIC == 0)
            .filter(|&&q| {
                let q = q as usize;
                pv_follow[3 * q..3 * q + 3] != pv[3 * q..3 * q + 3]
            })
            .count();
        assert!(moved > 10, "follow set only {moved} embedded velocities");
        let e = rel(
            &g.read_f32("particle_velocities").unwrap()[..pv_follow.len()],
            &pv_follow,
        );
        eprintln!("follow: particle_velocities rel err {e:.2e}");
        assert!(
            e <= KERNEL_TOL,
            "follow: particle_velocities rel err {e:.2e}"
        );
    }
    assert!(
        ptimer
            .iter()
            .zip(&timers_before)
            .filter(|(a, b)| a != b)
            .count()
            == blending,
        "the blend clocks of the blending particles advance, no others"
    );
    let e = rel(
        &g.read_f32("particle_displacements").unwrap()[..pu.len()],
        &pu,
    );
    assert!(e <= KERNEL_TOL, "follow rel err {e:.2e}");
    let timers = g.read_f32("particle_timer").unwrap();
    assert_eq!(
        bits(&timers[..ptimer.len()]),
        bits(&ptimer),
        "follow: blend clocks"
    );

    // sph_stress (from the GPU's displacements, to test the kernel alone)
    let pu = g.read_f32("particle_displacements").unwrap();
    let corr = g.read_f32("particle_correction").unwrap();
    let mut ccorr = vec![0.0f32; 9 * n];
    cpu::sph_setup::sph_setup(&pp, &pd.rest, noff, nbrs, &mut ccorr);
    let e = rel(&corr[..9 * n], &ccorr);
    eprintln!("sph_setup: rel err {e:.2e}");
    assert!(e <= KERNEL_TOL, "sph_setup rel err {e:.2e}");
    g.run_stage(Stage::SphStress).unwrap();
    // The CPU path caches rest-state pair quantities; the cache must not change a bit.
    let pairs = cpu::sph::PairTable::new(&pp, &pd.rest, noff, nbrs);
    let pv_gpu = g.read_f32("particle_velocities").unwrap();
    let stress_of = |pairs: Option<&cpu::sph::PairTable>, velocities: Option<&[f32]>| {
        let (mut stress, mut grad, mut energy) =
            (vec![0.0f32; 9 * n], vec![0.0f32; 9 * n], vec![0.0f32; n]);
        cpu::sph_stress::sph_stress(
            &params,
            &pp,
            m.material.model,
            &sl,
            &pd.rest,
            &pu,
            velocities,
            noff,
            nbrs,
            &corr,
            pairs,
            &mut stress,
            &mut grad,
            &mut energy,
        );
        (stress, grad, energy)
    };
    let stress_with =
        |pairs: Option<&cpu::sph::PairTable>| stress_of(pairs, viscous.then_some(&pv_gpu[..]));
    let (stress, grad, energy) = stress_with(Some(&pairs));
    if viscous {
        // The viscous part is well above the tolerance the backends are held to.
        let (elastic, _, _) = stress_of(Some(&pairs), None);
        let e = rel(&on_list9(&sl, &elastic), &on_list9(&sl, &stress));
        eprintln!("sph_stress: the viscous part, relative to the whole: {e:.2e}");
        assert!(e > 100.0 * KERNEL_TOL, "the viscous stress is only {e:.2e}");
    }
    assert!(
        stress_with(None) == (stress.clone(), grad.clone(), energy.clone()),
        "sph_stress with the pair cache differs from without it"
    );
    for (name, c) in [
        ("particle_stress", &stress),
        ("particle_gradient", &grad),
        ("particle_energy", &energy),
    ] {
        let gv = g.read_f32(name).unwrap();
        let idx: Vec<usize> = if name == "particle_energy" {
            sl.iter().map(|&p| p as usize).collect()
        } else {
            sl.iter()
                .flat_map(|&p| (0..9).map(move |k| 9 * p as usize + k))
                .collect()
        };
        let (a, b): (Vec<f32>, Vec<f32>) = idx.iter().map(|&i| (gv[i], c[i])).unzip();
        let e = rel(&a, &b);
        eprintln!("sph_stress: {name} rel err {e:.2e}");
        assert!(e <= KERNEL_TOL, "sph_stress: {name} rel err {e:.2e}");
    }

    // sph_forces
    let gstress = g.read_f32("particle_stress").unwrap();
    let ggrad = g.read_f32("particle_gradient").unwrap();
    let pv = g.read_f32("particle_velocities").unwrap();
    g.run_stage(Stage::SphForces).unwrap();
    let inp = cpu::sph_forces::ForceInputs {
        params: &params,
        pp: &pp,
        tool: Some((&tp, &tool_input, &tool_state)),
        mode: &pmode,
        rest: &pd.rest,
        displacements: &pu,
        velocities: &pv,
        neighbour_offsets: noff,
        neighbours: nbrs,
        stress: &gstress,
        gradient: &ggrad,
        area: &pd.contact_area,
        contact_offset: &pd.contact_offset,
        pairs: Some(&pairs),
    };
    let forces_of = |inp: &cpu::sph_forces::ForceInputs| {
        let (mut f, mut fs, mut fc) = (
            vec![0.0f32; 3 * n],
            vec![0.0f32; 3 * n],
            vec![0.0f32; 3 * n],
        );
        cpu::sph_forces::sph_forces(inp, &fl, false, &mut f, &mut fs, &mut fc);
        (f, fs, fc)
    };
    let (f, fs, fc) = forces_of(&inp);
    let uncached = cpu::sph_forces::ForceInputs { pairs: None, ..inp };
    assert!(
        forces_of(&uncached) == (f.clone(), fs.clone(), fc.clone()),
        "sph_forces with the pair cache differs from without it"
    );
    let touching = fl
        .iter()
        .filter(|&&p| fc[3 * p as usize + 2] != 0.0)
        .count();
    assert!(touching > 0, "no particle touches the tool");
    for (name, c) in [
        ("particle_forces", &f),
        ("particle_force_sum", &fs),
        ("particle_contact", &fc),
    ] {
        let gv = g.read_f32(name).unwrap();
        let idx: Vec<usize> = fl
            .iter()
            .flat_map(|&p| (0..3).map(move |k| 3 * p as usize + k))
            .collect();
        let (a, b): (Vec<f32>, Vec<f32>) = idx.iter().map(|&i| (gv[i], c[i])).unzip();
        let e = rel(&a, &b);
        eprintln!("sph_forces: {name} rel err {e:.2e} ({touching} particles touch the tool)");
        assert!(e <= SPH_FORCES_TOL, "sph_forces: {name} rel err {e:.2e}");
    }

    // integrate_particles
    let gf = g.read_f32("particle_forces").unwrap();
    let (mut pu2, mut pv2) = (pu.clone(), pv.clone());
    let mut status = vec![u32::MAX; 4];
    g.run_stage(Stage::IntegrateParticles).unwrap();
    cpu::integrate_particles::integrate_particles(
        &params,
        &pp,
        &dl,
        &gf,
        &mut pu2,
        &mut pv2,
        &mut status,
    );
    let e = rel(
        &g.read_f32("particle_displacements").unwrap()[..pu2.len()],
        &pu2,
    )
    .max(rel(
        &g.read_f32("particle_velocities").unwrap()[..pv2.len()],
        &pv2,
    ));
    eprintln!("integrate_particles: rel err {e:.2e}");
    assert!(e <= KERNEL_TOL, "integrate_particles rel err {e:.2e}");

    // gather_coupled: corner forces + m g + f_ext + the tool's contact + the SPH forces of
    // the non-dynamic particles of the force set, back to their host nodes (wᵢ·f).
    let corner = g.read_f32("corner_forces").unwrap();
    let mass = g.read_f32("mass").unwrap();
    let ext = g.read_f32("external_forces").unwrap();
    let contact = g.read_f32("contact_forces").unwrap();
    let force_sum = g.read_f32("particle_force_sum").unwrap();
    let weights = g.read_f32("particle_weights").unwrap();
    let (inc_off, inc) = (bits_u32(&g, "incidence_offsets"), bits_u32(&g, "incidence"));
    let surface_index = bits_u32(&g, "surface_index");
    let node_flags = bits_u32(&g, "node_flags");
    let (slot_off, slots) = (
        bits_u32(&g, "particle_slot_offsets"),
        bits_u32(&g, "particle_slots"),
    );
    let gmode = bits_u32(&g, "particle_mode");
    let coupled = (0..m.n_vertices())
        .filter(|&i| node_flags[i] & palpate::particles::params::NODE_COUPLED != 0)
        .filter(|&i| {
            (slot_off[i]..slot_off[i + 1]).any(|k| {
                let p = slots[k as usize] as usize / 4;
                gmode[p] & mode::IN_F != 0 && gmode[p] & mode::DYNAMIC == 0
            })
        })
        .count();
    assert!(coupled > 0, "no vertex receives particle forces");
    g.run_stage(Stage::GatherCoupled).unwrap();
    let mut forces = vec![0.0f32; 3 * m.n_vertices()];
    cpu::gather::gather_coupled(
        &params,
        &corner,
        &inc_off,
        &inc,
        &mass,
        &ext,
        &mut forces,
        &cpu::gather::Coupling {
            surface_index: &surface_index,
            contact_forces: &contact,
            contact: true,
            node_flags: &node_flags,
            slot_offsets: &slot_off,
            slots: &slots,
            weights: &weights,
            mode: &gmode,
            force_sum: &force_sum,
            particles: true,
        },
    );
    let e = rel(&g.read_f32("forces").unwrap()[..forces.len()], &forces);
    eprintln!("gather_coupled: rel err {e:.2e} ({coupled} vertices receive particle forces)");
    assert!(e <= KERNEL_TOL, "gather_coupled rel err {e:.2e}");
}

/// The 9 floats of each particle of `list` in `a`.
fn on_list9(list: &[u32], a: &[f32]) -> Vec<f32> {
    list.iter()
        .flat_map(|&p| a[9 * p as usize..9 * p as usize + 9].iter().copied())
        .collect()
}

/// A vertex with no mass left (every particle it hosts is dynamic) takes its particles'
/// velocity field at its rest place (`activate_relump`'s weighted least-squares fit): with
/// the particles of an all-dynamic block given a rigid spin, the kernel and its CPU twin give
/// every such vertex the spin's velocity there. The particles' mean velocity, the rule before,
/// is that of their weighted centroid, up to a third of a tet away: in a free spin such
/// vertices drifted 1.3 mm in 0.18 s while the body stayed within 0.27 mm.
#[test]
fn massless_vertices_take_their_particles_rigid_velocity_on_both_backends() {
    let scene = block_scene(0.001, "activation = \"all\"\nactivation_interval = 1\n");
    let m = Arc::new(Model::from_scene(&scene));
    let pd = m.particles.as_ref().unwrap();
    let params = m.step_params(0.5 * m.bounds.dt_bound, 0.0);
    let pp = m.particle_params(&params).unwrap();
    let g = GpuStepper::new(gpu(), &m, params).unwrap();
    // The first activation wakes every free particle at rest; then the particles spin.
    g.run_stage(Stage::Activate).unwrap();
    let omega = glam::Vec3::new(3.0, -2.0, 5.0);
    let centre = glam::Vec3::new(0.01, 0.005, 0.005);
    let spin = |x: glam::Vec3| omega.cross(x - centre);
    let pv: Vec<f32> = (0..pd.len())
        .flat_map(|p| spin(pd.rest_position(p)).to_array())
        .collect();
    g.write_f32("particle_velocities", &pv).unwrap();
    g.run_stage(Stage::Activate).unwrap();
    let gpu_v = g.read_f32("velocities").unwrap();
    let inv_mass = g.read_f32("inv_mass").unwrap();
    let pmode = bits_u32(&g, "particle_mode");
    let (nv, mut cpu_v) = (m.n_vertices(), vec![0.0f32; 3 * m.n_vertices()]);
    let cpu_inv = cpu_relump(
        &m,
        &params,
        &pp,
        &pmode,
        &g.read_f32("particle_velocities").unwrap(),
        &bits_u32(&g, "node_fixed"),
        &g.read_f32("tet_weight").unwrap(),
        &mut cpu_v,
    )
    .inv_mass;
    // The massless flag (−1) exactly, the masses to rounding (a GPU may fuse the lumping's
    // multiply-adds: 1 ulp apart on an NVIDIA H200, 2026-11-27).
    for (i, (&g, &c)) in inv_mass[..nv].iter().zip(&cpu_inv).enumerate() {
        assert!(
            (g < 0.0) == (c < 0.0) && (g - c).abs() <= 1e-6 * c.abs(),
            "inverse mass of vertex {i}: GPU {g:e}, CPU {c:e}"
        );
    }
    let speed = omega.length() * 0.012; // the spin's speed at the block's corners
    let (mut massless, mut worst, mut worst_mean) = (0, 0.0f32, 0.0f32);
    for i in (0..nv).filter(|&i| inv_mass[i] < 0.0) {
        massless += 1;
        let want = spin(glam::Vec3::from_slice(&m.rest[3 * i..3 * i + 3]));
        for (name, v) in [("GPU", &gpu_v), ("CPU", &cpu_v)] {
            let err = (glam::Vec3::from_slice(&v[3 * i..3 * i + 3]) - want).length();
            assert!(
                err.is_finite(),
                "{name}: vertex {i}'s velocity is not finite"
            );
            worst = worst.max(err);
        }
        // The mean over the hosted particles, weights w m_p, all dynamic here.
        let (mut b, mut sum) = (0.0f32, glam::Vec3::ZERO);
        for k in pd.slot_offsets[i]..pd.slot_offsets[i + 1] {
            let slot = pd.slots[k as usize] as usize;
            let w = pd.weights[slot];
            b += w;
            sum += glam::Vec3::from_slice(&pv[3 * (slot / 4)..3 * (slot / 4) + 3]) * w;
        }
        worst_mean = worst_mean.max((sum / b - want).length());
    }
    eprintln!(
        "{massless} massless vertices: largest error of the fitted velocity {:.1e}, of the mean {:.1e} (of the spin's largest speed)",
        worst / speed,
        worst_mean / speed
    );
    assert!(massless >= 10, "only {massless} massless vertices");
    assert!(
        worst <= 1e-4 * speed,
        "fitted velocity off by {worst:.2e} m/s"
    );
    assert!(
        worst_mean >= 0.05 * speed,
        "the mean was as good: {worst_mean:.2e} m/s"
    );
}

#[test]
fn hybrid_trajectory_300_steps_gpu_matches_cpu() {
    let scene = pressed_block();
    let (c, _) = run_batches(&scene, palpate::sim::Backend::Cpu, None, 3, 100);
    let (g, _) = run_batches(&scene, palpate::sim::Backend::Gpu, None, 3, 100);
    backends_agree("", &c, &g);
}

/// Snapshots of batches of 100 steps on the CPU (`c`) and the GPU (`g`) agree: the same
/// dynamic-particle counts (some), vertex and particle displacements and the tool force within
/// 1e-4 of the largest the CPU reaches over the whole trajectory (not of each snapshot's own:
/// before the tool touches, the CPU's block is exactly at rest, while a GPU that fuses the
/// force's multiply-adds moves it by rounding, 1e-11 m on an NVIDIA H200, 2026-11-27).
/// `label` prefixes the printed lines.
fn backends_agree(label: &str, c: &[Snapshot], g: &[Snapshot]) {
    fn points(r: &[Snapshot]) -> Vec<common::RunPoint<'_>> {
        r.iter().map(|s| (&s.0[..], &s.1[..], s.2)).collect()
    }
    let (offsets, _) = common::run_offsets(&points(c), &points(g));
    for (k, ((cc, gg), [eu, ep, ef])) in c.iter().zip(g).zip(offsets).enumerate() {
        eprintln!(
            "{label}step {}: {} dynamic particles, |F| {:.4e} N; rel err vertices {eu:.2e}, particles {ep:.2e}, tool force {ef:.2e}",
            100 * (k + 1),
            cc.3,
            cc.2.length()
        );
        assert_eq!(cc.3, gg.3, "dynamic particle counts");
        assert!(cc.3 > 0, "no particle became dynamic");
        assert!(
            eu <= 1e-4 && ep <= 1e-4 && ef <= 1e-4,
            "step {}",
            100 * (k + 1)
        );
    }
}

/// The CPU twin of `particle_reduce` on the GPU's current particle buffers and stress list:
/// (the partials of the list's blocks, stats).
fn particle_reduce_twin(
    g: &GpuStepper,
    pp: &palpate::particles::params::ParticleParams,
) -> (Vec<f32>, Vec<f32>) {
    let mut partials =
        vec![0.0f32; cpu::particle_reduce::LANE * cpu::particle_reduce::n_partials(pp)];
    let mut stats = vec![0.0f32; 8];
    let stress = bits_u32(g, "particle_counts")[1] as usize;
    let stress_list = bits_u32(g, "stress_list")[..stress].to_vec();
    cpu::particle_reduce::particle_reduce(
        pp,
        &stress_list,
        &bits_u32(g, "particle_mode"),
        &g.read_f32("particle_displacements").unwrap(),
        &g.read_f32("particle_velocities").unwrap(),
        &g.read_f32("particle_forces").unwrap(),
        &g.read_f32("particle_energy").unwrap(),
        &g.read_f32("particle_gradient").unwrap(),
        &mut partials,
        &mut stats,
    );
    let blocks = stress_list.len().div_ceil(cpu::particle_reduce::WORKGROUP);
    partials.truncate(cpu::particle_reduce::LANE * blocks);
    (partials, stats)
}

/// Compare the GPU's `particle_stats` and `particle_partials` with the twin's, per diagnostic.
fn check_particle_reduce(
    g: &GpuStepper,
    pp: &palpate::particles::params::ParticleParams,
    what: &str,
) -> Vec<f32> {
    let (partials, stats) = particle_reduce_twin(g, pp);
    let gstats = g.read_f32("particle_stats").unwrap();
    let gpartials = g.read_f32("particle_partials").unwrap();
    let names = [
        "kinetic",
        "elastic",
        "max speed",
        "sum |f|^2",
        "sum m|u|^2",
        "max stiffening",
    ];
    for (k, name) in names.iter().enumerate() {
        assert!(
            stats[k].is_finite() && stats[k] > 0.0,
            "{what}: {name} = {}",
            stats[k]
        );
        let e = rel(&gstats[k..k + 1], &stats[k..k + 1]);
        eprintln!(
            "particle_reduce ({what}): {name} gpu {:.6e} cpu {:.6e} rel err {e:.2e}",
            gstats[k], stats[k]
        );
        assert!(
            e <= KERNEL_TOL,
            "particle_reduce ({what}): {name} rel err {e:.2e}"
        );
        // Per block as well (each partial is a full 256-lane tree).
        let lane = cpu::particle_reduce::LANE;
        let (a, b): (Vec<f32>, Vec<f32>) = (0..partials.len() / lane)
            .map(|blk| (gpartials[lane * blk + k], partials[lane * blk + k]))
            .unzip();
        let e = rel(&a, &b);
        assert!(
            e <= KERNEL_TOL,
            "particle_reduce ({what}): {name} partials rel err {e:.2e}"
        );
    }
    gstats[..cpu::particle_reduce::LANE].to_vec()
}

/// `sph_forces_accumulate` (the 2nd..n-th particle sub-step's force kernel) and
/// `particle_reduce` (the particles' diagnostics) against their CPU twins, on the pressed
/// block after 60 steps (scene with 2 particle sub-steps per core step):
/// - the accumulate kernel writes the same `particle_forces`, `particle_contact` and
///   `particle_force_sum` as `cpu::sph_forces::sph_forces(.., accumulate = true, ..)`, and the
///   sum really accumulates: after `SphForces` then `SphForcesAccumulate` on unchanged inputs
///   it is 2·f/substeps, i.e. twice the one-stage sum (it would equal it, or f, if the
///   `ACCUMULATE` constant or the division by the sub-steps were lost);
/// - `particle_reduce`'s five diagnostics (and its per-block partials) equal the twin's, both
///   as the batch left them (the report the GPU read back) and re-run after the force stages
///   changed `particle_forces`; the twin's sums also match a plain f64 sum over the modes.
#[test]
fn sph_forces_accumulate_and_particle_reduce_match_their_cpu_twins() {
    let (m, params) = pressed_block_model();
    let pd = m.particles.as_ref().unwrap();
    let pp = m.particle_params(&params).unwrap();
    assert!(
        pp.substeps >= 2,
        "the pressed block should sub-step its particles"
    );
    let mut g = GpuStepper::new(gpu(), &m, params).unwrap();
    let (a, b) = press_segment();
    g.submit(60, &BatchInput::moving(a, b)).unwrap();
    let report = g.wait().unwrap();
    let n = pd.len();

    // particle_reduce as the batch's last step ran it, and what the report read back.
    let gstats = check_particle_reduce(&g, &pp, "end of batch");
    let pr = report.particles.unwrap();
    assert_eq!(pr.kinetic_energy, gstats[0] as f64);
    assert_eq!(pr.elastic_energy, gstats[1] as f64);
    assert_eq!(pr.max_speed, gstats[2] as f64);
    assert_eq!(pr.residual_norm, (gstats[3] as f64).sqrt());
    assert_eq!(pr.mass_displacement_sq, gstats[4] as f64);
    // The twin's tree sums are the plain sums over the modes (f64, any order).
    {
        let pmode = bits_u32(&g, "particle_mode");
        let (u, v, f, en) = (
            g.read_f32("particle_displacements").unwrap(),
            g.read_f32("particle_velocities").unwrap(),
            g.read_f32("particle_forces").unwrap(),
            g.read_f32("particle_energy").unwrap(),
        );
        let sq =
            |x: &[f32], p: usize| -> f64 { (0..3).map(|k| (x[3 * p + k] as f64).powi(2)).sum() };
        let mut want = [0.0f64; 5];
        for p in 0..n {
            if pmode[p] & mode::DYNAMIC != 0 {
                want[0] += 0.5 * pp.mass as f64 * sq(&v, p);
                want[2] = want[2].max(sq(&v, p).sqrt());
                want[3] += sq(&f, p);
                want[4] += pp.mass as f64 * sq(&u, p);
            }
            if pmode[p] & mode::IN_S != 0 {
                want[1] += en[p] as f64;
            }
        }
        for k in 0..5 {
            let e = (gstats[k] as f64 - want[k]).abs() / want[k];
            eprintln!("particle_reduce: diagnostic {k} vs f64 sum rel err {e:.2e}");
            assert!(e <= 1e-5, "diagnostic {k}: {} vs {}", gstats[k], want[k]);
        }
    }

    // Inputs of the force kernels, read back from the GPU.
    let grid = GridParams::over(&pd.rest, pd.support);
    let lists = cpu::neighbours::build(&grid, &pd.rest);
    let (noff, nbrs) = (&lists.neighbour_offsets, &lists.neighbours);
    let pairs = cpu::sph::PairTable::new(&pp, &pd.rest, noff, nbrs);
    let tp = m.tool_params();
    let tool_input = palpate::contact::batch_input(a, b, 60);
    let tool_state: palpate::contact::ToolState = *bytemuck::from_bytes(bytemuck::cast_slice(
        &g.read_f32("tool_state").unwrap()[..4],
    ));
    let pmode = bits_u32(&g, "particle_mode");
    let counts = bits_u32(&g, "particle_counts");
    let fl = bits_u32(&g, "force_list")[..counts[2] as usize].to_vec();
    assert!(fl.len() > 100, "force set of {} particles", fl.len());
    let pu = g.read_f32("particle_displacements").unwrap();
    let pv = g.read_f32("particle_velocities").unwrap();
    let gstress = g.read_f32("particle_stress").unwrap();
    let ggrad = g.read_f32("particle_gradient").unwrap();
    let inp = cpu::sph_forces::ForceInputs {
        params: &params,
        pp: &pp,
        tool: Some((&tp, &tool_input, &tool_state)),
        mode: &pmode,
        rest: &pd.rest,
        displacements: &pu,
        velocities: &pv,
        neighbour_offsets: noff,
        neighbours: nbrs,
        stress: &gstress,
        gradient: &ggrad,
        area: &pd.contact_area,
        contact_offset: &pd.contact_offset,
        pairs: Some(&pairs),
    };
    let on_fl = |x: &[f32]| on_particles(&fl, x);

    // The first sub-step's kernel starts the sum: f / substeps.
    g.run_stage(Stage::SphForces).unwrap();
    let sum1 = g.read_f32("particle_force_sum").unwrap();
    let f1 = g.read_f32("particle_forces").unwrap();
    let scaled: Vec<f32> = on_fl(&f1).iter().map(|x| x / pp.substeps as f32).collect();
    let e = rel(&on_fl(&sum1), &scaled);
    eprintln!("sph_forces: force sum vs f/{} rel err {e:.2e}", pp.substeps);
    assert!(
        e <= 1e-6,
        "sph_forces: force sum is not f/substeps ({e:.2e})"
    );

    // The accumulate kernel on the same inputs: the CPU twin starts from the GPU's sum.
    g.run_stage(Stage::SphForcesAccumulate).unwrap();
    let (mut f, mut fs, mut fc) = (vec![0.0f32; 3 * n], sum1.clone(), vec![0.0f32; 3 * n]);
    fs.truncate(3 * n);
    cpu::sph_forces::sph_forces(&inp, &fl, true, &mut f, &mut fs, &mut fc);
    let touching = fl
        .iter()
        .filter(|&&p| fc[3 * p as usize + 2] != 0.0)
        .count();
    assert!(touching > 0, "no particle touches the tool");
    for (name, c) in [
        ("particle_forces", &f),
        ("particle_force_sum", &fs),
        ("particle_contact", &fc),
    ] {
        let e = rel(&on_fl(&g.read_f32(name).unwrap()), &on_fl(c));
        eprintln!(
            "sph_forces_accumulate: {name} rel err {e:.2e} ({touching} particles touch the tool)"
        );
        assert!(
            e <= SPH_FORCES_TOL,
            "sph_forces_accumulate: {name} rel err {e:.2e}"
        );
    }
    // It accumulated: the sum is now twice the one-stage sum (2 f / substeps).
    let sum2 = on_fl(&g.read_f32("particle_force_sum").unwrap());
    let twice: Vec<f32> = on_fl(&sum1).iter().map(|x| 2.0 * x).collect();
    let e_twice = rel(&sum2, &twice);
    let e_once = rel(&sum2, &on_fl(&sum1));
    eprintln!(
        "sph_forces_accumulate: sum vs 2x one-stage sum rel err {e_twice:.2e} (vs the one-stage sum {e_once:.2e})"
    );
    assert!(
        e_twice <= 1e-6,
        "the force sum did not accumulate ({e_twice:.2e})"
    );
    assert!(e_once >= 0.5, "the force sum did not change ({e_once:.2e})");
    // The accumulate kernel's forces are the first kernel's (same inputs).
    let e = rel(&on_fl(&g.read_f32("particle_forces").unwrap()), &on_fl(&f1));
    assert!(e <= 1e-6, "forces differ between the two kernels ({e:.2e})");

    // particle_reduce again, standalone, after the force stages rewrote particle_forces.
    g.run_stage(Stage::ParticleReduce).unwrap();
    check_particle_reduce(&g, &pp, "standalone stage");
}

/// The pressed block with a 10× softer tool (1e7 N/m³) and activation every
/// `activation_interval` core steps. The tool's springs on the 5 mm tets' vertices no longer
/// hold the core's stable step down (3.7e-4 s) while the 1 mm particle lattice's bound stays
/// at 1.5e-4 s, so the automatic step needs 3 particle sub-steps per core step.
fn soft_pressed_block(activation_interval: u32) -> Scene {
    let text = PRESSED_BLOCK
        .replace("stiffness = 1.0e8", "stiffness = 1.0e7")
        .replace(
            "activation_radius = 0.003\n",
            &format!("activation_radius = 0.003\nactivation_interval = {activation_interval}\n"),
        );
    assert!(text.contains("1.0e7") && text.contains("activation_interval"));
    Scene::from_toml(&text, "soft hybrid block", "soft_hybrid_block", None).unwrap()
}

/// After each batch of a run: vertex displacements, particle displacements, the tool's force
/// and the dynamic particle count.
type Snapshot = (Vec<f32>, Vec<f32>, DVec3, u32);

/// Run `scene` for `batches` batches of `steps` steps (core step `dt`, or the automatic one):
/// the snapshots, and the stage counts of the last batch.
fn run_batches(
    scene: &Scene,
    backend: palpate::sim::Backend,
    dt: Option<f64>,
    batches: usize,
    steps: u32,
) -> (Vec<Snapshot>, Vec<(Stage, u32)>) {
    let mut sim = palpate::sim::Simulation::new(
        scene,
        backend,
        palpate::sim::SimOptions {
            dt,
            gpu: (backend == palpate::sim::Backend::Gpu).then(gpu),
            ..Default::default()
        },
    )
    .unwrap();
    let mut out = Vec::new();
    for _ in 0..batches {
        assert!(matches!(
            sim.advance(steps).unwrap(),
            palpate::sim::Advance::Done(_)
        ));
        let (u, p) = (
            sim.state().unwrap().displacements,
            sim.particle_state().unwrap().unwrap().displacements,
        );
        assert!(
            u.iter().chain(&p).all(|x| x.is_finite()),
            "non-finite state"
        );
        out.push((
            u,
            p,
            sim.last_tool.unwrap().force,
            sim.last_particles.unwrap().dynamic,
        ));
    }
    (out, sim.stage_counts())
}

/// On more than one thread the CPU stepper runs all the particle sub-steps beside the core's
/// element forces; on one thread in the plan's order. On the 3-sub-step scene, 300 pressed
/// steps must give the same bits both ways (vertices and particles).
#[test]
fn multi_rate_steps_are_bit_identical_on_one_and_two_threads() {
    let scene = soft_pressed_block(10);
    let run = |threads: usize| {
        let mut sim = palpate::sim::Simulation::new(
            &scene,
            palpate::sim::Backend::Cpu,
            palpate::sim::SimOptions {
                threads: Some(threads),
                ..Default::default()
            },
        )
        .unwrap();
        for _ in 0..3 {
            assert!(matches!(
                sim.advance(100).unwrap(),
                palpate::sim::Advance::Done(_)
            ));
        }
        let dynamic = sim.last_particles.map_or(0, |p| p.dynamic);
        let p = sim.particle_state().unwrap().unwrap();
        let v = sim.state().unwrap();
        let bits = |a: &[f32]| a.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
        let mut all = bits(&v.displacements);
        all.extend(bits(&v.velocities));
        all.extend(bits(&p.displacements));
        all.extend(bits(&p.velocities));
        (all, dynamic)
    };
    let m = Model::from_scene(&scene);
    let dt = palpate::sim::choose_dt(&scene, &m, None, false, false).unwrap();
    assert!(m.particle_substeps(dt) >= 2, "not a multi-rate scene");
    let ((one, dynamic), (two, _)) = (run(1), run(2));
    assert!(dynamic > 0, "no particle woke");
    assert!(one == two, "the state differs between 1 and 2 threads");
}

/// How many times `stage` ran over a batch's stage counts (every plan position of it).
fn stage_runs(counts: &[(Stage, u32)], stage: Stage) -> u32 {
    counts
        .iter()
        .filter(|&&(y, _)| y == stage)
        .map(|&(_, n)| n)
        .sum()
}

/// Multi-rate stepping: on a scene whose automatic core step needs 3 particle sub-steps
/// (`soft_pressed_block`), (a) the plan repeats Follow / SphStress / SphForces (then
/// SphForcesAccumulate) / IntegrateParticles once per sub-step, between Activate and the core
/// stages, and both backends run exactly those stages (counted over a batch); (b) 300 pressed
/// steps stay finite and the GPU matches the CPU within 1e-4 relative (vertices, particles,
/// tool force), as `hybrid_trajectory_300_steps_gpu_matches_cpu` does with 2 sub-steps.
#[test]
fn particle_substeps_are_planned_run_and_match_between_backends() {
    let scene = soft_pressed_block(10);
    let m = Model::from_scene(&scene);
    let dt = palpate::sim::choose_dt(&scene, &m, None, false, false).unwrap();
    let s = m.particle_substeps(dt);
    eprintln!(
        "core dt {dt:.3e} s (bound {:.3e} s), particle bound {:.3e} s: {s} sub-steps",
        m.bounds.dt_bound,
        m.particles.as_ref().unwrap().dt_bound(
            &m.material,
            m.tool.as_ref().map(|t| (t.tool.stiffness, t.tool.damping))
        )
    );
    assert_eq!(
        s, 3,
        "the soft pressed block should need 3 particle sub-steps"
    );
    assert_eq!(
        m.particle_params(&m.step_params(dt, 50.0))
            .unwrap()
            .substeps,
        s
    );

    // (a) The plan: Activate, then s sub-steps, then the core's stages.
    let plan = palpate::plan::StepPlan::for_model_at(&m, s);
    let stages: Vec<Stage> = plan.stages.iter().map(|p| p.stage).collect();
    let first = stages.iter().position(|&x| x == Stage::Follow).unwrap();
    assert_eq!(stages[first - 1], Stage::Activate);
    let mut want = Vec::new();
    for k in 0..s {
        want.extend([
            Stage::Follow,
            Stage::SphStress,
            if k == 0 {
                Stage::SphForces
            } else {
                Stage::SphForcesAccumulate
            },
            Stage::IntegrateParticles,
        ]);
    }
    assert_eq!(stages[first..first + want.len()], want[..], "{stages:?}");
    assert_eq!(stages[first + want.len()], Stage::FemForces, "{stages:?}");
    let count = |st: &[Stage], x: Stage| st.iter().filter(|&&y| y == x).count() as u32;
    for (x, n) in [
        (Stage::Follow, s),
        (Stage::SphStress, s),
        (Stage::SphForces, 1),
        (Stage::SphForcesAccumulate, s - 1),
        (Stage::IntegrateParticles, s),
        (Stage::Activate, 1),
        (Stage::ParticleReduce, 1),
    ] {
        assert_eq!(count(&stages, x), n, "{x:?} in {stages:?}");
    }

    // (b) Both backends, 3 batches of 100 steps (the tool reaches its depth at step 109).
    let (c, c_counts) = run_batches(&scene, palpate::sim::Backend::Cpu, None, 3, 100);
    let (g, g_counts) = run_batches(&scene, palpate::sim::Backend::Gpu, None, 3, 100);
    // The last batch (steps 200..300) ran each planned stage as the plan says.
    for (name, counts) in [("CPU", &c_counts), ("GPU", &g_counts)] {
        let planned: Vec<Stage> = counts.iter().map(|&(x, _)| x).collect();
        assert_eq!(planned, stages, "{name}: not the plan for {s} sub-steps");
        let total = |x: Stage| stage_runs(counts, x);
        for (x, n) in [
            (Stage::Follow, 100 * s),
            (Stage::SphStress, 100 * s),
            (Stage::SphForces, 100),
            (Stage::SphForcesAccumulate, 100 * (s - 1)),
            (Stage::IntegrateParticles, 100 * s),
            (Stage::FemForces, 100),
            (Stage::Activate, 10),
            (Stage::ParticleReduce, 1),
        ] {
            assert_eq!(total(x), n, "{name}: {x:?} ran {} times", total(x));
        }
    }
    backends_agree(&format!("{s} sub-steps, "), &c, &g);
    assert!(c[2].2.length() > 0.0, "the tool never touched");
}

/// The particle sub-step bound includes the tool's contact damping as the vertices' bound
/// does: a surface particle of mass m and contact area Δx² on a spring k with damping b per
/// unit area is stable up to (2/ω)(sqrt(1 + ζ²) − ζ), ω² = k Δx²/m, ζ = b Δx²/(2 m ω). On the
/// pressed block with a soft, damped tool (ζ = 1.5 for a particle): (a) the bound is that
/// formula, in quadrature with the lattice's; (b) the sub-step dt/s is within the safety
/// factor of it (3 sub-steps; the undamped bound would give 2, a sub-step 3 % over); (c)
/// pressing for 300 steps stays finite with the tool touching.
#[test]
fn contact_damping_shortens_the_particle_sub_step() {
    // Particle mass ρΔx³ = 1e-6 kg, area 1e-6 m², k = 1e6: ω = 1000 /s, ζ = b/2000.
    let (k, b) = (1.0e6, 3.0e3);
    // Without hourglass control, whose springs (in the bound too) would shift both bounds
    // past the sub-step count that tells them apart.
    let text = PRESSED_BLOCK
        .replace(
            "stiffness = 1.0e8\n",
            &format!("stiffness = {k:e}\ndamping = {b:e}\n"),
        )
        .replace("[particles]\n", "[particles]\nhourglass = 0.0\n");
    assert!(
        text.contains("damping = 3e3") && text.contains("hourglass = 0.0"),
        "{text}"
    );
    let scene = Scene::from_toml(&text, "damped block", "damped_block", None).unwrap();
    let m = Model::from_scene(&scene);
    let p = m.particles.as_ref().unwrap();
    let (dx, mass) = (0.001f64, p.mass as f64);
    let omega = (k * dx * dx / mass).sqrt();
    let zeta = b * dx * dx / (2.0 * mass * omega);
    assert!((zeta - 1.5).abs() < 1e-3, "ζ = {zeta}");
    let contact = 2.0 / omega * ((1.0 + zeta * zeta).sqrt() - zeta);
    let elastic = dx / m.material.p_wave_speed();
    // With the hourglass penalty's springs in quadrature (Particles::hourglass_omega).
    let omega_h = p.hourglass_omega(&m.material);
    let want = 1.0
        / (1.0 / (elastic * elastic) + 1.0 / (contact * contact) + 0.25 * omega_h * omega_h).sqrt();
    let bound = p.dt_bound(&m.material, Some((k, b)));
    assert!(
        (bound / want - 1.0).abs() < 1e-9,
        "bound {bound:e} s, formula {want:e} s"
    );
    let dt = palpate::sim::choose_dt(&scene, &m, None, false, false).unwrap();
    let s = m.particle_substeps(dt);
    let undamped = p.dt_bound(&m.material, Some((k, 0.0)));
    eprintln!(
        "dt {dt:.3e} s; particle bound {bound:.3e} s (undamped {undamped:.3e} s): {s} sub-steps"
    );
    let s_undamped = (dt / (m.safety * undamped)).ceil() as u32;
    assert!(
        s_undamped < s,
        "the case must tell the bounds apart: {s} sub-steps, undamped {s_undamped}"
    );
    assert!(
        dt / s as f64 <= m.safety * bound,
        "sub-step {:.3e} s over {} x the bound {bound:.3e} s",
        dt / s as f64,
        m.safety
    );
    let (c, _) = run_batches(&scene, palpate::sim::Backend::Cpu, None, 3, 100);
    for (u, pu, f, _) in &c {
        assert!(u.iter().chain(pu).all(|x| x.is_finite()) && f.is_finite());
    }
    let (_, pu, f, dynamic) = &c[2];
    let largest = pu.iter().fold(0.0f32, |a, x| a.max(x.abs()));
    assert!(f.length() > 0.0 && *dynamic > 0, "the tool never touched");
    assert!(largest < 0.01, "a particle moved {largest} m");
}

/// Multi-rate stepping converges to single-rate stepping: the soft pressed block at its
/// automatic core step dt with 3 particle sub-steps against a reference run at dt/3 (one
/// particle step per core step, activation every 30 instead of 10 steps so that it happens at
/// the same times), both on the CPU over the same 0.055 s of pressing.
#[test]
fn particle_substeps_agree_with_a_core_step_divided_as_much() {
    let multi = soft_pressed_block(10);
    let m = Model::from_scene(&multi);
    let dt = palpate::sim::choose_dt(&multi, &m, None, false, false).unwrap();
    let s = m.particle_substeps(dt);
    assert_eq!(s, 3);
    assert_eq!(
        m.particle_substeps(dt / s as f64),
        1,
        "the reference must not sub-step"
    );
    let reference = soft_pressed_block(10 * s);
    let (a, _) = run_batches(&multi, palpate::sim::Backend::Cpu, None, 3, 100);
    let (b, _) = run_batches(
        &reference,
        palpate::sim::Backend::Cpu,
        Some(dt / s as f64),
        3,
        100 * s,
    );
    for (k, (aa, bb)) in a.iter().zip(&b).enumerate() {
        let eu = rel(&aa.0, &bb.0);
        let ep = rel(&aa.1, &bb.1);
        let ef = (aa.2 - bb.2).length() / bb.2.length().max(1e-30);
        eprintln!(
            "t = {:.4} s: dynamic {} vs {}, |F| {:.4e} vs {:.4e} N; rel diff vertices {eu:.2e}, particles {ep:.2e}, tool force {ef:.2e}",
            100.0 * (k + 1) as f64 * dt,
            aa.3,
            bb.3,
            aa.2.length(),
            bb.2.length()
        );
        // Two discretisations of one problem: the multi-rate run holds the core (and the tool)
        // still over 3 particle sub-steps and moves the tool in 3x coarser steps, a
        // first-order splitting error. Measured: <= 1.1e-2 on vertex displacements, 6.6e-3
        // on particle displacements and 7.6e-3 on the tool force while the tool moves (to
        // t = 0.02 s), the force within 6e-4 once it holds. The tolerances are ~3x that; a
        // sub-step sum passed to the hosts without its 1/substeps, or not accumulated, or a
        // sub-step of dt instead of dt/3, changes the coupling forces by a factor ~3 (or
        // diverges) and lands far outside.
        assert!(
            eu <= 3e-2 && ep <= 3e-2 && ef <= 2e-2,
            "t = {:.4} s: the multi-rate run departs from the reference",
            100.0 * (k + 1) as f64 * dt
        );
        assert!(
            aa.3.abs_diff(bb.3) * 20 <= bb.3 && bb.3 > 0,
            "dynamic particles {} vs {}",
            aa.3,
            bb.3
        );
    }
    // Holding still, both settle towards the same equilibrium.
    let ef = (a[2].2 - b[2].2).length() / b[2].2.length();
    assert!(ef <= 5e-3, "held tool force differs by {ef:.2e}");
}

#[test]
fn a_dt_change_gives_both_backends_the_same_particle_parameters_and_trajectory() {
    // The stability guard halves dt mid-run (Stepper::set_params). Both steppers keep the
    // plan's sub-step count and derive the sub-step and activation interval from the new dt
    // the same way (ParticleParams::at_core_dt), so the uniforms are byte-equal (this fails
    // if either stepper forms them differently) and the runs stay together (measured 1e-7 /
    // 7e-7, asserted 1e-5; the particle modes must be equal).
    let scene = soft_pressed_block(3);
    let m = Arc::new(Model::from_scene(&scene));
    let dt = 0.5 * m.bounds.dt_bound;
    let params = m.step_params(dt, 50.0);
    let mut c = cpu::CpuStepper::new(m.clone(), params);
    let mut g = GpuStepper::new(gpu(), &m, params).unwrap();
    let built = c.particle_params().unwrap();
    assert!(built.substeps >= 2, "{} sub-steps", built.substeps);
    let smaller = m.step_params(0.6 * dt, 50.0);
    for s in [&mut c as &mut dyn Stepper, &mut g] {
        s.set_params(&smaller).unwrap();
    }
    let pc = c.particle_params().unwrap();
    let pg = g.particle_params().unwrap();
    assert_eq!(
        bytemuck::bytes_of(&pc),
        bytemuck::bytes_of(&pg),
        "particle uniforms differ: CPU {pc:?}, GPU {pg:?}"
    );
    // Press for 200 steps at the new dt: the runs agree.
    let tool = scene.tool.clone().unwrap();
    let (batch, mut t) = (20u32, 0.0);
    for _ in 0..10 {
        let input = BatchInput {
            tool: Some((
                tool.position_at(t),
                tool.position_at(t + batch as f64 * smaller.dt as f64),
            )),
            tool_slice: None,
        };
        for s in [&mut c as &mut dyn Stepper, &mut g] {
            s.submit(batch, &input).unwrap();
            s.wait().unwrap();
        }
        t += batch as f64 * smaller.dt as f64;
    }
    let (sc, sg) = (c.read_state().unwrap(), g.read_state().unwrap());
    let (pc, pg) = (
        c.read_particle_state().unwrap().unwrap(),
        g.read_particle_state().unwrap().unwrap(),
    );
    let dynamic = pc.modes.iter().filter(|&&m| m & mode::DYNAMIC != 0).count();
    assert_eq!(pg.modes, pc.modes, "particle modes differ");
    let (eu, ep) = (
        rel(&sg.displacements, &sc.displacements),
        rel(&pg.displacements, &pc.displacements),
    );
    eprintln!("after dt × 0.6: {dynamic} dynamic particles; GPU vs CPU rel err vertices {eu:.2e}, particles {ep:.2e}");
    assert!(dynamic > 0, "no particle became dynamic");
    assert!(
        eu <= 1e-4 && ep <= 1e-4,
        "GPU vs CPU after a dt change: {eu:.2e} / {ep:.2e}"
    );
}

#[test]
fn the_cpu_activation_skips_only_particles_the_kernel_leaves_unchanged() {
    // The CPU twin of `activate` skips particles that cannot reach the tool
    // (|X − c| − Σ|w|·max|u| − R ≥ activation radius + margin); the kernel evaluates every
    // particle. On hm1 (a curved zone; its particles all lie inside their hosts), pressed and
    // deformed, the tool is moved through 24 positions that sweep the activation boundary
    // across the particles; at each the kernel and the twin must give bit-equal modes,
    // timers, offsets and particle states.
    let scene = Scene::load("hm1").unwrap();
    let m = Arc::new(Model::from_scene(&scene));
    let pd = m.particles.as_ref().unwrap();
    let dt = scene.solver.dt.unwrap();
    let params = m.step_params(dt, 0.5);
    let pp = m.particle_params(&params).unwrap();
    let mut g = GpuStepper::new(gpu(), &m, params).unwrap();
    let tool = scene.tool.clone().unwrap();
    let (batch, mut t) = (50u32, 0.0);
    while t < 3.0 {
        let (a, b) = (tool.position_at(t), tool.position_at(t + batch as f64 * dt));
        g.submit(batch, &BatchInput::moving(a, b)).unwrap();
        g.wait().unwrap();
        t += batch as f64 * dt;
    }
    let st = ParticleStatic::of(&m).unwrap();
    let n = pd.len();
    let tp = m.tool_params();
    let pressed = tool.position_at(3.0);
    let (mut near, mut dynamic_max) = (0usize, 0usize);
    for k in 0..24 {
        // Out along the outward normal (x) from 0.5 inside to 2.5 outside, and across z.
        let c = pressed
            + DVec3::new(
                -0.5 + 3.0 * k as f64 / 23.0,
                0.0,
                if k % 2 == 0 { 0.7 } else { -0.7 },
            );
        let state = palpate::contact::ToolState {
            position: c.as_vec3().to_array(),
            step: 0,
        };
        g.write_f32("tool_state", bytemuck::cast_slice(&[state]))
            .unwrap();
        let mut io = ActivateIo::read(&g);
        let u = &io.u;
        near += (0..n)
            .filter(|&p| {
                let x = st.embed(u, p) + glam::Vec3::from_slice(&pd.rest[3 * p..3 * p + 3]);
                let d = (x - c.as_vec3()).length() - tp.radius;
                (d - pp.activation_radius).abs() < 0.1 * pp.activation_radius
            })
            .count();
        g.run_stage(Stage::Activate).unwrap();
        io.run_twin(&pp, &tp, &state, &st);
        let ActivateIo {
            pu,
            pv,
            pmode,
            ptimer,
            poffset,
            ..
        } = io;
        let sets = mode::IN_S | mode::IN_F;
        let gmode: Vec<u32> = bits_u32(&g, "particle_mode")[..n]
            .iter()
            .map(|m| m & !sets)
            .collect();
        let differ = |kernel: &[u32], twin: &[u32]| {
            let bad: Vec<usize> = (0..twin.len()).filter(|&i| kernel[i] != twin[i]).collect();
            bad.first().map(|&i| {
                format!(
                    "{} entries differ, first [{i}]: kernel {:#x}, twin {:#x}",
                    bad.len(),
                    kernel[i],
                    twin[i]
                )
            })
        };
        if let Some(d) = differ(&gmode, &pmode[..n]) {
            panic!("tool position {k}: particle_mode: {d}");
        }
        // The floats to rounding: a GPU may fuse the embedding's multiply-adds (1 ulp apart on
        // an NVIDIA H200, 2026-11-27); a particle wrongly skipped keeps a stale timer, offset
        // or place, far more than rounding off. A release offset u − Σ w u is a difference of
        // displacements, so it is rounded on their scale (0 against 1.9e-9 m there).
        let largest = |x: &[f32]| x.iter().fold(f32::MIN_POSITIVE, |m, &v| m.max(v.abs()));
        for (name, c, scale) in [
            ("particle_timer", &ptimer, largest(&ptimer)),
            ("particle_offset", &poffset, largest(&pu)),
            ("particle_displacements", &pu, largest(&pu)),
            ("particle_velocities", &pv, largest(&pv)),
        ] {
            let kernel = g.read_f32(name).unwrap();
            let bad: Vec<usize> = (0..c.len())
                .filter(|&i| (kernel[i] - c[i]).abs() > 1e-6 * scale)
                .collect();
            if let Some(&i) = bad.first() {
                panic!(
                    "tool position {k}: {name}: {} entries differ by more than rounding, first [{i}]: kernel {:e}, twin {:e}",
                    bad.len(),
                    kernel[i],
                    c[i]
                );
            }
        }
        dynamic_max = dynamic_max.max(pmode.iter().filter(|&&m| m & mode::DYNAMIC != 0).count());
    }
    eprintln!(
        "activation sweep: {n} particles, {near} particle-positions within 10 % of the activation radius, up to {dynamic_max} dynamic: kernel and twin give the same modes, and values equal to rounding"
    );
    assert!(
        near > 100,
        "the sweep never brought particles near the boundary"
    );
    assert!(
        dynamic_max > 50,
        "the sweep activated {dynamic_max} particles"
    );
}

/// Press the pressed block in batches of 7 steps (the activation runs every 10, so batches
/// end between activations) to batch 40; with `restore`, checkpoint after batch 28 (the tool
/// touches from about step 150), run 3 more (past the activations of steps 200 and 210),
/// restore and replay from batch 28: (vertex displacements, particle displacements, dynamic
/// particles at the end).
fn press_with_a_restore(
    s: &mut dyn Stepper,
    scene: &Scene,
    dt: f64,
    restore: bool,
) -> (Vec<f32>, Vec<f32>, usize) {
    let tool = scene.tool.as_ref().unwrap();
    let input = |b: u32| BatchInput {
        tool: Some((
            tool.position_at(7.0 * b as f64 * dt),
            tool.position_at(7.0 * (b + 1) as f64 * dt),
        )),
        tool_slice: None,
    };
    let mut b = 0;
    let mut restored = !restore;
    while b < 40 {
        s.submit(7, &input(b)).unwrap();
        s.wait().unwrap();
        b += 1;
        if b == 28 {
            s.checkpoint().unwrap();
        }
        if b == 31 && !restored {
            restored = true;
            s.restore().unwrap();
            b = 28;
        }
    }
    let u = s.read_state().unwrap().displacements;
    let p = s.read_particle_state().unwrap().unwrap();
    let dynamic = p.modes.iter().filter(|&&m| m & mode::DYNAMIC != 0).count();
    (u, p.displacements, dynamic)
}

/// A checkpoint restored between two activations, after the run went on past two more: the
/// restore brings back the step count (which steps activate) and the lists, weights and flags
/// the restored modes were built with, so on each backend the replay is bit for bit the run
/// without the restore. Pressing the block with such a restore, the GPU matches the CPU
/// within 1e-4 relative (vertices and particles), with the same dynamic particles (some).
#[test]
fn a_restore_between_activations_gives_both_backends_the_same_trajectory() {
    let scene = pressed_block();
    let m = Arc::new(Model::from_scene(&scene));
    let dt = 0.5 * m.bounds.dt_bound;
    let params = m.step_params(dt, 50.0);
    let mut c = cpu::CpuStepper::new(m.clone(), params);
    let mut g = GpuStepper::new(gpu(), &m, params).unwrap();
    let (cu, cp, cd) = press_with_a_restore(&mut c, &scene, dt, true);
    let (gu, gp, gd) = press_with_a_restore(&mut g, &scene, dt, true);
    let mut c = cpu::CpuStepper::new(m.clone(), params);
    let mut g = GpuStepper::new(gpu(), &m, params).unwrap();
    for (name, s, u, p, d) in [
        ("cpu", &mut c as &mut dyn Stepper, &cu, &cp, cd),
        ("gpu", &mut g, &gu, &gp, gd),
    ] {
        let (nu, np, nd) = press_with_a_restore(s, &scene, dt, false);
        assert_eq!(
            nd, d,
            "{name}: dynamic particles with and without the restore"
        );
        assert_eq!(
            bits(u),
            bits(&nu),
            "{name}: vertices differ after the restore"
        );
        assert_eq!(
            bits(p),
            bits(&np),
            "{name}: particles differ after the restore"
        );
    }
    let (eu, ep) = (rel(&gu, &cu), rel(&gp, &cp));
    eprintln!("restored press: {cd} dynamic; rel err vertices {eu:.2e}, particles {ep:.2e}");
    assert_eq!(cd, gd, "dynamic particles");
    assert!(cd > 0, "no particle became dynamic");
    assert!(
        eu <= 1e-4 && ep <= 1e-4,
        "vertices {eu:.2e}, particles {ep:.2e}"
    );
}

/// `restore` without a checkpoint goes back to the state at rest on both backends: after a
/// press that made particles dynamic and moved vertex mass onto them, every vertex and
/// particle is at rest, the particles have their initial modes (only PINNED bits) and the
/// vertices the all-embedded masses; pressing again from there repeats the first press bit
/// for bit on each backend (the step count is back at 0), and the GPU matches the CPU.
#[test]
fn a_restore_without_a_checkpoint_returns_both_backends_to_rest() {
    let (m, params) = pressed_block_model();
    let pd = m.particles.as_ref().unwrap();
    let initial = pd.initial_modes();
    let (a, b) = press_segment();
    let mut c = cpu::CpuStepper::new(m.clone(), params);
    let mut g = GpuStepper::new(gpu(), &m, params).unwrap();
    let mut ends = Vec::new();
    for (name, s) in [("cpu", &mut c as &mut dyn Stepper), ("gpu", &mut g)] {
        s.submit(150, &BatchInput::moving(a, b)).unwrap();
        s.wait().unwrap();
        let first = (
            s.read_state().unwrap().displacements,
            s.read_particle_state().unwrap().unwrap().displacements,
        );
        let p = s.read_particle_state().unwrap().unwrap();
        let dynamic = p.modes.iter().filter(|&&x| x & mode::DYNAMIC != 0).count();
        assert!(dynamic > 0, "{name}: no particle became dynamic");
        s.restore().unwrap();
        let st = s.read_state().unwrap();
        let p = s.read_particle_state().unwrap().unwrap();
        assert!(
            st.displacements
                .iter()
                .chain(&st.velocities)
                .all(|&x| x == 0.0),
            "{name}: vertices not at rest"
        );
        assert!(
            p.displacements
                .iter()
                .chain(&p.velocities)
                .all(|&x| x == 0.0),
            "{name}: particles not at rest"
        );
        assert_eq!(p.modes, initial, "{name}: particle modes");
        s.submit(150, &BatchInput::moving(a, b)).unwrap();
        s.wait().unwrap();
        let again = (
            s.read_state().unwrap().displacements,
            s.read_particle_state().unwrap().unwrap().displacements,
        );
        assert_eq!(
            bits(&first.0),
            bits(&again.0),
            "{name}: vertices, pressed again"
        );
        assert_eq!(
            bits(&first.1),
            bits(&again.1),
            "{name}: particles, pressed again"
        );
        ends.push(again);
    }
    // The all-embedded masses after the restore (before the next activation relumps them).
    c.restore().unwrap();
    g.restore().unwrap();
    assert_eq!(
        bits(c.vertex_masses().0),
        bits(&m.mass),
        "cpu: vertex masses"
    );
    assert_eq!(
        bits(&g.read_f32("mass").unwrap()[..m.n_vertices()]),
        bits(&m.mass),
        "gpu: vertex masses"
    );
    let (eu, ep) = (rel(&ends[1].0, &ends[0].0), rel(&ends[1].1, &ends[0].1));
    eprintln!(
        "pressed again after a restore to rest: rel err vertices {eu:.2e}, particles {ep:.2e}"
    );
    assert!(
        eu <= 1e-4 && ep <= 1e-4,
        "vertices {eu:.2e}, particles {ep:.2e}"
    );
}

/// A batch replayed one step at a time through `tool_slice` (as `Simulation::advance` replays
/// a diverged batch) repeats the batch bit for bit on both backends: the same tool positions
/// and velocity (contact damping included), the same activations, the same end. One-step
/// batches of their own moves (at(k), at(k + 1)) do not: their f32 tool velocity is rounded
/// over one step instead of the batch's 150.
#[test]
fn a_batch_replayed_one_step_at_a_time_repeats_it_bit_for_bit() {
    let (m, params) = pressed_block_model();
    let (a, b) = press_segment();
    let n = 150u32;
    let mut c = cpu::CpuStepper::new(m.clone(), params);
    let mut g = GpuStepper::new(gpu(), &m, params).unwrap();
    for (name, s) in [("cpu", &mut c as &mut dyn Stepper), ("gpu", &mut g)] {
        let end = |s: &mut dyn Stepper| {
            (
                s.read_state().unwrap(),
                s.read_particle_state().unwrap().unwrap(),
            )
        };
        s.submit(n, &BatchInput::moving(a, b)).unwrap();
        let whole = s.wait().unwrap();
        let batch = end(s);
        let dynamic = batch.1.modes.iter().filter(|&&x| x & mode::DYNAMIC != 0);
        assert!(dynamic.count() > 0, "{name}: no particle became dynamic");
        s.restore().unwrap();
        let mut last = None;
        let mut sliced_tool = Vec::new();
        for k in 0..n {
            let input = BatchInput {
                tool_slice: Some((k, n)),
                ..BatchInput::moving(a, b)
            };
            assert_eq!(
                input.tool_after(1).unwrap(),
                a + (b - a) * ((k + 1) as f64 / n as f64)
            );
            s.submit(1, &input).unwrap();
            let r = s.wait().unwrap();
            sliced_tool.push(r.tool.unwrap());
            last = Some(r);
        }
        let sliced = end(s);
        for (what, x, y) in [
            (
                "vertex displacements",
                &batch.0.displacements,
                &sliced.0.displacements,
            ),
            (
                "vertex velocities",
                &batch.0.velocities,
                &sliced.0.velocities,
            ),
            (
                "particle displacements",
                &batch.1.displacements,
                &sliced.1.displacements,
            ),
            (
                "particle velocities",
                &batch.1.velocities,
                &sliced.1.velocities,
            ),
        ] {
            assert_eq!(bits(x), bits(y), "{name}: {what}");
        }
        assert_eq!(batch.1.modes, sliced.1.modes, "{name}: modes");
        let (t0, t1) = (whole.tool.unwrap(), last.unwrap().tool.unwrap());
        assert_eq!(t0.position, b);
        assert_eq!(
            t0.force.to_array(),
            t1.force.to_array(),
            "{name}: tool force"
        );
        // One-step batches of their own moves: the tool velocity differs by rounding.
        s.restore().unwrap();
        let mut worst = 0.0f64;
        for k in 0..n {
            let at = |j: u32| a + (b - a) * (j as f64 / n as f64);
            s.submit(1, &BatchInput::moving(at(k), at(k + 1))).unwrap();
            let own = s.wait().unwrap().tool.unwrap();
            // Each slice's report has the tool where that step left it (not at the move's
            // end): the same force as the one-step move's, to the rounding of the velocity.
            let sliced = sliced_tool[k as usize];
            assert_eq!(
                sliced.position, own.position,
                "{name}: step {k}: tool position"
            );
            if own.force.length() > 0.0 {
                worst = worst.max((sliced.force - own.force).length() / own.force.length());
            }
        }
        assert!(
            worst <= 1e-2,
            "{name}: a slice's tool force is {worst:.2e} off the one-step move's"
        );
        let own = end(s);
        assert_ne!(
            bits(&batch.1.velocities),
            bits(&own.1.velocities),
            "{name}: one-step moves repeat the batch too (this test no longer tells them apart)"
        );
    }
}

/// A divergence in a particle scene: `Simulation::advance` finds the failing step on a replay
/// that activates on the same steps as the batch (the step that one-step batches from the same
/// state find), leaves the state at the step before it (bit for bit that of the one-step run),
/// and `rollback_to_checkpoint` brings back the batch start, particles and modes included.
/// The block is pressed at its step until particles are dynamic, then the tool is held and
/// dt raised to 4× the bound.
#[test]
fn a_divergence_in_a_particle_scene_is_located_and_rolled_back_whole() {
    use palpate::sim::{Advance, DivergencePolicy, Guarded, SimOptions, Simulation};
    let scene = pressed_block();
    let start = |batch: u32| {
        let mut sim = Simulation::new(
            &scene,
            palpate::Backend::Cpu,
            SimOptions {
                threads: Some(1),
                ..Default::default()
            },
        )
        .unwrap();
        for _ in 0..250 / batch {
            assert!(matches!(sim.advance(batch).unwrap(), Advance::Done(_)));
        }
        let dt = sim.dt;
        // The particle sub-steps held (not adapted at the ends of batches, which the batch and
        // the one-step batches have at different steps).
        sim.fix_particle_substeps(sim.model.particle_substeps(dt))
            .unwrap();
        sim.set_dt(4.0 * dt).unwrap();
        // Held where it is: a batch and one-step batches give the tool the same inputs.
        sim.tool_target = Some(sim.tool_position);
        sim
    };
    let mut batch = start(25);
    let max_at_start = batch.active_particles_max;
    let before = (
        batch.state().unwrap(),
        batch.particle_state().unwrap().unwrap(),
    );
    let dynamic = before.1.modes.iter().filter(|&&m| m & mode::DYNAMIC != 0);
    assert!(
        dynamic.count() > 0,
        "no particle is dynamic before the jump"
    );
    let Advance::Diverged { step, .. } = batch.advance(200).unwrap() else {
        panic!("200 steps at 4x the bound did not diverge");
    };
    let mut single = start(25);
    let single_step = loop {
        if let Advance::Diverged { step, .. } = single.advance(1).unwrap() {
            break step;
        }
        assert!(single.steps_done < 450, "the one-step run did not diverge");
    };
    eprintln!("diverged at step {step} (one-step batches: {single_step})");
    assert!(step > 251, "diverged on the first step ({step})");
    assert_eq!(step, single_step, "the replay found another step");
    assert_eq!(batch.steps_done, single.steps_done);
    let (a, b) = (batch.state().unwrap(), single.state().unwrap());
    assert_eq!(bits(&a.displacements), bits(&b.displacements), "vertices");
    let (pa, pb) = (
        batch.particle_state().unwrap().unwrap(),
        single.particle_state().unwrap().unwrap(),
    );
    assert_eq!(
        bits(&pa.displacements),
        bits(&pb.displacements),
        "particles"
    );
    assert_eq!(pa.modes, pb.modes, "modes");
    let max_diverged = batch.active_particles_max;
    assert!(batch.rollback_to_checkpoint().unwrap());
    assert_eq!(batch.steps_done, 250);
    eprintln!(
        "most dynamic particles: {max_at_start} at the batch start, {max_diverged} before the rollback"
    );
    assert_eq!(
        batch.active_particles_max, max_at_start,
        "active_particles_max"
    );
    let after = (
        batch.state().unwrap(),
        batch.particle_state().unwrap().unwrap(),
    );
    assert_eq!(bits(&after.0.displacements), bits(&before.0.displacements));
    assert_eq!(bits(&after.0.velocities), bits(&before.0.velocities));
    assert_eq!(bits(&after.1.displacements), bits(&before.1.displacements));
    assert_eq!(bits(&after.1.velocities), bits(&before.1.velocities));
    assert_eq!(after.1.modes, before.1.modes);
    assert!(
        !batch.rollback_to_checkpoint().unwrap(),
        "a second rollback"
    );
    // Under HalveDt the same batch comes back at its start with dt halved, without redoing
    // the steps before the failing one.
    let mut halving = start(25);
    let dt = halving.dt;
    let Guarded::Retry {
        step: at, dt: half, ..
    } = halving
        .advance_with(200, DivergencePolicy::HalveDt)
        .unwrap()
    else {
        panic!("HalveDt did not retry");
    };
    assert_eq!((at, half, halving.steps_done), (step, 0.5 * dt, 250));
    let p = halving.particle_state().unwrap().unwrap();
    assert_eq!(
        bits(&halving.state().unwrap().displacements),
        bits(&before.0.displacements)
    );
    assert_eq!(bits(&p.displacements), bits(&before.1.displacements));
    assert_eq!(p.modes, before.1.modes);
}

/// A divergence at a particle (flagged as n_vertices + p) is reported as that particle, not
/// as a vertex past the end of the mesh.
#[test]
fn a_diverged_particle_is_reported_as_a_particle() {
    use palpate::output::summary::RunStatus;
    let status = |vertex| {
        RunStatus::Diverged {
            step: 7,
            vertex,
            n_vertices: 100,
            speed_limit: 1.0,
            wave_speeds: 10.0,
            dt: 1e-5,
            dt_bound: 2e-5,
            rolled_back_to: None,
        }
        .divergence()
        .unwrap()
    };
    assert!(status(99).contains("step 7, vertex 99"), "{}", status(99));
    let particle = status(103);
    assert!(
        particle.contains("step 7, particle 3") && !particle.contains("vertex"),
        "{particle}"
    );
}

/// The dwell counts from the first activation check that finds a dynamic particle beyond the
/// release radius (it may have left just before): with a dwell shorter than the check
/// interval it is released at the second far check, not the first, so it is always far for
/// at least the dwell. A check that finds it near again restarts the clock.
#[test]
fn a_released_particle_was_far_for_at_least_the_dwell() {
    use palpate::contact::{ToolParams, ToolState};
    use palpate::cpu::activate::{update_particle, ModeInputs, ModeState};
    use palpate::particles::params::ParticleParams;
    let tets = [[0u32, 1, 2, 3]];
    let s = ParticleStatic {
        rest: &[0.25, 0.25, 0.25],
        host: &[0],
        weights: &[0.25; 4],
        tets: &tets,
    };
    let pp = ParticleParams {
        n_particles: 1,
        activation_radius: 0.1,
        release_radius: 0.15,
        candidate_radius: 0.15,
        dwell: 0.005, // shorter than the 0.01 s between checks
        blend: 0.02,
        interval: 0.01,
        ..Default::default()
    };
    let tp = ToolParams {
        radius: 0.1,
        ..Default::default()
    };
    let zeros = [0.0f32; 12];
    let (mut u, mut v, mut mode_bits, mut timer, mut offset) =
        ([0.0f32; 3], [0.0f32; 3], 0u32, 0.0f32, [0.0f32; 3]);
    // Tool centres: touching (distance 0.05 from the tool's surface), then far (1.0).
    let mut check = |centre: [f32; 3]| {
        let state = ToolState {
            position: centre,
            step: 0,
        };
        let inp = ModeInputs::new(&pp, &tp, &state, true, &s, &zeros, &zeros);
        update_particle(
            &inp,
            0,
            ModeState {
                u: &mut u,
                v: &mut v,
                mode: &mut mode_bits,
                timer: &mut timer,
                offset: &mut offset,
            },
        );
        mode_bits
    };
    let near = [0.25, 0.25, 0.25 + 0.15];
    let far = [0.25, 0.25, 1.5];
    assert!(check(near) & mode::DYNAMIC != 0, "activated");
    assert!(check(far) & mode::DYNAMIC != 0, "first far check: kept");
    assert!(check(near) & mode::DYNAMIC != 0, "near again");
    assert!(
        check(far) & mode::DYNAMIC != 0,
        "far again: the clock restarted"
    );
    let m = check(far);
    assert!(
        m & mode::DYNAMIC == 0 && m & mode::BLENDING != 0,
        "second far check in a row: released, blending back"
    );
}

/// The CPU stepper's force stage evaluates each tlsph pair once (`cpu::sph_pairs`): the owner
/// computes the pair's terms, the other end takes their negatives. On the pressed block after
/// 60 steps (dynamic, stressed and touching particles, hourglass control on), its forces, force
/// sums and contacts must equal the kernel twin's (`cpu::sph_forces`, which visits each pair
/// from both ends) to rounding, with the stress and force lists in index order and in reverse
/// (the stepper's incremental lists are not sorted); with gravity and the tool left out, the
/// forces must sum to zero to rounding (each pair's two ends get exactly opposite terms).
#[test]
fn the_paired_sph_force_stage_equals_the_kernel_twin() {
    use palpate::cpu::sph_pairs::{transpose_slots, PairPlan, PairScratch, PlanScratch};
    let (m, params) = pressed_block_model();
    let pd = m.particles.as_ref().unwrap();
    let pp = m.particle_params(&params).unwrap();
    assert!(
        pp.model == 0 && pp.hourglass > 0.0,
        "tlsph with hourglass control"
    );
    let mut s = cpu::CpuStepper::with_threads(m.clone(), params, 2).unwrap();
    let (a, b) = press_segment();
    s.submit(60, &BatchInput::moving(a, b)).unwrap();
    s.wait().unwrap();
    let snap = s.particle_state().unwrap();
    let n = pd.len();
    let grid = GridParams::over(&pd.rest, pd.support);
    let lists = cpu::neighbours::build(&grid, &pd.rest);
    let (noff, nbrs) = (&lists.neighbour_offsets, &lists.neighbours);
    let pairs = cpu::sph::PairTable::new(&pp, &pd.rest, noff, nbrs);
    let transpose = transpose_slots(noff, nbrs);
    let with = |bit: u32| -> Vec<u32> {
        (0..n as u32)
            .filter(|&p| snap.modes[p as usize] & bit != 0)
            .collect()
    };
    let (sl, fl, dl) = (with(mode::IN_S), with(mode::IN_F), with(mode::DYNAMIC));
    assert!(
        dl.len() > 20 && sl.len() > dl.len() && fl.len() > sl.len(),
        "dynamic {}, stress {}, force {}",
        dl.len(),
        sl.len(),
        fl.len()
    );
    let mut correction = vec![0.0f32; 9 * n];
    cpu::sph_setup::sph_setup(&pp, &pd.rest, noff, nbrs, &mut correction);
    let (mut stress, mut grad, mut energy) =
        (vec![0.0f32; 9 * n], vec![0.0f32; 9 * n], vec![0.0f32; n]);
    cpu::sph_stress::sph_stress(
        &params,
        &pp,
        m.material.model,
        &sl,
        &pd.rest,
        &snap.displacements,
        None,
        noff,
        nbrs,
        &correction,
        Some(&pairs),
        &mut stress,
        &mut grad,
        &mut energy,
    );
    let tp = m.tool_params();
    let tool_input = palpate::contact::batch_input(a, b, 60);
    let tool_state = palpate::contact::ToolState {
        position: b.as_vec3().to_array(),
        step: 60,
    };
    let inp = cpu::sph_forces::ForceInputs {
        params: &params,
        pp: &pp,
        tool: Some((&tp, &tool_input, &tool_state)),
        mode: &snap.modes,
        rest: &pd.rest,
        displacements: &snap.displacements,
        velocities: &snap.velocities,
        neighbour_offsets: noff,
        neighbours: nbrs,
        stress: &stress,
        gradient: &grad,
        area: &pd.contact_area,
        contact_offset: &pd.contact_offset,
        pairs: Some(&pairs),
    };
    let on_fl = |x: &[f32]| on_particles(&fl, x);
    let twin = |inp: &cpu::sph_forces::ForceInputs| {
        let (mut f, mut fs, mut fc) = (
            vec![0.0f32; 3 * n],
            vec![0.0f32; 3 * n],
            vec![0.0f32; 3 * n],
        );
        cpu::sph_forces::sph_forces(inp, &fl, false, &mut f, &mut fs, &mut fc);
        (f, fs, fc)
    };
    let (mut plan, mut plan_scratch, mut scratch) = (
        PairPlan::default(),
        PlanScratch::default(),
        PairScratch::default(),
    );
    // `restore`: take that plan back (as a checkpoint's restore does) instead of building
    // one; the scratch then holds another build's pair records.
    let mut paired =
        |inp: &cpu::sph_forces::ForceInputs, sl: &[u32], fl: &[u32], restore: Option<&PairPlan>| {
            match restore {
                Some(saved) => plan.clone_from(saved),
                None => plan.rebuild(
                    sl,
                    fl,
                    inp.mode,
                    (noff, nbrs, &transpose),
                    &mut plan_scratch,
                ),
            }
            let (mut f, mut fs, mut fc) = (
                vec![0.0f32; 3 * n],
                vec![0.0f32; 3 * n],
                vec![0.0f32; 3 * n],
            );
            plan.sph_forces(inp, sl, fl, false, &mut scratch, &mut f, &mut fs, &mut fc);
            (f, fs, fc, plan.pairs(), plan.clone())
        };
    let (f, fs, fc) = twin(&inp);
    let touching = fl
        .iter()
        .filter(|&&p| fc[3 * p as usize + 2] != 0.0)
        .count();
    assert!(touching > 0, "no particle touches the tool");
    let (rs, rf): (Vec<u32>, Vec<u32>) = (
        sl.iter().rev().copied().collect(),
        fl.iter().rev().copied().collect(),
    );
    let mut first = None;
    for (order, sl_o, fl_o) in [("index order", &sl, &fl), ("reversed", &rs, &rf)] {
        let (pf, pfs, pfc, n_pairs, built) = paired(&inp, sl_o, fl_o, None);
        if first.is_none() {
            first = Some((pf.clone(), built));
        }
        for (name, c, p) in [
            ("particle_forces", &f, &pf),
            ("particle_force_sum", &fs, &pfs),
            ("particle_contact", &fc, &pfc),
        ] {
            let e = rel(&on_fl(p), &on_fl(c));
            eprintln!("paired sph_forces ({order}, {n_pairs} pairs): {name} rel err {e:.2e}");
            assert!(
                e <= 1e-5,
                "paired sph_forces ({order}): {name} rel err {e:.2e}"
            );
        }
    }
    // A force list that misses a neighbour of S cannot be paired: the plan says so.
    let short: Vec<u32> = fl
        .iter()
        .copied()
        .filter(|&p| snap.modes[p as usize] & mode::IN_S != 0)
        .collect();
    let mut broken = PairPlan::default();
    broken.rebuild(
        &sl,
        &short,
        &snap.modes,
        (noff, nbrs, &transpose),
        &mut PlanScratch::default(),
    );
    assert!(
        !broken.valid,
        "a plan over a force list without S's neighbours claims to be valid"
    );
    // The index-order plan restored after the reversed one was built: its own records again.
    let (first_forces, first_plan) = first.expect("the loop ran");
    let (pf, _, _, _, _) = paired(&inp, &sl, &fl, Some(&first_plan));
    assert!(
        pf == first_forces,
        "a restored pair plan does not give its own forces back"
    );
    // Internal forces only: they sum to zero to rounding.
    let still = palpate::params::StepParams {
        gravity: [0.0; 3],
        ..params
    };
    let internal = cpu::sph_forces::ForceInputs {
        params: &still,
        tool: None,
        ..inp
    };
    let (pf, _, _, _, _) = paired(&internal, &sl, &fl, None);
    let sum_of = |f: &[f32]| {
        fl.iter().fold((DVec3::ZERO, 0.0f64), |(t, s), &p| {
            let v = cpu::load3(f, p as usize).as_dvec3();
            (t + v, s + v.length())
        })
    };
    let (total, scale) = sum_of(&pf);
    let (twin_total, _) = sum_of(&twin(&internal).0);
    eprintln!(
        "internal forces: |sum| / sum |f| = {:.2e} paired, {:.2e} twin",
        total.length() / scale,
        twin_total.length() / scale
    );
    assert!(
        scale > 0.0 && total.length() <= 1e-6 * scale,
        "the paired forces do not sum to zero"
    );
    // Design 8's paired stage (the pairs' stress and hourglass parts apart) against its twin,
    // which visits each pair from both ends: the particles' forces, contacts and what their
    // hosts take.
    let zeros = || vec![0.0f32; 3 * n];
    let (mut tf, mut tc, mut th) = (zeros(), zeros(), zeros());
    cpu::exact_stages::exact_forces(&inp, &fl, &mut tf, &mut tc, &mut th);
    let mut plan = PairPlan::default();
    plan.rebuild(
        &sl,
        &fl,
        &snap.modes,
        (noff, nbrs, &transpose),
        &mut PlanScratch::default(),
    );
    let (mut pf, mut pc, mut ph) = (zeros(), zeros(), zeros());
    plan.exact_forces(
        &inp,
        (&sl, &fl, &pairs),
        &mut PairScratch::<cpu::sph_pairs::Split>::default(),
        &mut pf,
        &mut pc,
        &mut ph,
    );
    for (name, twin, paired) in [
        ("forces", &tf, &pf),
        ("contact", &tc, &pc),
        ("host force", &th, &ph),
    ] {
        let e = rel(&on_fl(paired), &on_fl(twin));
        eprintln!("paired exact_forces: {name} rel err {e:.2e}");
        assert!(e <= 1e-5, "paired exact_forces: {name} rel err {e:.2e}");
    }
}

/// The GPU's activation skips its set marks, lists and tet weights, and relumps only the
/// vertices without mass, when no particle became or stopped being dynamic (`activate_gate`).
/// Over the pressed block's press, hold and withdrawal in batches of one activation interval,
/// a stepper whose every activation is forced to be a full one must reach the same bits
/// (vertices, particles, modes, lists, weights, masses). The gated one must have skipped
/// updates and run full ones where the set changed, with released particles on the way; and
/// with every particle dynamic (`activation = "all"`: the zone's vertices have no mass and
/// take their particles' velocity at each update) it runs one full update, then skips.
#[test]
fn a_skipped_gpu_activation_equals_the_full_one() {
    let tool_set = gated_against_full(&pressed_block(), 12);
    eprintln!("tool's set: {tool_set:?}");
    assert!(tool_set.full > 2 && tool_set.skipped > 2, "{tool_set:?}");
    assert!(tool_set.released, "no particle was released");
    let all = PRESSED_BLOCK.replace(
        "activation_radius = 0.003\n",
        "activation_radius = 0.003\nactivation = \"all\"\n",
    );
    assert!(all.contains("\"all\""));
    let all = gated_against_full(&Scene::from_toml(&all, "all", "all", None).unwrap(), 3);
    eprintln!("all dynamic: {all:?}");
    assert_eq!((all.full, all.skipped), (1, all.intervals - 1));
    assert!(all.massless, "no vertex lost its mass");
}

/// What [`gated_against_full`] saw of the gated stepper.
#[derive(Debug)]
struct GateRun {
    intervals: u32,
    full: u32,
    skipped: u32,
    massless: bool,
    released: bool,
}

/// Run `scene` on two GPU steppers, one of them forced to a full activation at every update,
/// through a press, hold, withdrawal and wait of `per_leg` batches of one activation interval
/// each, asserting the same bits after each.
fn gated_against_full(scene: &Scene, per_leg: u32) -> GateRun {
    let m = Arc::new(Model::from_scene(scene));
    let params = m.step_params(0.5 * m.bounds.dt_bound, 50.0);
    let k = m.particles.as_ref().unwrap().settings.activation_interval;
    let mut gated = GpuStepper::new(gpu(), &m, params).unwrap();
    let mut full = GpuStepper::new(gpu(), &m, params).unwrap();
    // 12 intervals a leg take the pressed block past the release radius, the dwell and the
    // blend.
    let (mut massless, mut released, mut intervals) = (false, false, 0);
    for input in press_hold_withdraw_wait(per_leg) {
        full.raise_activation_gate().unwrap();
        for s in [&mut gated, &mut full] {
            s.submit(k, &input).unwrap();
            s.wait().unwrap();
        }
        intervals += 1;
        let counts = bits_u32(&gated, "particle_counts");
        assert_eq!(
            counts,
            bits_u32(&full, "particle_counts"),
            "interval {intervals}"
        );
        for (list, len) in [("dynamic_list", 0), ("stress_list", 1), ("force_list", 2)] {
            let len = counts[len] as usize;
            assert_eq!(
                bits_u32(&gated, list)[..len],
                bits_u32(&full, list)[..len],
                "{list} after interval {intervals}"
            );
        }
        assert_same_buffers(
            &gated,
            &full,
            &[
                "displacements",
                "velocities",
                "inv_mass",
                "mass",
                "node_flags",
                "coupled_count",
                "contact_weight",
                "tet_weight",
                "particle_dispatch",
                "particle_displacements",
                "particle_velocities",
                "particle_mode",
                "particle_timer",
            ],
            &format!("after interval {intervals}"),
        );
        massless |= bits_u32(&gated, "node_flags")
            .iter()
            .any(|f| f & palpate::particles::params::NODE_MASSLESS != 0);
        released |= bits_u32(&gated, "particle_mode")
            .iter()
            .any(|m| m & mode::BLENDING != 0);
    }
    let (runs, skips) = gated.activation_counts().unwrap();
    assert_eq!(runs + skips, intervals);
    assert_eq!(full.activation_counts().unwrap(), (intervals, 0));
    GateRun {
        intervals,
        full: runs,
        skipped: skips,
        massless,
        released,
    }
}

/// The GPU records `follow` on `fem_forces`' grid, `sph_stress` on `contact`'s (built with
/// `Fusions::All` only) and `integrate_particles` on `gather_coupled`'s
/// (`StepPlan::gpu_fusions`): three passes fewer a step. A stepper that
/// records them and one that records every stage's own passes, through a press, hold,
/// withdrawal (particles released and blending back) and wait, hold the same bits after every
/// interval: the fused kernels do the same arithmetic, and nothing the moved stages read is
/// written in between. With one particle sub-step, and with two (the first follow, the first
/// stress and the last integration fused); and with every particle dynamic, more than the host
/// grids have threads (the first two's fused grids grow and their rider loops take several
/// rounds; contact + sph_stress's indirect grid grows with S).
#[test]
fn fused_gpu_passes_equal_the_plan_s() {
    let m = Arc::new(Model::from_scene(&pressed_block()));
    let k = m.particles.as_ref().unwrap().settings.activation_interval;
    // The block's own sub-stepped step, then a quarter of its bound, which the particles take
    // in one sub-step; the same simulated time a batch.
    let half = 0.5 * m.bounds.dt_bound;
    // By default only the fusions measured to pay on a GPU are built.
    let measured = GpuStepper::with_fusions(
        gpu(),
        &m,
        m.step_params(half, 50.0),
        palpate::plan::Fusions::Measured,
    )
    .unwrap();
    assert_eq!(
        measured.fused_passes(),
        [
            (Stage::FemForces, Stage::Follow),
            (Stage::GatherCoupled, Stage::IntegrateParticles)
        ]
    );
    drop(measured);
    assert_eq!(m.particle_substeps(half), 2);
    assert_eq!(m.particle_substeps(0.5 * half), 1);
    for (dt, steps) in [(half, k), (0.5 * half, 2 * k)] {
        let (dynamic, blending) = fused_against_plain(&m, m.step_params(dt, 50.0), steps, 10);
        assert!(dynamic > 10, "the press woke {dynamic} particles");
        assert!(blending, "no particle was released");
    }
    let all = PRESSED_BLOCK.replace(
        "activation_radius = 0.003\n",
        "activation_radius = 0.003\nactivation = \"all\"\n",
    );
    let m = Arc::new(Model::from_scene(
        &Scene::from_toml(&all, "all", "all", None).unwrap(),
    ));
    let (dynamic, _) = fused_against_plain(&m, m.step_params(0.5 * half, 50.0), 2 * k, 2);
    // gather_coupled's own grid: 64 vertices and 256 threads a workgroup.
    let threads = m.n_vertices().div_ceil(64) * 256;
    assert!(
        dynamic as usize > threads && dynamic as usize > m.n_tets(),
        "{dynamic} dynamic against the gather's {threads} threads and {} tets",
        m.n_tets()
    );
}

/// A GPU stepper records the next batch while the GPU runs the one it submitted, where nothing
/// else is in flight (`GpuStepper::set_prerecord`), and uses it when the next submission asks
/// for the same batch. Through the press, hold, withdrawal and wait, against a stepper that
/// records every batch at its submission, with what would make a batch recorded ahead wrong
/// (another step count, the fused passes switched off, a restore to an earlier step, two
/// batches in flight), the two hold the same bits and reports after every batch, and most
/// batches were recorded ahead.
#[test]
fn batches_recorded_ahead_equal_batches_recorded_at_submission() {
    let m = Arc::new(Model::from_scene(&pressed_block()));
    let k = m.particles.as_ref().unwrap().settings.activation_interval;
    let params = m.step_params(0.5 * m.bounds.dt_bound, 50.0);
    let mut ahead = GpuStepper::new(gpu(), &m, params).unwrap();
    ahead.set_prerecord(true);
    let mut fresh = GpuStepper::new(gpu(), &m, params).unwrap();
    fresh.set_prerecord(false);
    let names = [
        "displacements",
        "velocities",
        "particle_displacements",
        "particle_velocities",
        "particle_mode",
        "particle_timer",
        "status",
    ];
    let inputs = press_hold_withdraw_wait(6);
    let batches = inputs.len() as u32;
    for (i, input) in inputs.iter().enumerate() {
        let i = i as u32;
        // Every fifth batch is shorter (the one recorded ahead has k steps).
        let steps = if i % 5 == 4 { k / 2 + 1 } else { k };
        if i == 2 {
            ahead.checkpoint().unwrap();
            fresh.checkpoint().unwrap();
        }
        if i == batches / 2 {
            for s in [&mut ahead, &mut fresh] {
                s.set_fusion(false);
                // Parameters are a buffer written at submission: the batch ahead stands.
                s.set_params(&params).unwrap();
            }
        }
        let reports: Vec<String> = if i == batches - 2 {
            // Two in flight: the second submission finds the first's batch ahead.
            [&mut ahead, &mut fresh]
                .into_iter()
                .map(|s| {
                    s.submit(steps, input).unwrap();
                    s.submit(steps, input).unwrap();
                    format!("{:?} {:?}", s.wait().unwrap(), s.wait().unwrap())
                })
                .collect()
        } else {
            [&mut ahead, &mut fresh]
                .into_iter()
                .map(|s| {
                    s.submit(steps, input).unwrap();
                    format!("{:?}", s.wait().unwrap())
                })
                .collect()
        };
        assert_eq!(reports[0], reports[1], "reports after batch {i}");
        assert_eq!(
            ahead.stage_counts(),
            fresh.stage_counts(),
            "stage runs of batch {i}"
        );
        assert_same_buffers(&ahead, &fresh, &names, &format!("after batch {i}"));
        if i == 5 {
            // Back to the checkpoint while the tool presses, to a step count whose place
            // among the activation steps (every k) is not the batch recorded ahead's.
            ahead.restore().unwrap();
            fresh.restore().unwrap();
            assert_same_buffers(&ahead, &fresh, &names, &format!("restored at batch {i}"));
        }
    }
    assert_eq!(fresh.batches_recorded_ahead(), 0);
    let used = ahead.batches_recorded_ahead();
    eprintln!("{used} of {batches} batches (and one more) were recorded ahead");
    assert!(
        used >= batches as u64 / 2,
        "only {used} of {batches} batches were recorded ahead"
    );
}

/// [`fused_gpu_passes_equal_the_plan_s`] at one step: batches of `steps` steps, `n` a leg of
/// the press; (the most dynamic particles, whether one blended back).
fn fused_against_plain(
    m: &Arc<Model>,
    params: palpate::params::StepParams,
    steps: u32,
    n: u32,
) -> (u32, bool) {
    let mut fused =
        GpuStepper::with_fusions(gpu(), m, params, palpate::plan::Fusions::All).unwrap();
    fused.set_fusion(true);
    let mut plain = GpuStepper::new(gpu(), m, params).unwrap();
    plain.set_fusion(false);
    assert_eq!(
        fused.fused_passes(),
        [
            (Stage::FemForces, Stage::Follow),
            (Stage::Contact, Stage::SphStress),
            (Stage::GatherCoupled, Stage::IntegrateParticles)
        ]
    );
    assert!(plain.fused_passes().is_empty());
    let (mut dynamic, mut blending, mut interval) = (0, false, 0);
    for input in press_hold_withdraw_wait(n) {
        let reports: Vec<_> = [&mut fused, &mut plain]
            .into_iter()
            .map(|s| {
                s.submit(steps, &input).unwrap();
                s.wait().unwrap()
            })
            .collect();
        interval += 1;
        assert_eq!(
            format!("{:?}", reports[0]),
            format!("{:?}", reports[1]),
            "reports after batch {interval}"
        );
        assert_same_buffers(
            &fused,
            &plain,
            &[
                "displacements",
                "velocities",
                "forces",
                "corner_forces",
                "particle_displacements",
                "particle_velocities",
                "particle_forces",
                "particle_force_sum",
                "particle_mode",
                "particle_timer",
                "status",
            ],
            &format!("after batch {interval} (dt {})", params.dt),
        );
        dynamic = dynamic.max(bits_u32(&fused, "particle_counts")[0]);
        blending |= bits_u32(&fused, "particle_mode")
            .iter()
            .any(|m| m & mode::BLENDING != 0);
    }
    eprintln!(
        "dt {}: at most {dynamic} dynamic particles; some blended back: {blending}",
        params.dt
    );
    (dynamic, blending)
}

/// The fused contact + sph_stress dispatch runs over the larger of the surface's grid and the
/// stress set's: with the tool pressing the block from below, where every particle within
/// reach is pinned by the fixed base (none wakes, S stays empty), the contact forces and the
/// reports equal those of the own passes bit for bit, and are not zero.
#[test]
fn the_fused_contact_runs_with_no_particle_awake() {
    let text = PRESSED_BLOCK.replace(
        "activation_radius = 0.003\n",
        "activation_radius = 0.0005\n",
    );
    let m = Arc::new(Model::from_scene(
        &Scene::from_toml(&text, "below", "below", None).unwrap(),
    ));
    let params = m.step_params(0.5 * m.bounds.dt_bound, 50.0);
    let mut fused =
        GpuStepper::with_fusions(gpu(), &m, params, palpate::plan::Fusions::All).unwrap();
    assert!(fused
        .fused_passes()
        .contains(&(Stage::Contact, Stage::SphStress)));
    let mut plain = GpuStepper::new(gpu(), &m, params).unwrap();
    plain.set_fusion(false);
    // The sphere's top 0.5 mm above the fixed base z = 0, under the block's middle.
    let below = BatchInput::moving(
        DVec3::new(0.01, 0.01, -0.0025),
        DVec3::new(0.01, 0.01, -0.0025),
    );
    for batch in 0..3 {
        let reports: Vec<String> = [&mut fused, &mut plain]
            .into_iter()
            .map(|s| {
                s.submit(10, &below).unwrap();
                format!("{:?}", s.wait().unwrap())
            })
            .collect();
        assert_eq!(reports[0], reports[1], "reports after batch {batch}");
        assert_same_buffers(
            &fused,
            &plain,
            &["contact_forces", "displacements", "particle_counts"],
            &format!("after batch {batch}"),
        );
        assert_eq!(bits_u32(&fused, "particle_counts")[..3], [0, 0, 0]);
    }
    let contact = bits_u32(&fused, "contact_forces");
    assert!(
        contact.iter().any(|&b| f32::from_bits(b) != 0.0),
        "the tool touches nothing"
    );
}

/// The fused contact + sph_stress dispatch takes the stress set in several rounds where its
/// grid does not cover it (its own grid always does: this one is narrowed to the surface's
/// after the batches that end between two activations, until the next activation sizes it
/// again): through the press, hold, withdrawal and wait in half-intervals, the same bits and
/// reports as the own passes, with S larger than the narrowed grid's 64-entry slots at times.
#[test]
fn the_fused_stress_takes_several_rounds_on_a_narrow_grid() {
    let (m, params) = pressed_block_model();
    let k = m.particles.as_ref().unwrap().settings.activation_interval;
    assert!(k % 2 == 0, "activation interval {k}");
    let mut fused =
        GpuStepper::with_fusions(gpu(), &m, params, palpate::plan::Fusions::All).unwrap();
    // Built (where it fell back to the own passes, the comparison below would be of a
    // stepper with itself).
    assert!(fused
        .fused_passes()
        .contains(&(Stage::Contact, Stage::SphStress)));
    let mut plain = GpuStepper::new(gpu(), &m, params).unwrap();
    plain.set_fusion(false);
    let groups = m.tool_params().n_surface.div_ceil(64);
    let mut most_rounds = 0;
    for (i, input) in press_hold_withdraw_wait(4).iter().enumerate() {
        let reports: Vec<String> = [&mut fused, &mut plain]
            .into_iter()
            .map(|s| {
                s.submit(k / 2, input).unwrap();
                format!("{:?}", s.wait().unwrap())
            })
            .collect();
        assert_eq!(reports[0], reports[1], "reports after batch {i}");
        assert_same_buffers(
            &fused,
            &plain,
            &[
                "displacements",
                "velocities",
                "contact_forces",
                "particle_displacements",
                "particle_stress",
            ],
            &format!("after batch {i}"),
        );
        if i % 2 == 0 {
            // The next batch runs between two activations: narrow its grid.
            let stress = bits_u32(&fused, "particle_counts")[1];
            most_rounds = most_rounds.max(stress.div_ceil(64 * groups));
            for s in [&fused, &plain] {
                let mut args = bits_u32(s, "particle_dispatch");
                args[9..12].copy_from_slice(&[groups, 1, 1]);
                let args: Vec<f32> = args.into_iter().map(f32::from_bits).collect();
                s.write_f32("particle_dispatch", &args).unwrap();
            }
        }
    }
    assert!(
        most_rounds >= 2,
        "the stress set never outgrew {groups} workgroups: at most {most_rounds} rounds"
    );
}

/// The particles' stable step counts the hourglass penalty's springs: at the default
/// coefficient (0.1) it moves lv_touch's particle bound by well under 1 % (no scene's step
/// or sub-steps change), and at the largest allowed (100) it shrinks it enough that the run
/// sub-steps the particles; above that the scene is refused (the penalty then drives the
/// mode it damps whatever the step).
#[test]
fn the_particle_step_bound_counts_the_hourglass_penalty() {
    let text = |hourglass: f64| {
        Scene::builtin_text("lv_touch").unwrap().replacen(
            "[particles]\n",
            &format!("[particles]\nhourglass = {hourglass}\nactivation = \"all\"\n"),
            1,
        )
    };
    let with = |hourglass: f64| {
        Scene::from_toml(&text(hourglass), "lv_touch variant", "lv_touch", None).unwrap()
    };
    let bound = |scene: &Scene| {
        let m = Model::from_scene(scene);
        let p = m.particles.as_ref().unwrap();
        let contact = m.tool.as_ref().map(|t| (t.tool.stiffness, t.tool.damping));
        (
            p.dt_bound(&m.material, contact),
            p.hourglass_omega(&m.material),
        )
    };
    let (none, omega_none) = bound(&with(0.0));
    let (default, omega_default) = bound(&with(0.1));
    let (stiff, omega_stiff) = bound(&with(100.0));
    assert_eq!(omega_none, 0.0);
    assert!(
        omega_default > 0.0 && default < none && default > 0.99 * none,
        "{default:e} against {none:e}"
    );
    // ω_h grows as sqrt(α).
    let ratio = omega_stiff / omega_default;
    assert!(
        (ratio / 1000f64.sqrt() - 1.0).abs() < 1e-9,
        "ω_h ratio {ratio}"
    );
    assert!(
        stiff < 0.8 * none,
        "α = 100: bound {stiff:e} against {none:e}"
    );
    let err = Scene::from_toml(&text(1000.0), "lv_touch variant", "lv_touch", None)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("particles.hourglass") && err.contains("[0, 100]"),
        "{err}"
    );
    // The run at α = 100 sub-steps its particles and stays quiet.
    let scene = with(100.0);
    let mut sim = palpate::sim::Simulation::new(
        &scene,
        palpate::sim::Backend::Cpu,
        palpate::sim::SimOptions::default(),
    )
    .unwrap();
    let substeps = sim.model.particle_substeps(sim.dt);
    assert!(substeps > 1, "{substeps} sub-steps");
    sim.advance(300)
        .expect("α = 100 stays finite for 300 steps");
}

/// The paper particle model computes StVK's stress whatever the material: a scene that pairs
/// it with another law is warned (run and haptic print the scene's warnings), one with StVK
/// or the tlsph model is not.
#[test]
fn the_paper_model_with_a_material_other_than_stvk_is_warned_of() {
    let with = |material: &str, model: &str| {
        let text = PRESSED_BLOCK
            .replace(
                "[material]\n",
                &format!("[material]\nmodel = \"{material}\"\n"),
            )
            .replace(
                "spacing = 0.001\n",
                &format!("spacing = 0.001\nmodel = \"{model}\"\n"),
            );
        Scene::from_toml(&text, "block", "block", None)
            .unwrap()
            .load_warnings
            .into_iter()
            .filter(|w| w.contains("particles.model = \"paper\""))
            .collect::<Vec<_>>()
    };
    let warned = with("stable_neohookean", "paper");
    assert!(
        warned.len() == 1
            && warned[0].contains("whatever [material] model says, here \"stable_neohookean\""),
        "{warned:?}"
    );
    assert!(with("stvk", "paper").is_empty());
    assert!(with("stable_neohookean", "tlsph").is_empty());
}

/// The particle sub-step count changed during a run (as [`palpate::substeps`] changes it when
/// the layer stiffens): on the soft pressed block (3 sub-steps at its core step), 100 steps
/// at 3, 100 at 5 and 100 at 4 sub-steps. Both backends then run the plan for 4 (stage
/// counts over the last batch), agree within 1e-4 relative after each batch, and measure
/// the same largest stiffening κ of the stressed particles (1e-4 relative; above 1: the
/// tool has squeezed the layer).
#[test]
fn particle_substeps_changed_during_a_run_match_between_backends() {
    let scene = soft_pressed_block(10);
    let m = Model::from_scene(&scene);
    let dt = palpate::sim::choose_dt(&scene, &m, None, false, false).unwrap();
    assert_eq!(m.particle_substeps(dt), 3);
    let run = |backend: palpate::sim::Backend| {
        let mut sim = palpate::sim::Simulation::new(
            &scene,
            backend,
            palpate::sim::SimOptions {
                gpu: (backend == palpate::sim::Backend::Gpu).then(gpu),
                ..Default::default()
            },
        )
        .unwrap();
        let mut out = Vec::new();
        let mut stiffening = Vec::new();
        for s in [3, 5, 4] {
            sim.fix_particle_substeps(s).unwrap();
            assert!(matches!(
                sim.advance(100).unwrap(),
                palpate::sim::Advance::Done(_)
            ));
            let (u, p) = (
                sim.state().unwrap().displacements,
                sim.particle_state().unwrap().unwrap().displacements,
            );
            stiffening.push(sim.particle_stiffening());
            out.push((
                u,
                p,
                sim.last_tool.unwrap().force,
                sim.last_particles.unwrap().dynamic,
            ));
        }
        (out, sim.stage_counts(), stiffening)
    };
    let (c, c_counts, c_k) = run(palpate::sim::Backend::Cpu);
    let (g, g_counts, g_k) = run(palpate::sim::Backend::Gpu);
    let plan = palpate::plan::StepPlan::for_model_at(&m, 4);
    let stages: Vec<Stage> = plan.stages.iter().map(|p| p.stage).collect();
    for (name, counts) in [("CPU", &c_counts), ("GPU", &g_counts)] {
        let planned: Vec<Stage> = counts.iter().map(|&(x, _)| x).collect();
        assert_eq!(planned, stages, "{name}: not the plan for 4 sub-steps");
        let total = |x: Stage| stage_runs(counts, x);
        assert_eq!(total(Stage::SphStress), 400, "{name}");
        assert_eq!(total(Stage::SphForcesAccumulate), 300, "{name}");
        assert_eq!(total(Stage::FemForces), 100, "{name}");
    }
    backends_agree("3, 5, 4 sub-steps, ", &c, &g);
    eprintln!("largest stiffening: CPU {c_k:?}, GPU {g_k:?}");
    for (a, b) in c_k.iter().zip(&g_k) {
        assert!((a / b - 1.0).abs() < 1e-4, "CPU {a} GPU {b}");
    }
    assert!(c_k[2] > 1.0, "the layer never stiffened: {c_k:?}");
}
