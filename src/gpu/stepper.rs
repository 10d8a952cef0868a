//! The GPU backend: records many steps into one command buffer (fem_forces → gather →
//! integrate, and reduce where needed), with bind groups built once, and reads back only the
//! 48-byte stats/status block at the end of a batch.

use crate::error::{PalpateError, Result};
use crate::gpu::buffers::{SimBuffers, STATS_BYTES, STATUS_BYTES};
use crate::gpu::kernel::BoundKernel;
use crate::gpu::kernels::{FemForces, Gather, Integrate, Reduce};
use crate::gpu::GpuContext;
use crate::model::Model;
use crate::params::{stat, StepParams};
use crate::stepper::{BatchStats, State, Stepper};
use std::sync::Arc;

/// Pipelines of one step (stateless; shared by any number of simulations on a device).
pub struct StepPipelines {
    /// fem_forces.wgsl.
    pub fem_forces: FemForces,
    /// gather.wgsl.
    pub gather: Gather,
    /// integrate.wgsl.
    pub integrate: Integrate,
    /// reduce.wgsl.
    pub reduce: Reduce,
}

impl StepPipelines {
    /// Build the pipelines; `variant` picks the fem_forces specialisation.
    pub fn new(
        ctx: &GpuContext,
        variant: crate::cpu::fem_forces::FemVariant,
    ) -> Result<StepPipelines> {
        Ok(StepPipelines {
            fem_forces: FemForces::new(ctx, variant)?,
            gather: Gather::new(ctx)?,
            integrate: Integrate::new(ctx)?,
            reduce: Reduce::new(ctx)?,
        })
    }
}

/// One stage of a step, for running kernels one at a time (tests, bisecting a mismatch).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// fem_forces.wgsl.
    FemForces,
    /// gather.wgsl.
    Gather,
    /// integrate.wgsl.
    Integrate,
    /// reduce.wgsl (both entry points).
    Reduce,
}

/// Mean GPU time per stage of one step, from timestamp queries, ns.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageTimes {
    /// fem_forces.
    pub fem_forces_ns: f64,
    /// gather.
    pub gather_ns: f64,
    /// integrate.
    pub integrate_ns: f64,
    /// reduce (both entry points).
    pub reduce_ns: f64,
}

struct Bound {
    fem_forces: BoundKernel,
    gather: BoundKernel,
    integrate: BoundKernel,
    reduce_partial: BoundKernel,
    reduce_final: BoundKernel,
}

/// GPU stepper for one model.
pub struct GpuStepper {
    ctx: Arc<GpuContext>,
    pipelines: StepPipelines,
    buffers: SimBuffers,
    bound: Bound,
    params: StepParams,
    n: u64,
}

impl GpuStepper {
    /// Upload `model` and build pipelines and bind groups.
    pub fn new(ctx: Arc<GpuContext>, model: &Model, params: StepParams) -> Result<GpuStepper> {
        let buffers = SimBuffers::new(&ctx, model, &params)?;
        let pipelines = StepPipelines::new(&ctx, model.fem_variant())?;
        let (n, m) = (model.n_vertices() as u64, model.n_tets() as u64);
        let (reduce_partial, reduce_final) = pipelines.reduce.bind(&ctx, &buffers, n, m)?;
        let bound = Bound {
            fem_forces: pipelines.fem_forces.bind(&ctx, &buffers, n, m)?,
            gather: pipelines.gather.bind(&ctx, &buffers, n, m)?,
            integrate: pipelines.integrate.bind(&ctx, &buffers, n)?,
            reduce_partial,
            reduce_final,
        };
        Ok(GpuStepper {
            ctx,
            pipelines,
            buffers,
            bound,
            params,
            n,
        })
    }

