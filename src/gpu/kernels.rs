//! One struct per kernel file, each holding its pipeline(s) and a typed `bind` that names
//! every buffer in the shader's binding order with the size it must have.

use crate::error::Result;
use crate::gpu::buffers::{SimBuffers, STATS_BYTES, STATUS_BYTES};
use crate::gpu::kernel::{BoundKernel, ComputeKernel};
use crate::gpu::GpuContext;
use crate::params::StepParams;

const PARAMS_BYTES: u64 = std::mem::size_of::<StepParams>() as u64;

/// `kernels/fem_forces.wgsl`.
pub struct FemForces {
    /// Entry point `fem_forces`, specialised by the `MATERIAL` and `VISCOUS` constants.
    pub fem_forces: ComputeKernel,
}

impl FemForces {
    /// Build the variant (material model, with or without the viscous terms).
    pub fn new(ctx: &GpuContext, variant: crate::cpu::fem_forces::FemVariant) -> Result<Self> {
        let constants = [
            ("MATERIAL", variant.model as u32 as f64),
            ("VISCOUS", if variant.viscous { 1.0 } else { 0.0 }),
        ];
        Ok(FemForces {
            fem_forces: ComputeKernel::new(ctx, "fem_forces", "fem_forces", &constants)?,
        })
    }

    /// Bind for `n` vertices and `m` tets.
    pub fn bind(&self, ctx: &GpuContext, b: &SimBuffers, n: u64, m: u64) -> Result<BoundKernel> {
        self.fem_forces.bind(
            ctx,
            &[
                ("params", &b.params, PARAMS_BYTES),
                ("displacements", &b.displacements, 12 * n),
                ("velocities", &b.velocities, 12 * n),
                ("tets", &b.tets, 16 * m),
                ("dm_inv", &b.dm_inv, 36 * m),
                ("rest_volume", &b.rest_volume, 4 * m),
                ("corner_forces", &b.corner_forces, 48 * m),
                ("tet_energy", &b.tet_energy, 4 * m),
            ],
            m as u32,
        )
    }
}

/// `kernels/gather.wgsl`.
pub struct Gather {
    /// Entry point `gather`.
    pub gather: ComputeKernel,
}

impl Gather {
    /// Build.
    pub fn new(ctx: &GpuContext) -> Result<Self> {
        Ok(Gather {
            gather: ComputeKernel::new(ctx, "gather", "gather", &[])?,
        })
    }

    /// Bind for `n` vertices and `m` tets.
    pub fn bind(&self, ctx: &GpuContext, b: &SimBuffers, n: u64, m: u64) -> Result<BoundKernel> {
        self.gather.bind(
            ctx,
            &[
                ("params", &b.params, PARAMS_BYTES),
                ("corner_forces", &b.corner_forces, 48 * m),
                ("incidence_offsets", &b.incidence_offsets, 4 * (n + 1)),
                ("incidence", &b.incidence, 16 * m),
                ("mass", &b.mass, 4 * n),
                ("external_forces", &b.external_forces, 12 * n),
                ("forces", &b.forces, 12 * n),
            ],
            n as u32,
        )
    }
}

/// `kernels/integrate.wgsl`.
pub struct Integrate {
    /// Entry point `integrate`.
    pub integrate: ComputeKernel,
}

impl Integrate {
    /// Build.
    pub fn new(ctx: &GpuContext) -> Result<Self> {
        Ok(Integrate {
            integrate: ComputeKernel::new(ctx, "integrate", "integrate", &[])?,
        })
    }

    /// Bind for `n` vertices.
    pub fn bind(&self, ctx: &GpuContext, b: &SimBuffers, n: u64) -> Result<BoundKernel> {
        self.integrate.bind(
            ctx,
            &[
                ("params", &b.params, PARAMS_BYTES),
                ("forces", &b.forces, 12 * n),
                ("inv_mass", &b.inv_mass, 4 * n),
                ("displacements", &b.displacements, 12 * n),
                ("velocities", &b.velocities, 12 * n),
                ("status", &b.status, STATUS_BYTES),
            ],
            n as u32,
        )
    }
}

/// `kernels/reduce.wgsl`.
pub struct Reduce {
    /// Entry point `reduce_partial`.
    pub reduce_partial: ComputeKernel,
    /// Entry point `reduce_final`.
    pub reduce_final: ComputeKernel,
}

impl Reduce {
    /// Build.
    pub fn new(ctx: &GpuContext) -> Result<Self> {
        Ok(Reduce {
            reduce_partial: ComputeKernel::new(ctx, "reduce", "reduce_partial", &[])?,
            reduce_final: ComputeKernel::new(ctx, "reduce", "reduce_final", &[])?,
        })
    }

    /// Bind both entry points for `n` vertices and `m` tets.
    pub fn bind(
        &self,
        ctx: &GpuContext,
        b: &SimBuffers,
        n: u64,
        m: u64,
    ) -> Result<(BoundKernel, BoundKernel)> {
        let blocks = n.max(m).div_ceil(crate::cpu::REDUCE_WORKGROUP as u64);
        let list = |_k: &ComputeKernel| {
            [
                ("params", &b.params, PARAMS_BYTES),
                ("displacements", &b.displacements, 12 * n),
                ("velocities", &b.velocities, 12 * n),
                ("mass", &b.mass, 4 * n),
                ("inv_mass", &b.inv_mass, 4 * n),
                ("forces", &b.forces, 12 * n),
                ("external_forces", &b.external_forces, 12 * n),
                ("tet_energy", &b.tet_energy, 4 * m),
                (
                    "partials",
                    &b.partials,
                    4 * crate::cpu::reduce::PARTIAL_LEN as u64 * blocks,
                ),
                ("stats", &b.stats, STATS_BYTES),
            ]
        };
        let items = n.max(m) as u32;
        Ok((
            self.reduce_partial
                .bind(ctx, &list(&self.reduce_partial), items)?,
            self.reduce_final
                .bind(ctx, &list(&self.reduce_final), items)?,
        ))
    }
}
