//! A compute pipeline built from one kernel file and entry point. Its bind-group layout is
//! reflected from the WGSL by naga — only the globals that entry point actually uses — so
//! bindings are written once, in the shader, and buffers are bound by the names of those
//! globals (see [`crate::gpu::buffers`]).

use crate::error::{PalpateError, Result};
use crate::gpu::buffers::GpuBuffers;
use crate::gpu::GpuContext;

/// One binding as the shader declares it.
#[derive(Clone, Debug, PartialEq)]
pub struct ReflectedBinding {
    /// `@binding(n)` in group 0.
    pub binding: u32,
    /// The WGSL variable name (= the buffer's name).
    pub name: String,
    /// Uniform, read-only storage or read-write storage.
    pub ty: wgpu::BufferBindingType,
    /// Smallest size the binding can have, bytes (a uniform struct's size, or one element of
    /// a runtime-sized array).
    pub min_bytes: u64,
}

/// What [`reflect`] reads off an entry point.
#[derive(Clone, Debug, PartialEq)]
pub struct Reflected {
    /// Group-0 bindings that the entry point uses, in binding order.
    pub bindings: Vec<ReflectedBinding>,
    /// Threads per workgroup (x).
    pub workgroup_size: u32,
    /// Items (list entries, vertices, …) one workgroup covers: the module's constant
    /// `ITEMS_PER_WORKGROUP` where it declares one (a kernel that gives each item several
    /// lanes, `workgroup_size / ITEMS_PER_WORKGROUP` of them), else `workgroup_size`.
    pub items_per_workgroup: u32,
}

/// The module-scope `const ITEMS_PER_WORKGROUP: u32` of `module`, if it declares one.
fn items_per_workgroup(module: &naga::Module) -> Option<u32> {
    module.constants.iter().find_map(|(_, c)| {
        if c.name.as_deref() != Some("ITEMS_PER_WORKGROUP") {
            return None;
        }
        match module.global_expressions[c.init] {
            naga::Expression::Literal(naga::Literal::U32(v)) => Some(v),
            naga::Expression::Literal(naga::Literal::AbstractInt(v)) => u32::try_from(v).ok(),
            _ => None,
        }
    })
}

/// Group-0 bindings that entry point `entry` of `source` uses (reads, writes or queries), in
/// binding order, its workgroup size (x) and the items one workgroup covers.
pub fn reflect(source: &str, entry: &str) -> Result<Reflected> {
    let module = naga::front::wgsl::parse_str(source)
        .map_err(|e| PalpateError::Gpu(format!("kernel parse: {}", e.message())))?;
    let info = naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::all(),
    )
    .validate(&module)
    .map_err(|e| PalpateError::Gpu(format!("kernel validation: {e}")))?;
    let index = module
        .entry_points
        .iter()
        .position(|e| e.name == entry)
        .ok_or_else(|| PalpateError::Gpu(format!("no entry point '{entry}'")))?;
    let ep = &module.entry_points[index];
    let uses = info.get_entry_point(index);
    let mut layouter = naga::proc::Layouter::default();
    layouter
        .update(module.to_ctx())
        .map_err(|e| PalpateError::Gpu(format!("kernel layout: {e}")))?;
    let mut out = Vec::new();
    for (handle, var) in module.global_variables.iter() {
        let Some(rb) = &var.binding else { continue };
        if uses[handle].is_empty() {
            continue;
        }
        if rb.group != 0 {
            return Err(PalpateError::Gpu(format!(
                "binding group {} unsupported",
                rb.group
            )));
        }
        let ty = match var.space {
            naga::AddressSpace::Uniform => wgpu::BufferBindingType::Uniform,
            naga::AddressSpace::Storage { access } => wgpu::BufferBindingType::Storage {
                read_only: !access.contains(naga::StorageAccess::STORE),
            },
            other => {
                return Err(PalpateError::Gpu(format!(
                    "unsupported address space {other:?}"
                )))
            }
        };
        let min_bytes = match &module.types[var.ty].inner {
            naga::TypeInner::Array {
                base,
                size: naga::ArraySize::Dynamic,
                ..
            } => layouter[*base].size as u64,
            _ => layouter[var.ty].size as u64,
        };
        out.push(ReflectedBinding {
            binding: rb.binding,
            name: var.name.clone().unwrap_or_default(),
            ty,
            min_bytes,
        });
    }
    out.sort_by_key(|b| b.binding);
    let workgroup_size = ep.workgroup_size[0];
    let items = items_per_workgroup(&module).unwrap_or(workgroup_size);
    if items == 0 || workgroup_size % items != 0 {
        return Err(PalpateError::Gpu(format!(
            "entry point '{entry}': ITEMS_PER_WORKGROUP = {items} does not divide its workgroup size {workgroup_size}"
        )));
    }
    Ok(Reflected {
        bindings: out,
        workgroup_size,
        items_per_workgroup: items,
    })
}

/// A compute pipeline with its reflected layout.
pub struct ComputeKernel {
    /// `file::entry`, for labels and errors.
    pub label: String,
    /// The pipeline.
    pub pipeline: wgpu::ComputePipeline,
    /// Group-0 layout (only the globals this entry point uses).
    pub layout: wgpu::BindGroupLayout,
    /// Reflected bindings, by binding number.
    pub bindings: Vec<ReflectedBinding>,
    /// Threads per workgroup (x).
    pub workgroup_size: u32,
    /// Items one workgroup covers ([`Reflected::items_per_workgroup`]).
    pub items_per_workgroup: u32,
}

