//! Work done once when a simulation is created: building the particles' reference neighbour
//! lists on the device (counting sort on a uniform grid, prefix sums) and their correction
//! matrices. The lists are sized from a count read back half-way.

use crate::error::{PalpateError, Result};
use crate::gpu::buffers::{BufferGroup, BufferSpec, GpuBuffers, Usage};
use crate::gpu::kernel::{ComputeKernel, Dispatch};
use crate::gpu::GpuContext;
use crate::particles::params::GridParams;

/// One dispatch of a setup pass: kernel file, entry point, how many threads, aliases.
pub struct SetupPass<'a> {
    /// Kernel file.
    pub file: &'static str,
    /// Entry point.
    pub entry: &'static str,
    /// Threads (items) or one workgroup.
    pub dispatch: SetupDispatch,
    /// Binding aliases (global, buffer).
    pub aliases: &'a [(&'static str, &'static str)],
}

/// Dispatch size of a setup pass.
#[derive(Clone, Copy, Debug)]
pub enum SetupDispatch {
    /// One thread per item.
    Items(u32),
    /// One workgroup.
    One,
    /// Workgroup counts read at execution time from the `DispatchIndirectArgs` at this byte
    /// offset of the named buffer (written by an earlier pass).
    Indirect(&'static str, u64),
}

/// Build, bind and run `passes` in order in one compute pass, then wait.
pub fn run_passes(ctx: &GpuContext, buffers: &GpuBuffers, passes: &[SetupPass]) -> Result<()> {
    let max_dim = ctx.limits.max_compute_workgroups_per_dimension;
    let mut built = Vec::new();
    for p in passes {
        let k = ComputeKernel::new(ctx, p.file, p.entry, &[])?;
        let bg = k.bind(ctx, buffers, p.aliases)?;
        built.push((k, bg));
    }
    let mut enc = ctx.device.create_command_encoder(&Default::default());
    {
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("setup"),
            timestamp_writes: None,
        });
        for (p, (k, bg)) in passes.iter().zip(&built) {
            pass.push_debug_group(p.entry);
            let d = match p.dispatch {
                SetupDispatch::Items(n) => Dispatch::Items(n),
                SetupDispatch::One => Dispatch::One,
                SetupDispatch::Indirect(name, offset) => {
                    Dispatch::Indirect(buffers.require(name)?, offset)
                }
            };
            k.record(&mut pass, bg, d, max_dim);
            pass.pop_debug_group();
        }
    }
    ctx.queue.submit([enc.finish()]);
    ctx.wait()
}

/// Read `count` u32 words at byte `offset` of `buffer`.
pub fn read_u32(
    ctx: &GpuContext,
    buffer: &wgpu::Buffer,
    offset: u64,
    count: u64,
) -> Result<Vec<u32>> {
    let bytes = 4 * count;
    let staging = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("setup readback"),
        size: bytes.max(4),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut enc = ctx.device.create_command_encoder(&Default::default());
    enc.copy_buffer_to_buffer(buffer, offset, &staging, 0, bytes);
    ctx.queue.submit([enc.finish()]);
    Ok(bytemuck::cast_slice(&ctx.read_mapped(&staging, bytes)?).to_vec())
}

const CELL_SCAN: &[(&str, &str)] = &[
    ("scan_params", "cell_scan_params"),
    ("scan_data", "cell_offsets"),
    ("scan_blocks", "cell_scan_blocks"),
];
const NEIGHBOUR_SCAN: &[(&str, &str)] = &[
    ("scan_params", "neighbour_scan_params"),
    ("scan_data", "neighbour_offsets"),
    ("scan_blocks", "neighbour_scan_blocks"),
];

/// Build the reference neighbour lists in `buffers` (the `particles` group must exist):
/// `neighbours_bin`, a prefix sum over the cells, `neighbours_place`, `neighbours_sort`,
/// `neighbours_count`, a prefix sum over the counts; then read the total, add the
/// `neighbours` buffer and run `neighbours_fill`. Returns the number of neighbour entries.
pub fn build_neighbour_lists(
    ctx: &GpuContext,
    buffers: &mut GpuBuffers,
    grid: &GridParams,
) -> Result<u32> {
    let n = grid.n_particles;
    let nc = grid.n_cells;
    let items = SetupDispatch::Items;
    let runs = crate::cpu::scan::n_runs;
    let pass = |file, entry, dispatch, aliases| SetupPass {
        file,
        entry,
        dispatch,
        aliases,
    };
    run_passes(
        ctx,
        buffers,
        &[
            pass("neighbours", "neighbours_bin", items(n), &[]),
            pass("scan", "scan_local", items(runs(nc + 1)), CELL_SCAN),
            pass("scan", "scan_totals", SetupDispatch::One, CELL_SCAN),
            pass("scan", "scan_apply", items(nc + 1), CELL_SCAN),
            pass("neighbours", "neighbours_place", items(n), &[]),
            pass("neighbours", "neighbours_sort", items(nc), &[]),
            pass("neighbours", "neighbours_count", items(n), &[]),
            pass("scan", "scan_local", items(runs(n + 1)), NEIGHBOUR_SCAN),
            pass("scan", "scan_totals", SetupDispatch::One, NEIGHBOUR_SCAN),
            pass("scan", "scan_apply", items(n + 1), NEIGHBOUR_SCAN),
        ],
    )?;
    let total = read_u32(ctx, buffers.require("neighbour_offsets")?, 4 * n as u64, 1)?[0];
    buffers.extend(
        ctx,
        &[BufferGroup {
            name: "neighbour lists",
            specs: vec![BufferSpec::zeroed(
                "neighbours",
                Usage::Storage,
                4 * total as u64,
            )],
        }],
    )?;
    run_passes(
        ctx,
        buffers,
        &[pass("neighbours", "neighbours_fill", items(n), &[])],
    )?;
    if total == 0 {
        return Err(PalpateError::Usage(
            "particles.kernel_radius: no particle has a neighbour within the kernel support".into(),
        ));
    }
    Ok(total)
}
