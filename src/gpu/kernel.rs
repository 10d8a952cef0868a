//! A compute pipeline built from one kernel file and entry point, with its bind-group layout
//! reflected from the WGSL by naga (so bindings are written once, in the shader), and a
//! typed bind step that checks every buffer's name and size before anything is recorded.

use crate::error::{PalpateError, Result};
use crate::gpu::GpuContext;

/// One binding as the shader declares it.
#[derive(Clone, Debug, PartialEq)]
pub struct ReflectedBinding {
    /// `@binding(n)` in group 0.
    pub binding: u32,
    /// The WGSL variable name.
    pub name: String,
    /// Uniform, read-only storage or read-write storage.
    pub ty: wgpu::BufferBindingType,
}

/// Bindings of group 0 declared in `source`, and the workgroup size of `entry`.
pub fn reflect(source: &str, entry: &str) -> Result<(Vec<ReflectedBinding>, u32)> {
    let module = naga::front::wgsl::parse_str(source)
        .map_err(|e| PalpateError::Gpu(format!("kernel parse: {}", e.message())))?;
    let ep = module
        .entry_points
        .iter()
        .find(|e| e.name == entry)
        .ok_or_else(|| PalpateError::Gpu(format!("no entry point '{entry}'")))?;
    let mut out = Vec::new();
    for (_, var) in module.global_variables.iter() {
        let Some(rb) = &var.binding else { continue };
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
        out.push(ReflectedBinding {
            binding: rb.binding,
            name: var.name.clone().unwrap_or_default(),
            ty,
        });
    }
    out.sort_by_key(|b| b.binding);
    Ok((out, ep.workgroup_size[0]))
}

/// A compute pipeline with its reflected layout.
pub struct ComputeKernel {
    /// `file::entry`, for labels and errors.
    pub label: String,
    /// The pipeline.
    pub pipeline: wgpu::ComputePipeline,
    /// Group-0 layout.
    pub layout: wgpu::BindGroupLayout,
    /// Reflected bindings, by binding number.
    pub bindings: Vec<ReflectedBinding>,
    /// Threads per workgroup (x).
    pub workgroup_size: u32,
}

/// A bind group made for a kernel, and the number of items (threads) it covers.
pub struct BoundKernel {
    /// The bind group (built once).
    pub bind_group: wgpu::BindGroup,
    /// Items to cover (one thread each).
    pub items: u32,
    /// Workgroup grid (x, y) covering `items`.
    pub grid: (u32, u32),
}

impl ComputeKernel {
    /// Build the pipeline for `entry` in kernel file `file`, with pipeline-overridable constants.
    pub fn new(
        ctx: &GpuContext,
        file: &str,
        entry: &str,
        constants: &[(&str, f64)],
    ) -> Result<ComputeKernel> {
        let label = format!("{file}::{entry}");
        let source = crate::gpu::kernel_source(file)
            .ok_or_else(|| PalpateError::Gpu(format!("no kernel file '{file}'")))?;
        let (bindings, workgroup_size) = reflect(source, entry)?;
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
        ctx.check_errors()?;
        Ok(ComputeKernel {
            label,
            pipeline,
            layout,
            bindings,
            workgroup_size,
        })
    }

    /// Make the bind group from `(name, buffer, minimum bytes)` in binding order. Each name
    /// must match the shader's variable and each buffer must hold at least its minimum.
    pub fn bind(
        &self,
        ctx: &GpuContext,
        buffers: &[(&str, &wgpu::Buffer, u64)],
        items: u32,
    ) -> Result<BoundKernel> {
        if buffers.len() != self.bindings.len() {
            return Err(PalpateError::Gpu(format!(
                "{}: {} buffers given for {} bindings",
                self.label,
                buffers.len(),
                self.bindings.len()
            )));
        }
        for ((name, buf, min), b) in buffers.iter().zip(&self.bindings) {
            if *name != b.name {
                return Err(PalpateError::Gpu(format!(
                    "{}: binding {} is '{}' in the shader but '{name}' was given",
                    self.label, b.binding, b.name
                )));
            }
            if buf.size() < *min {
                return Err(PalpateError::Gpu(format!(
                    "{}: buffer '{name}' has {} bytes, needs {min}",
                    self.label,
                    buf.size()
                )));
            }
        }
        let entries: Vec<wgpu::BindGroupEntry> = buffers
            .iter()
            .zip(&self.bindings)
            .map(|((_, buf, _), b)| wgpu::BindGroupEntry {
                binding: b.binding,
                resource: buf.as_entire_binding(),
            })
            .collect();
        let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(&self.label),
            layout: &self.layout,
            entries: &entries,
        });
        ctx.check_errors()?;
        Ok(BoundKernel {
            bind_group,
            items,
            grid: grid_for(
                items,
                self.workgroup_size,
                ctx.limits.max_compute_workgroups_per_dimension,
            ),
        })
    }

    /// Record one dispatch covering the bound items.
    pub fn record(&self, pass: &mut wgpu::ComputePass<'_>, bound: &BoundKernel) {
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &bound.bind_group, &[]);
        pass.dispatch_workgroups(bound.grid.0, bound.grid.1, 1);
    }

    /// Record a single workgroup (for `reduce_final`).
    pub fn record_one(&self, pass: &mut wgpu::ComputePass<'_>, bound: &BoundKernel) {
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &bound.bind_group, &[]);
        pass.dispatch_workgroups(1, 1, 1);
    }
}

/// Workgroup grid (x, y) with x ≤ `max_dim` covering `items` threads of `workgroup_size`.
pub fn grid_for(items: u32, workgroup_size: u32, max_dim: u32) -> (u32, u32) {
    let groups = items.div_ceil(workgroup_size).max(1);
    if groups <= max_dim {
        (groups, 1)
    } else {
        (max_dim, groups.div_ceil(max_dim))
    }
}
