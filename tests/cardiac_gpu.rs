//! The cardiac kernels against their CPU twins on whatever adapter exists (lavapipe in CI):
//! `fem_forces_split` for every split law × U(J) × nodal/element × viscous, `tet_volume_change`,
//! `nodal_pressure`, `follower_pressure` and `follower_pressure_gather`, on random valid
//! inputs, relative error ≤ 1e-5.
//!
//! Until the engine wires these stages into its step plan, this test binds the buffers
//! itself through `gpu::kernel::ComputeKernel` (by name, in binding order).

#![allow(clippy::too_many_arguments)]

mod common;

use common::{gpu, jittered_beam, rel_err, tissue, Rng};
use palpate::cpu::fem_forces_split::{fem_forces_split, SplitVariant};
use palpate::cpu::follower_pressure::{follower_pressure, FollowerLoad};
use palpate::cpu::follower_pressure_gather::{follower_incidence, follower_pressure_gather};
use palpate::cpu::nodal_pressure::nodal_pressure;
use palpate::cpu::tet_volume_change::tet_volume_change;
use palpate::gpu::kernel::ComputeKernel;
use palpate::gpu::GpuContext;
use palpate::material::{GuccioneParams, HyperelasticParams, MaterialModel, VolumetricLaw};
use palpate::model::Model;
use std::sync::Arc;
use wgpu::util::DeviceExt;

const KERNEL_TOL: f64 = 1e-5;

/// A named GPU buffer with its contents' byte size.
struct Buf {
    name: &'static str,
    buffer: wgpu::Buffer,
    bytes: u64,
}

fn storage(ctx: &GpuContext, name: &'static str, data: &[u8]) -> Buf {
    // wgpu refuses zero-sized bindings: unused inputs get one padding word.
    let padded: Vec<u8> = if data.is_empty() {
        vec![0; 4]
    } else {
        data.to_vec()
    };
    Buf {
        name,
        buffer: ctx
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(name),
                contents: &padded,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            }),
        bytes: padded.len() as u64,
    }
}

fn uniform(ctx: &GpuContext, name: &'static str, data: &[u8]) -> Buf {
    Buf {
        name,
        buffer: ctx
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(name),
                contents: data,
                usage: wgpu::BufferUsages::UNIFORM,
            }),
        bytes: data.len() as u64,
    }
}

/// Run `kernel` over `items` threads with `buffers` in binding order; read back `outputs`.
fn run(
    ctx: &GpuContext,
    kernel: &str,
    constants: &[(&str, f64)],
    buffers: &[Buf],
    items: u32,
    outputs: &[&str],
) -> Vec<Vec<f32>> {
    let k = ComputeKernel::new(ctx, kernel, kernel, constants).expect("pipeline");
    // Bind by name: the buffers move into a registry, read back through it afterwards.
    let sizes: Vec<(&str, u64)> = buffers.iter().map(|b| (b.name, b.bytes)).collect();
    let registry = palpate::gpu::buffers::GpuBuffers::from_existing(
        buffers.iter().map(|b| (b.name, b.buffer.clone())).collect(),
    );
    let bound = k.bind(ctx, &registry, &[]).expect("bind");
    let mut enc = ctx.device.create_command_encoder(&Default::default());
    {
        let mut pass = enc.begin_compute_pass(&Default::default());
        k.record(
            &mut pass,
            &bound,
            palpate::gpu::kernel::Dispatch::Items(items),
            ctx.limits.max_compute_workgroups_per_dimension,
        );
    }
    let staging: Vec<(wgpu::Buffer, u64)> = outputs
        .iter()
        .map(|name| {
            let bytes = sizes
                .iter()
                .find(|(n, _)| n == name)
                .expect("output buffer")
                .1;
            let s = ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("staging"),
                size: bytes,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            enc.copy_buffer_to_buffer(registry.require(name).unwrap(), 0, &s, 0, bytes);
            (s, bytes)
        })
        .collect();
    ctx.queue.submit([enc.finish()]);
    staging
        .iter()
        .map(|(s, n)| bytemuck::cast_slice(&ctx.read_mapped(s, *n).expect("read")).to_vec())
        .collect()
}

fn f32s(v: &[f32]) -> &[u8] {
    bytemuck::cast_slice(v)
}

fn model() -> Arc<Model> {
    let mesh = jittered_beam([6, 4, 3], 42);
    let mut material = tissue();
    material.phi = 15.0;
    material.psi = 25.0;
    Arc::new(Model::new(
        &mesh,
        &vec![false; mesh.n_vertices()],
        material,
        [0.0; 3],
    ))
}

fn random(n: usize, amp: f64, rng: &mut Rng) -> Vec<f32> {
    (0..n).map(|_| (rng.sym() * amp) as f32).collect()
}

