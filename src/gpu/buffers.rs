//! The simulation's GPU data: structure-of-arrays storage buffers (one per quantity), made
//! once per model, separate from the pipelines. Sizes are checked against the adapter's
//! limits first, so a mesh that does not fit gets a clear error instead of a wgpu panic.

use crate::cpu::reduce::PARTIAL_LEN;
use crate::error::{PalpateError, Result};
use crate::gpu::kernel::grid_for;
use crate::gpu::GpuContext;
use crate::model::Model;
use crate::params::{stat, StepParams};
use wgpu::util::DeviceExt;
use wgpu::BufferUsages as U;

/// Storage, copy-in and copy-out usages for simulation buffers.
const STORAGE: U = U::STORAGE.union(U::COPY_DST).union(U::COPY_SRC);

/// All buffers of one simulation.
pub struct SimBuffers {
    /// `StepParams` uniform.
    pub params: wgpu::Buffer,
    /// Displacements u = x − X, 3 f32 per vertex.
    pub displacements: wgpu::Buffer,
    /// Velocities, 3 f32 per vertex.
    pub velocities: wgpu::Buffer,
    /// Tets, 4 u32 each.
    pub tets: wgpu::Buffer,
    /// Dm⁻¹, 9 f32 per tet.
    pub dm_inv: wgpu::Buffer,
    /// Rest volume per tet.
    pub rest_volume: wgpu::Buffer,
    /// Corner forces, 12 f32 per tet.
    pub corner_forces: wgpu::Buffer,
    /// Elastic energy per tet.
    pub tet_energy: wgpu::Buffer,
    /// CSR offsets, n+1 u32.
    pub incidence_offsets: wgpu::Buffer,
    /// CSR corner ids, 4 u32 per tet.
    pub incidence: wgpu::Buffer,
    /// Lumped mass per vertex.
    pub mass: wgpu::Buffer,
    /// Inverse mass per vertex (0 = fixed).
    pub inv_mass: wgpu::Buffer,
    /// Constant external force per vertex, 3 f32.
    pub external_forces: wgpu::Buffer,
    /// Per-vertex force, 3 f32.
    pub forces: wgpu::Buffer,
    /// Reduction partials, 6 f32 per block of 256.
    pub partials: wgpu::Buffer,
    /// The 8-float stats (see [`crate::params::stat`]).
    pub stats: wgpu::Buffer,
    /// status[0]: lowest non-finite vertex, or u32::MAX.
    pub status: wgpu::Buffer,
    /// Snapshot of displacements at the start of a batch.
    pub snapshot_displacements: wgpu::Buffer,
    /// Snapshot of velocities at the start of a batch.
    pub snapshot_velocities: wgpu::Buffer,
    /// Snapshot of stats at the start of a batch.
    pub snapshot_stats: wgpu::Buffer,
    /// Host-readable copy of stats + status (48 bytes).
    pub readback_small: wgpu::Buffer,
    /// Host-readable copy of displacements and velocities.
    pub readback_state: wgpu::Buffer,
}

/// Bytes of the stats buffer.
pub const STATS_BYTES: u64 = (stat::LEN * 4) as u64;
/// Bytes of the status buffer.
pub const STATUS_BYTES: u64 = 16;