    /// The context this stepper runs on.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// Record `steps` steps into `encoder` (one compute pass).
    pub fn record_steps(&self, encoder: &mut wgpu::CommandEncoder, steps: u32) {
        let p = &self.pipelines;
        let b = &self.bound;
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("steps"),
            timestamp_writes: None,
        });
        for s in 0..steps {
            p.fem_forces.fem_forces.record(&mut pass, &b.fem_forces);
            p.gather.gather.record(&mut pass, &b.gather);
            p.integrate.integrate.record(&mut pass, &b.integrate);
            if s + 1 == steps {
                p.reduce.reduce_partial.record(&mut pass, &b.reduce_partial);
                p.reduce.reduce_final.record_one(&mut pass, &b.reduce_final);
            }
        }
    }

    /// Run a single stage on the current buffers and wait.
    pub fn run_stage(&self, stage: Stage) -> Result<()> {
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            self.record_stage(&mut pass, stage);
        }
        self.ctx.queue.submit([enc.finish()]);
        self.ctx.wait()
    }

    /// Time each stage with timestamp queries over `reps` steps (one compute pass per stage,
    /// reduce included every step); None when the device has no timestamp queries.
    pub fn profile_stages(&mut self, reps: u32) -> Result<Option<StageTimes>> {
        if !self
            .ctx
            .device
            .features()
            .contains(wgpu::Features::TIMESTAMP_QUERY)
        {
            return Ok(None);
        }
        let reps = reps.clamp(1, 100);
        let count = 8 * reps;
        let d = &self.ctx.device;
        let queries = d.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some("stage timestamps"),
            ty: wgpu::QueryType::Timestamp,
            count,
        });
        let bytes = 8 * count as u64;
        let resolve = d.create_buffer(&wgpu::BufferDescriptor {
            label: Some("timestamps"),
            size: bytes,
            usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let staging = d.create_buffer(&wgpu::BufferDescriptor {
            label: Some("timestamps readback"),
            size: bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc = d.create_command_encoder(&Default::default());
        let stages = [
            Stage::FemForces,
            Stage::Gather,
            Stage::Integrate,
            Stage::Reduce,
        ];
        for r in 0..reps {
            for (k, stage) in stages.iter().enumerate() {
                let q = 2 * (4 * r + k as u32);
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("profiled stage"),
                    timestamp_writes: Some(wgpu::ComputePassTimestampWrites {
                        query_set: &queries,
                        beginning_of_pass_write_index: Some(q),
                        end_of_pass_write_index: Some(q + 1),
                    }),
                });
                self.record_stage(&mut pass, *stage);
            }
        }
        enc.resolve_query_set(&queries, 0..count, &resolve, 0);
        enc.copy_buffer_to_buffer(&resolve, 0, &staging, 0, bytes);
        self.ctx.queue.submit([enc.finish()]);
        let raw = self.ctx.read_mapped(&staging, bytes)?;
        let ticks: &[u64] = bytemuck::cast_slice(&raw);
        let period = self.ctx.queue.get_timestamp_period() as f64;
        let mean = |k: usize| {
            (0..reps as usize)
                .map(|r| {
                    ticks[2 * (4 * r + k) + 1].saturating_sub(ticks[2 * (4 * r + k)]) as f64
                        * period
                })
                .sum::<f64>()
                / reps as f64
        };
        Ok(Some(StageTimes {
            fem_forces_ns: mean(0),
            gather_ns: mean(1),
            integrate_ns: mean(2),
            reduce_ns: mean(3),
        }))
    }

    fn record_stage(&self, pass: &mut wgpu::ComputePass<'_>, stage: Stage) {
        let p = &self.pipelines;
        let b = &self.bound;
        match stage {
            Stage::FemForces => p.fem_forces.fem_forces.record(pass, &b.fem_forces),
            Stage::Gather => p.gather.gather.record(pass, &b.gather),
            Stage::Integrate => p.integrate.integrate.record(pass, &b.integrate),
            Stage::Reduce => {
                p.reduce.reduce_partial.record(pass, &b.reduce_partial);
                p.reduce.reduce_final.record_one(pass, &b.reduce_final);
            }
        }
    }

    /// Overwrite a storage buffer of f32 (`forces`, `corner_forces`, `tet_energy`,
    /// `displacements`, `velocities`, `stats`) from the start (tests and debugging).
    pub fn write_f32(&self, which: &str, data: &[f32]) -> Result<()> {
        let buf = self.buffer(which)?;
        if (data.len() * 4) as u64 > buf.size() {
            return Err(PalpateError::Gpu(format!(
                "{} floats do not fit buffer '{which}'",
                data.len()
            )));
        }
        self.ctx
            .queue
            .write_buffer(buf, 0, bytemuck::cast_slice(data));
        self.ctx.wait()
    }

    fn buffer(&self, which: &str) -> Result<&wgpu::Buffer> {
        let b = &self.buffers;
        Ok(match which {
            "forces" => &b.forces,
            "corner_forces" => &b.corner_forces,
            "tet_energy" => &b.tet_energy,
            "displacements" => &b.displacements,
            "velocities" => &b.velocities,
            "stats" => &b.stats,
            "status" => &b.status,
            other => return Err(PalpateError::Gpu(format!("no buffer '{other}'"))),
        })
    }

    /// Run `steps` steps without any readback (for benchmarks); waits for completion.
    pub fn run_no_readback(&mut self, steps: u32) -> Result<()> {
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        self.record_steps(&mut enc, steps);
        self.ctx.queue.submit([enc.finish()]);
        self.ctx.wait()
    }

    /// Read a storage buffer of f32 (see [`GpuStepper::write_f32`]; `status` reads as bits).
    pub fn read_f32(&self, which: &str) -> Result<Vec<f32>> {
        let buf = self.buffer(which)?;
        let size = buf.size();
        let staging = self.ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("read_f32"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(buf, 0, &staging, 0, size);
        self.ctx.queue.submit([enc.finish()]);
        let bytes = self.ctx.read_mapped(&staging, size)?;
        Ok(bytemuck::cast_slice(&bytes).to_vec())
    }
}

impl Stepper for GpuStepper {
    fn name(&self) -> String {
        self.ctx.describe()
    }

    fn set_params(&mut self, params: &StepParams) -> Result<()> {
        self.params = *params;
        self.ctx
            .queue
            .write_buffer(&self.buffers.params, 0, bytemuck::bytes_of(params));
        Ok(())
    }

    fn run(&mut self, steps: u32) -> Result<BatchStats> {
        let b = &self.buffers;
        let q = &self.ctx.queue;
        q.write_buffer(&b.status, 0, bytemuck::cast_slice(&[u32::MAX; 4]));
        let mut enc = self
            .ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("batch"),
            });
        let state_bytes = 12 * self.n;
        enc.copy_buffer_to_buffer(
            &b.displacements,
            0,
            &b.snapshot_displacements,
            0,
            state_bytes,
        );
        enc.copy_buffer_to_buffer(&b.velocities, 0, &b.snapshot_velocities, 0, state_bytes);
        enc.copy_buffer_to_buffer(&b.stats, 0, &b.snapshot_stats, 0, STATS_BYTES);
        self.record_steps(&mut enc, steps);
        enc.copy_buffer_to_buffer(&b.stats, 0, &b.readback_small, 0, STATS_BYTES);
        enc.copy_buffer_to_buffer(&b.status, 0, &b.readback_small, STATS_BYTES, STATUS_BYTES);
        q.submit([enc.finish()]);
        let bytes = self
            .ctx
            .read_mapped(&b.readback_small, STATS_BYTES + STATUS_BYTES)?;
        let floats: &[f32] = bytemuck::cast_slice(&bytes[..STATS_BYTES as usize]);
        let status: &[u32] = bytemuck::cast_slice(&bytes[STATS_BYTES as usize..]);
        let mut out = BatchStats::default();
        out.stats.copy_from_slice(&floats[..stat::LEN]);
        out.non_finite_vertex = (status[0] != u32::MAX).then_some(status[0]);
        Ok(out)
    }

    fn restore(&mut self) -> Result<()> {
        let b = &self.buffers;
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        let state_bytes = 12 * self.n;
        enc.copy_buffer_to_buffer(
            &b.snapshot_displacements,
            0,
            &b.displacements,
            0,
            state_bytes,
        );
        enc.copy_buffer_to_buffer(&b.snapshot_velocities, 0, &b.velocities, 0, state_bytes);
        enc.copy_buffer_to_buffer(&b.snapshot_stats, 0, &b.stats, 0, STATS_BYTES);
        self.ctx.queue.submit([enc.finish()]);
        self.ctx.wait()
    }

    fn read_state(&mut self) -> Result<State> {
        let b = &self.buffers;
        let bytes = 12 * self.n;
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(&b.displacements, 0, &b.readback_state, 0, bytes);
        enc.copy_buffer_to_buffer(&b.velocities, 0, &b.readback_state, bytes, bytes);
        self.ctx.queue.submit([enc.finish()]);
        let data = self.ctx.read_mapped(&b.readback_state, 2 * bytes)?;
        let all: &[f32] = bytemuck::cast_slice(&data);
        let k = 3 * self.n as usize;
        Ok(State {
            displacements: all[..k].to_vec(),
            velocities: all[k..].to_vec(),
        })
    }

    fn write_state(&mut self, state: &State) -> Result<()> {
        let b = &self.buffers;
        let q = &self.ctx.queue;
        q.write_buffer(
            &b.displacements,
            0,
            bytemuck::cast_slice(&state.displacements),
        );
        q.write_buffer(&b.velocities, 0, bytemuck::cast_slice(&state.velocities));
        q.write_buffer(&b.stats, 0, bytemuck::cast_slice(&[0f32; stat::LEN]));
        self.ctx.wait()
    }
}