#[test]
fn fem_forces_split_and_the_nodal_average_stages_match_their_twins() {
    let ctx = gpu();
    let m = model();
    let p = m.step_params(1e-5, 0.0);
    let (nv, nt) = (m.n_vertices(), m.n_tets());
    let tets: Vec<u32> = m.tets.iter().flatten().copied().collect();
    let mut rng = Rng(3);
    let fibres: Vec<f32> = (0..nt)
        .flat_map(|_| {
            let f = rng.vec();
            [f.x as f32, f.y as f32, f.z as f32] // not normalised: the kernel normalises
        })
        .collect();
    let mut worst = 0.0f64;
    for model_kind in MaterialModel::SPLIT {
        for law in VolumetricLaw::ALL {
            for nodal in [false, true] {
                let viscous = nodal; // both on and off, without multiplying the cases
                let mut h = HyperelasticParams::new(50.0 * m.material.mu);
                h.volumetric = law;
                h.guccione = GuccioneParams::new(0.25 * m.material.mu, 8.0, 2.0, 4.0);
                let c = h.constants();
                // Large enough to rotate and stretch elements (|H| up to ~0.2).
                let u = random(3 * nv, 4e-4, &mut rng);
                let v = random(3 * nv, 0.05, &mut rng);

                // Stage 1–2 (nodal average).
                let mut delta = vec![0.0; nt];
                tet_volume_change(&p, &u, &m.tets, &m.dm_inv, &m.rest_volume, &mut delta);
                let gpu_delta = run(
                    &ctx,
                    "tet_volume_change",
                    &[],
                    &[
                        uniform(&ctx, "params", bytemuck::bytes_of(&p)),
                        storage(&ctx, "displacements", f32s(&u)),
                        storage(&ctx, "tets", bytemuck::cast_slice(&tets)),
                        storage(&ctx, "dm_inv", f32s(&m.dm_inv)),
                        storage(&ctx, "rest_volume", f32s(&m.rest_volume)),
                        storage(&ctx, "tet_delta_volume", f32s(&vec![0.0; nt])),
                    ],
                    nt as u32,
                    &["tet_delta_volume"],
                );
                let e_delta = rel_err(&gpu_delta[0][..nt], &delta);
                let (mut vp, mut ve) = (vec![0.0; nv], vec![0.0; nv]);
                nodal_pressure(
                    &p,
                    &c,
                    &m.incidence_offsets,
                    &m.incidence,
                    &m.rest_volume,
                    &delta,
                    &mut vp,
                    &mut ve,
                    law,
                );
                let gpu_nodal = run(
                    &ctx,
                    "nodal_pressure",
                    &[("VOLUMETRIC", law as u32 as f64)],
                    &[
                        uniform(&ctx, "params", bytemuck::bytes_of(&p)),
                        uniform(&ctx, "material_constants", bytemuck::bytes_of(&c)),
                        storage(
                            &ctx,
                            "incidence_offsets",
                            bytemuck::cast_slice(&m.incidence_offsets),
                        ),
                        storage(&ctx, "incidence", bytemuck::cast_slice(&m.incidence)),
                        storage(&ctx, "rest_volume", f32s(&m.rest_volume)),
                        storage(&ctx, "tet_delta_volume", f32s(&delta)),
                        storage(&ctx, "vertex_pressure", f32s(&vec![0.0; nv])),
                        storage(&ctx, "vertex_volumetric_energy", f32s(&vec![0.0; nv])),
                    ],
                    nv as u32,
                    &["vertex_pressure", "vertex_volumetric_energy"],
                );
                let e_vp = rel_err(&gpu_nodal[0][..nv], &vp);
                let e_ve = rel_err(&gpu_nodal[1][..nv], &ve);

                // Stage 3.
                let variant = SplitVariant {
                    model: model_kind,
                    viscous,
                    volumetric: law,
                    nodal_pressure: nodal,
                };
                let (mut corner, mut energy) = (vec![0.0; 12 * nt], vec![0.0; nt]);
                fem_forces_split(
                    &p,
                    &c,
                    &u,
                    &v,
                    &m.tets,
                    &m.dm_inv,
                    &m.rest_volume,
                    &fibres,
                    &vp,
                    &ve,
                    &mut corner,
                    &mut energy,
                    variant,
                );
                let out = run(
                    &ctx,
                    "fem_forces_split",
                    &[
                        ("MATERIAL", model_kind as u32 as f64),
                        ("VISCOUS", viscous as u32 as f64),
                        ("VOLUMETRIC", law as u32 as f64),
                        ("NODAL_PRESSURE", nodal as u32 as f64),
                    ],
                    &[
                        uniform(&ctx, "params", bytemuck::bytes_of(&p)),
                        uniform(&ctx, "material_constants", bytemuck::bytes_of(&c)),
                        storage(&ctx, "displacements", f32s(&u)),
                        storage(&ctx, "velocities", f32s(&v)),
                        storage(&ctx, "tets", bytemuck::cast_slice(&tets)),
                        storage(&ctx, "dm_inv", f32s(&m.dm_inv)),
                        storage(&ctx, "rest_volume", f32s(&m.rest_volume)),
                        storage(&ctx, "fibres", f32s(&fibres)),
                        storage(&ctx, "vertex_pressure", f32s(&vp)),
                        storage(&ctx, "vertex_volumetric_energy", f32s(&ve)),
                        storage(&ctx, "corner_forces", f32s(&vec![0.0; 12 * nt])),
                        storage(&ctx, "tet_energy", f32s(&vec![0.0; nt])),
                    ],
                    nt as u32,
                    &["corner_forces", "tet_energy"],
                );
                let ec = rel_err(&out[0][..12 * nt], &corner);
                let ee = rel_err(&out[1][..nt], &energy);
                eprintln!(
                    "{:>24} {:<11} nodal {nodal:<5}: corner forces {ec:.1e}, energy {ee:.1e}; tet_volume_change {e_delta:.1e}, nodal_pressure {e_vp:.1e}/{e_ve:.1e}",
                    model_kind.name(),
                    law.name()
                );
                for e in [ec, ee, e_delta, e_vp, e_ve] {
                    worst = worst.max(e);
                }
            }
        }
    }
    eprintln!("adapter {}: worst rel err {worst:.2e}", ctx.describe());
    assert!(worst <= KERNEL_TOL, "{worst:.2e}");
}

