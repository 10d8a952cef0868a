//! The simulation's GPU data: structure-of-arrays storage buffers grouped by subsystem, made
//! once per model and kept apart from the pipelines.
//!
//! Each subsystem (FEM, and later tool, particles, neighbour grid) describes its buffers in
//! one table of [`BufferSpec`] (name, size, usage, initial contents). That table drives the
//! size check against the adapter's limits, the creation, and the binding: kernels are bound
//! by the names of their WGSL globals, so a buffer's table name is its name in every shader.

use crate::error::{PalpateError, Result};
use crate::gpu::GpuContext;
use wgpu::util::DeviceExt;
use wgpu::BufferUsages as U;

/// How a buffer is used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Usage {
    /// Read or written by kernels.
    Storage,
    /// Per-run or per-batch uniform.
    Uniform,
    /// Part of the simulation state: saved by `checkpoint` (with the activation's products,
    /// `gpu::stepper::ACTIVATION_PRODUCTS`); the vertices' read and written by
    /// `read_state`/`write_state`.
    State,
    /// Written by kernels and copied into the readback ring at the end of every batch.
    Report,
    /// Dispatch arguments written by a kernel and read by `dispatch_workgroups_indirect`.
    Indirect,
}

impl Usage {
    fn wgpu(self) -> U {
        let storage = U::STORAGE | U::COPY_DST | U::COPY_SRC;
        match self {
            Usage::Uniform => U::UNIFORM | U::COPY_DST,
            Usage::Indirect => storage | U::INDIRECT,
            Usage::Storage | Usage::State | Usage::Report => storage,
        }
    }
}

/// Initial contents of a buffer.
#[derive(Clone, Copy, Debug)]
pub enum Init<'a> {
    /// All zero bytes.
    Zeroed,
    /// These bytes (the buffer's size is the larger of this and the spec's size).
    Bytes(&'a [u8]),
    /// Every u32 word set to this value.
    FillU32(u32),
}

/// One buffer of a group: its name (the WGSL global name), size, usage and contents.
#[derive(Clone, Copy, Debug)]
pub struct BufferSpec<'a> {
    /// Name, identical to the WGSL global that binds it.
    pub name: &'static str,
    /// Size in bytes.
    pub bytes: u64,
    /// Usage.
    pub usage: Usage,
    /// Initial contents.
    pub init: Init<'a>,
}

impl<'a> BufferSpec<'a> {
    /// A buffer initialised from a slice of plain data.
    pub fn data<T: bytemuck::Pod>(name: &'static str, usage: Usage, data: &'a [T]) -> Self {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        BufferSpec {
            name,
            bytes: bytes.len() as u64,
            usage,
            init: Init::Bytes(bytes),
        }
    }

    /// A zeroed buffer of `bytes` bytes.
    pub fn zeroed(name: &'static str, usage: Usage, bytes: u64) -> Self {
        BufferSpec {
            name,
            bytes,
            usage,
            init: Init::Zeroed,
        }
    }
}

/// The buffers of one subsystem.
#[derive(Clone, Debug)]
pub struct BufferGroup<'a> {
    /// Subsystem name (`fem`, `tool`, `particles`, …), for error messages.
    pub name: &'static str,
    /// Its buffers.
    pub specs: Vec<BufferSpec<'a>>,
}

/// Every buffer of one simulation, by name.
pub struct GpuBuffers {
    buffers: Vec<(&'static str, Usage, wgpu::Buffer)>,
}

/// The buffer groups sized by the particle layer (its particle count and neighbour slots),
/// whose overflow `particles.spacing` and `particles.kernel_radius` decide.
const PARTICLE_GROUPS: [&str; 5] = [
    "particles",
    "neighbour lists",
    "particle step",
    "particle stand-ins",
    "exact coupling",
];

/// How far the scene's estimate of a particle layer's largest binding must exceed the
/// adapter's limit for [`check_particle_estimate`] to refuse it before sampling (the estimate
/// counts every particle with a full lattice of neighbours; the exact check after sampling
/// decides the cases in between).
pub const ESTIMATE_MARGIN: f64 = 1.25;

/// The advice of a particle layer too big for the adapter.
const PARTICLE_ADVICE: &str =
    "; raise particles.spacing or lower particles.kernel_radius, or run with --backend cpu";

/// Refuse, before any sampling, a particle layer of about `n` particles of `settings` (the
/// scene's estimate, zone volume / spacing³) whose largest per-particle binding would exceed
/// the adapter's storage-binding limit by over [`ESTIMATE_MARGIN`]: its neighbour lists
/// (4 bytes × the lattice's neighbours per particle) or its 3×3 matrices (36 bytes).
pub fn check_particle_estimate(
    ctx: &GpuContext,
    n: f64,
    settings: &crate::scene::ParticleSettings,
) -> Result<()> {
    let l = &ctx.limits;
    let limit = l.max_storage_buffer_binding_size.min(l.max_buffer_size);
    let slots = crate::cpu::memory::lattice_neighbours(settings.kernel_radius) as f64;
    let (per_particle, buffer) = if 4.0 * slots > 36.0 {
        (4.0 * slots, "neighbours")
    } else {
        (36.0, "particle_stress")
    };
    let bytes = n * per_particle;
    if bytes <= ESTIMATE_MARGIN * limit as f64 {
        return Ok(());
    }
    Err(PalpateError::TooBigForAdapter {
        subject: "particle layer (the scene's estimate, before sampling)",
        advice: PARTICLE_ADVICE,
        adapter: ctx.info.name.clone(),
        buffer: buffer.into(),
        bytes: bytes.min(u64::MAX as f64) as u64,
        limit,
        what: "storage binding",
    })
}

/// Refuse a set of groups that does not fit the adapter: a storage buffer above the
/// storage-binding limit, a uniform above the uniform-binding limit, any buffer above the
/// buffer-size limit. The largest offender is named, and a particle layer's overflow names
/// the scene keys that size it.
pub fn check_limits(ctx: &GpuContext, groups: &[BufferGroup]) -> Result<()> {
    let l = &ctx.limits;
    let mut all: Vec<(&str, &BufferSpec)> = groups
        .iter()
        .flat_map(|g| g.specs.iter().map(move |s| (g.name, s)))
        .collect();
    all.sort_by_key(|(_, s)| std::cmp::Reverse(s.bytes));
    for (group, s) in all {
        let (limit, what) = match s.usage {
            Usage::Uniform => (
                l.max_uniform_buffer_binding_size.min(l.max_buffer_size),
                "uniform binding",
            ),
            _ => (
                l.max_storage_buffer_binding_size.min(l.max_buffer_size),
                "storage binding",
            ),
        };
        if s.bytes > limit {
            let particles = PARTICLE_GROUPS.contains(&group);
            return Err(PalpateError::TooBigForAdapter {
                subject: if particles { "particle layer" } else { "mesh" },
                advice: if particles { PARTICLE_ADVICE } else { "" },
                adapter: ctx.info.name.clone(),
                buffer: s.name.into(),
                bytes: s.bytes,
                limit,
                what,
            });
        }
    }
    Ok(())
}

impl GpuBuffers {
    /// Check the groups against the adapter's limits, then create and fill every buffer.
    /// A duplicate name is an error (names are how kernels find their buffers).
    pub fn new(ctx: &GpuContext, groups: &[BufferGroup]) -> Result<GpuBuffers> {
        let mut b = GpuBuffers {
            buffers: Vec::new(),
        };
        b.extend(ctx, groups)?;
        Ok(b)
    }