impl SimBuffers {
    /// Upload a model. Fails with [`PalpateError::TooBigForAdapter`] when a buffer exceeds
    /// the adapter's storage-binding or buffer-size limit.
    pub fn new(ctx: &GpuContext, model: &Model, params: &StepParams) -> Result<SimBuffers> {
        let n = model.n_vertices() as u64;
        let m = model.n_tets() as u64;
        let blocks = {
            let (x, y) = grid_for(
                model.n_vertices().max(model.n_tets()) as u32,
                crate::cpu::REDUCE_WORKGROUP as u32,
                ctx.limits.max_compute_workgroups_per_dimension,
            );
            x as u64 * y as u64
        };
        // Largest first, so the error names the buffer that overflows most.
        let mut sizes: [(&str, u64); 10] = [
            ("displacements", 12 * n),
            ("tets", 16 * m),
            ("dm_inv", 36 * m),
            ("corner_forces", 48 * m),
            ("incidence", 16 * m),
            ("incidence_offsets", 4 * (n + 1)),
            ("forces", 12 * n),
            ("partials", 4 * PARTIAL_LEN as u64 * blocks),
            ("readback_state", 24 * n),
            ("tet_energy", 4 * m),
        ];
        sizes.sort_by_key(|(_, bytes)| std::cmp::Reverse(*bytes));
        for (name, bytes) in sizes {
            let (limit, what) = if name == "readback_state" {
                (ctx.limits.max_buffer_size, "buffer")
            } else {
                (
                    ctx.limits
                        .max_storage_buffer_binding_size
                        .min(ctx.limits.max_buffer_size),
                    "storage binding",
                )
            };
            if bytes > limit || n > u32::MAX as u64 / 4 || m > u32::MAX as u64 / 4 {
                return Err(PalpateError::TooBigForAdapter {
                    adapter: ctx.info.name.clone(),
                    buffer: name.into(),
                    bytes,
                    limit,
                    what: what.into(),
                });
            }
        }
        let scope = ctx.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let d = &ctx.device;
        let init = |label: &str, contents: &[u8], usage: U| {
            d.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage,
            })
        };
        let empty = |label: &str, size: u64, usage: U| {
            d.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: size.max(4),
                usage,
                mapped_at_creation: false,
            })
        };
        let zeros3 = vec![0f32; 3 * n as usize];
        let stats_init = [0f32; stat::LEN];
        let bufs = SimBuffers {
            params: init(
                "params",
                bytemuck::bytes_of(params),
                U::UNIFORM | U::COPY_DST,
            ),
            displacements: init("displacements", bytemuck::cast_slice(&zeros3), STORAGE),
            velocities: init("velocities", bytemuck::cast_slice(&zeros3), STORAGE),
            tets: init("tets", bytemuck::cast_slice(&model.tets), STORAGE),
            dm_inv: init("dm_inv", bytemuck::cast_slice(&model.dm_inv), STORAGE),
            rest_volume: init(
                "rest_volume",
                bytemuck::cast_slice(&model.rest_volume),
                STORAGE,
            ),
            corner_forces: empty("corner_forces", 48 * m, STORAGE),
            tet_energy: empty("tet_energy", 4 * m, STORAGE),
            incidence_offsets: init(
                "incidence_offsets",
                bytemuck::cast_slice(&model.incidence_offsets),
                STORAGE,
            ),
            incidence: init("incidence", bytemuck::cast_slice(&model.incidence), STORAGE),
            mass: init("mass", bytemuck::cast_slice(&model.mass), STORAGE),
            inv_mass: init("inv_mass", bytemuck::cast_slice(&model.inv_mass), STORAGE),
            forces: empty("forces", 12 * n, STORAGE),
            external_forces: init(
                "external_forces",
                bytemuck::cast_slice(&model.external_forces),
                STORAGE,
            ),
            partials: empty("partials", 4 * PARTIAL_LEN as u64 * blocks, STORAGE),
            stats: init("stats", bytemuck::cast_slice(&stats_init), STORAGE),
            status: init("status", bytemuck::cast_slice(&[u32::MAX; 4]), STORAGE),
            snapshot_displacements: empty("snapshot_displacements", 12 * n, STORAGE),
            snapshot_velocities: empty("snapshot_velocities", 12 * n, STORAGE),
            snapshot_stats: empty("snapshot_stats", STATS_BYTES, STORAGE),
            readback_small: empty(
                "readback_small",
                STATS_BYTES + STATUS_BYTES,
                U::MAP_READ | U::COPY_DST,
            ),
            readback_state: empty("readback_state", 24 * n, U::MAP_READ | U::COPY_DST),
        };
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(PalpateError::Gpu(format!(
                "out of GPU memory uploading {} vertices / {} tets on '{}': {e}",
                n, m, ctx.info.name
            )));
        }
        ctx.check_errors()?;
        Ok(bufs)
    }
}