#[test]
fn follower_pressure_stages_match_their_twins() {
    let ctx = gpu();
    let mesh = jittered_beam([6, 4, 3], 8);
    let faces = mesh.boundary_faces();
    let nv = mesh.n_vertices();
    let rest: Vec<f32> = mesh
        .positions
        .iter()
        .flat_map(|p| p.to_array().map(|c| c as f32))
        .collect();
    let mut rng = Rng(12);
    let u = random(3 * nv, 1e-3, &mut rng);
    let pressure: Vec<f32> = (0..faces.len())
        .map(|_| (1000.0 + 500.0 * rng.sym()) as f32)
        .collect();
    let dead = random(3 * nv, 1e-2, &mut rng);
    let flat: Vec<u32> = faces.iter().flatten().copied().collect();
    let load = FollowerLoad {
        n_faces: faces.len() as u32,
        load_factor: 0.7,
        ..Default::default()
    };
    let mut corner = vec![0.0; 9 * faces.len()];
    follower_pressure(&load, &rest, &u, &flat, &pressure, &mut corner);
    let gpu_corner = run(
        &ctx,
        "follower_pressure",
        &[],
        &[
            uniform(&ctx, "follower_load", bytemuck::bytes_of(&load)),
            storage(&ctx, "rest_positions", f32s(&rest)),
            storage(&ctx, "displacements", f32s(&u)),
            storage(&ctx, "follower_faces", bytemuck::cast_slice(&flat)),
            storage(&ctx, "follower_face_pressure", f32s(&pressure)),
            storage(
                &ctx,
                "follower_corner_forces",
                f32s(&vec![0.0; corner.len()]),
            ),
        ],
        faces.len() as u32,
        &["follower_corner_forces"],
    );
    let ec = rel_err(&gpu_corner[0][..corner.len()], &corner);

    let (offsets, incidence) = follower_incidence(nv, &faces);
    let p = palpate::params::StepParams {
        n_vertices: nv as u32,
        ..Default::default()
    };
    let mut external = vec![0.0; 3 * nv];
    follower_pressure_gather(&p, &corner, &offsets, &incidence, &dead, &mut external);
    let gpu_external = run(
        &ctx,
        "follower_pressure_gather",
        &[],
        &[
            uniform(&ctx, "params", bytemuck::bytes_of(&p)),
            storage(&ctx, "follower_corner_forces", f32s(&corner)),
            storage(
                &ctx,
                "follower_incidence_offsets",
                bytemuck::cast_slice(&offsets),
            ),
            storage(&ctx, "follower_incidence", bytemuck::cast_slice(&incidence)),
            storage(&ctx, "dead_load_forces", f32s(&dead)),
            storage(&ctx, "external_forces", f32s(&vec![0.0; 3 * nv])),
        ],
        nv as u32,
        &["external_forces"],
    );
    let eg = rel_err(&gpu_external[0][..3 * nv], &external);
    eprintln!(
        "follower_pressure {ec:.1e}, follower_pressure_gather {eg:.1e} ({})",
        ctx.describe()
    );
    assert!(ec <= KERNEL_TOL && eg <= KERNEL_TOL, "{ec:.2e} {eg:.2e}");
}