    /// Add the buffers of more groups (a group sized by an earlier GPU pass, such as the
    /// neighbour lists), with the same checks.
    pub fn extend(&mut self, ctx: &GpuContext, groups: &[BufferGroup]) -> Result<()> {
        check_limits(ctx, groups)?;
        let mut names: Vec<&str> = groups
            .iter()
            .flat_map(|g| g.specs.iter().map(|s| s.name))
            .chain(self.buffers.iter().map(|(n, _, _)| *n))
            .collect();
        names.sort_unstable();
        if let Some(w) = names.windows(2).find(|w| w[0] == w[1]) {
            return Err(PalpateError::Gpu(format!(
                "two GPU buffers are named '{}'",
                w[0]
            )));
        }
        let scope = ctx.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let d = &ctx.device;
        let buffers = &mut self.buffers;
        for spec in groups.iter().flat_map(|g| g.specs.iter()) {
            // Bindings must be non-empty and a multiple of 4 bytes.
            let size = spec.bytes.max(4).next_multiple_of(4);
            let buffer = match spec.init {
                Init::Zeroed => d.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(spec.name),
                    size,
                    usage: spec.usage.wgpu(),
                    mapped_at_creation: false,
                }),
                Init::Bytes(bytes) => {
                    let mut contents = bytes.to_vec();
                    contents.resize(size.max(bytes.len() as u64) as usize, 0);
                    d.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                        label: Some(spec.name),
                        contents: &contents,
                        usage: spec.usage.wgpu(),
                    })
                }
                Init::FillU32(v) => {
                    let words = vec![v; (size / 4) as usize];
                    d.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                        label: Some(spec.name),
                        contents: bytemuck::cast_slice(&words),
                        usage: spec.usage.wgpu(),
                    })
                }
            };
            buffers.push((spec.name, spec.usage, buffer));
        }
        if let Some(e) = pollster::block_on(scope.pop()) {
            let total: u64 = groups
                .iter()
                .flat_map(|g| g.specs.iter())
                .map(|s| s.bytes)
                .sum();
            return Err(PalpateError::Gpu(format!(
                "out of GPU memory creating {total} bytes of buffers on '{}': {e}",
                ctx.info.name
            )));
        }
        ctx.check_errors()
    }

    /// Buffers made elsewhere, by name (tests and tools that drive one kernel by hand).
    pub fn from_existing(buffers: Vec<(&'static str, wgpu::Buffer)>) -> GpuBuffers {
        GpuBuffers {
            buffers: buffers
                .into_iter()
                .map(|(n, b)| (n, Usage::Storage, b))
                .collect(),
        }
    }

    /// The buffer named `name`, if any.
    pub fn get(&self, name: &str) -> Option<&wgpu::Buffer> {
        self.buffers
            .iter()
            .find(|(n, _, _)| *n == name)
            .map(|(_, _, b)| b)
    }

    /// The buffer named `name`, or an error naming it.
    pub fn require(&self, name: &str) -> Result<&wgpu::Buffer> {
        self.get(name)
            .ok_or_else(|| PalpateError::Gpu(format!("no GPU buffer named '{name}'")))
    }

    /// Names and buffers of one usage, in table order.
    pub fn with_usage(&self, usage: Usage) -> impl Iterator<Item = (&'static str, &wgpu::Buffer)> {
        self.buffers
            .iter()
            .filter(move |(_, u, _)| *u == usage)
            .map(|(n, _, b)| (*n, b))
    }
}