/// How many workgroups one dispatch runs.
#[derive(Clone, Copy, Debug)]
pub enum Dispatch<'a> {
    /// Enough workgroups to cover `items` (one thread each, or `LANES` threads each in a
    /// kernel that declares `ITEMS_PER_WORKGROUP`; a 2-D grid past the per-dimension limit,
    /// which kernels linearise with `linear_index` or `workgroup_index`).
    Items(u32),
    /// Exactly one workgroup.
    One,
    /// Workgroup counts read at execution time from `DispatchIndirectArgs` at this byte
    /// offset of this buffer (written by an earlier kernel).
    Indirect(&'a wgpu::Buffer, u64),
}

impl ComputeKernel {
    /// Build the pipeline for `entry` in kernel file `file`, with pipeline-overridable
    /// constants.
    pub fn new(
        ctx: &GpuContext,
        file: &str,
        entry: &str,
        constants: &[(&str, f64)],
    ) -> Result<ComputeKernel> {
        let label = format!("{file}::{entry}");
        let source = crate::gpu::kernel_source(file)
            .ok_or_else(|| PalpateError::Gpu(format!("no kernel file '{file}'")))?;
        let Reflected {
            bindings,
            workgroup_size,
            items_per_workgroup,
        } = reflect(source, entry)?;
        let max = ctx.limits.max_storage_buffers_per_shader_stage as usize;
        let storage = bindings
            .iter()
            .filter(|b| matches!(b.ty, wgpu::BufferBindingType::Storage { .. }))
            .count();
        if storage > max {
            return Err(PalpateError::Gpu(format!(
                "{label} binds {storage} storage buffers but the adapter '{}' allows {max} per shader stage",
                ctx.info.name
            )));
        }
        let entries: Vec<wgpu::BindGroupLayoutEntry> = bindings
            .iter()
            .map(|b| wgpu::BindGroupLayoutEntry {
                binding: b.binding,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: wgpu::BindingType::Buffer {
                    ty: b.ty,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            })
            .collect();
        let device = &ctx.device;
        let (layout, pipeline) = ctx.scoped(&label, || {
            let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some(&label),
                entries: &entries,
            });
            let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(&label),
                bind_group_layouts: &[Some(&layout)],
                immediate_size: 0,
            });
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(&label),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            });
            let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(&label),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants,
                    zero_initialize_workgroup_memory: true,
                },
                cache: None,
            });
            (layout, pipeline)
        })?;
        Ok(ComputeKernel {
            label,
            pipeline,
            layout,
            bindings,
            workgroup_size,
            items_per_workgroup,
        })
    }

    /// Make the bind group: each binding gets the buffer with the global's name, or the
    /// name `aliases` maps it to ((global, buffer) pairs). A missing buffer, or one smaller
    /// than the binding's minimum, is an error naming both.
    pub fn bind(
        &self,
        ctx: &GpuContext,
        buffers: &GpuBuffers,
        aliases: &[(&str, &str)],
    ) -> Result<wgpu::BindGroup> {
        let mut entries = Vec::with_capacity(self.bindings.len());
        for b in &self.bindings {
            let name = aliases
                .iter()
                .find(|(global, _)| *global == b.name)
                .map_or(b.name.as_str(), |(_, buffer)| *buffer);
            let buf = buffers.get(name).ok_or_else(|| {
                PalpateError::Gpu(format!(
                    "{}: binding {} '{}' has no buffer named '{name}'",
                    self.label, b.binding, b.name
                ))
            })?;
            if buf.size() < b.min_bytes {
                return Err(PalpateError::Gpu(format!(
                    "{}: buffer '{}' has {} bytes, the shader needs at least {}",
                    self.label,
                    name,
                    buf.size(),
                    b.min_bytes
                )));
            }
            entries.push(wgpu::BindGroupEntry {
                binding: b.binding,
                resource: buf.as_entire_binding(),
            });
        }
        ctx.scoped(&self.label, || {
            ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some(&self.label),
                layout: &self.layout,
                entries: &entries,
            })
        })
    }

    /// Record one dispatch with `bind_group`. `max_dim` is the adapter's
    /// `max_compute_workgroups_per_dimension`.
    pub fn record(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        bind_group: &wgpu::BindGroup,
        dispatch: Dispatch<'_>,
        max_dim: u32,
    ) {
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, bind_group, &[]);
        match dispatch {
            Dispatch::Items(items) => {
                let (x, y) = grid_for(items, self.items_per_workgroup, max_dim);
                pass.dispatch_workgroups(x, y, 1);
            }
            Dispatch::One => pass.dispatch_workgroups(1, 1, 1),
            Dispatch::Indirect(buffer, offset) => pass.dispatch_workgroups_indirect(buffer, offset),
        }
    }
}

/// Workgroup grid (x, y) with x ≤ `max_dim` covering `items`, `per_workgroup` to a workgroup.
pub fn grid_for(items: u32, per_workgroup: u32, max_dim: u32) -> (u32, u32) {
    let groups = items.div_ceil(per_workgroup).max(1);
    if groups <= max_dim {
        (groups, 1)
    } else {
        (max_dim, groups.div_ceil(max_dim))
    }
}
