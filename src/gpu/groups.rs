//! The buffer tables of each subsystem (see [`crate::gpu::buffers`]): one function per
//! group, each listing (name, size, usage, contents). The names are the WGSL globals.

use crate::contact::{ToolInput, ToolParams, ToolState, REPORT_LEN};
use crate::cpu::reduce::PARTIAL_LEN;
use crate::gpu::buffers::{BufferGroup, BufferSpec, Init, Usage};
use crate::gpu::kernel::grid_for;
use crate::model::Model;
use crate::params::{stat, StepParams};

/// Bytes of the stats buffer.
pub const STATS_BYTES: u64 = (stat::LEN * 4) as u64;
/// Bytes of the status buffer (`status[0]`: lowest non-finite vertex, or `u32::MAX`).
pub const STATUS_BYTES: u64 = 16;

/// The FEM core: state, rest shape, CSR incidence, forces, reduction and status.
/// `max_dim` is the adapter's workgroups-per-dimension limit (it sets the number of
/// reduction blocks).
pub fn fem<'a>(model: &'a Model, params: &'a StepParams, max_dim: u32) -> BufferGroup<'a> {
    let n = model.n_vertices() as u64;
    let m = model.n_tets() as u64;
    let blocks = {
        let (x, y) = grid_for(
            model.n_vertices().max(model.n_tets()) as u32,
            crate::cpu::REDUCE_WORKGROUP as u32,
            max_dim,
        );
        x as u64 * y as u64
    };
    // With particles, vertex masses change at activation updates: part of the state.
    let state_if_particles = if model.particles.is_some() {
        Usage::State
    } else {
        Usage::Storage
    };
    BufferGroup {
        name: "fem",
        specs: vec![
            BufferSpec::data("params", Usage::Uniform, std::slice::from_ref(params)),
            BufferSpec::zeroed("displacements", Usage::State, 12 * n),
            BufferSpec::zeroed("velocities", Usage::State, 12 * n),
            BufferSpec::data("tets", Usage::Storage, &model.tets),
            BufferSpec::data("dm_inv", Usage::Storage, &model.dm_inv),
            BufferSpec::data("rest_volume", Usage::Storage, &model.rest_volume),
            BufferSpec::zeroed("corner_forces", Usage::Storage, 48 * m),
            BufferSpec::zeroed("tet_energy", Usage::Storage, 4 * m),
            BufferSpec::data(
                "incidence_offsets",
                Usage::Storage,
                &model.incidence_offsets,
            ),
            BufferSpec::data("incidence", Usage::Storage, &model.incidence),
            BufferSpec::data("mass", state_if_particles, &model.mass),
            BufferSpec::data("inv_mass", state_if_particles, &model.inv_mass),
            BufferSpec::data("external_forces", Usage::Storage, &model.external_forces),
            BufferSpec::zeroed("forces", Usage::Storage, 12 * n),
            BufferSpec::zeroed("partials", Usage::Storage, 4 * PARTIAL_LEN as u64 * blocks),
            BufferSpec::zeroed("stats", Usage::Report, STATS_BYTES),
            BufferSpec {
                name: "status",
                bytes: STATUS_BYTES,
                usage: Usage::Report,
                init: Init::FillU32(u32::MAX),
            },
        ],
    }
}

/// The tool: its uniforms, the surface it touches, contact forces, the reduction and the
/// per-batch report. Without a tool only `surface_index` and `contact_forces` exist, as
/// empty stand-ins for the bindings of `gather` and `reduce` (their `CONTACT` constant is
/// false, so they are never read).
pub fn tool<'a>(model: &'a Model, tool_params: &'a ToolParams) -> BufferGroup<'a> {
    let Some(t) = &model.tool else {
        let mut specs = vec![
            BufferSpec::zeroed("surface_index", Usage::Storage, 4),
            BufferSpec::zeroed("contact_forces", Usage::Storage, 4),
        ];
        if model.particles.is_some() {
            // The particle kernels' TOOL = false variants still bind these.
            specs.push(BufferSpec::data(
                "tool_params",
                Usage::Uniform,
                std::slice::from_ref(tool_params),
            ));
            specs.push(BufferSpec::zeroed(
                "tool_input",
                Usage::Uniform,
                std::mem::size_of::<ToolInput>() as u64,
            ));
            specs.push(BufferSpec::zeroed(
                "tool_state",
                Usage::Storage,
                std::mem::size_of::<ToolState>() as u64,
            ));
            // `activate_relump` fits the massless vertices' velocities over rest offsets.
            specs.push(BufferSpec::data(
                "rest_positions",
                Usage::Storage,
                &model.rest,
            ));
        }
        return BufferGroup {
            name: "tool",
            specs,
        };
    };
    let n_surface = t.surface_vertices.len() as u64;
    let blocks = crate::cpu::tool_force::n_partials(tool_params) as u64;
    BufferGroup {
        name: "tool",
        specs: vec![
            BufferSpec::data(
                "tool_params",
                Usage::Uniform,
                std::slice::from_ref(tool_params),
            ),
            BufferSpec::zeroed(
                "tool_input",
                Usage::Uniform,
                std::mem::size_of::<ToolInput>() as u64,
            ),
            BufferSpec::zeroed(
                "tool_state",
                Usage::Storage,
                std::mem::size_of::<ToolState>() as u64,
            ),
            BufferSpec::data("surface_vertices", Usage::Storage, &t.surface_vertices),
            BufferSpec::data("surface_area", Usage::Storage, &t.surface_area),
            BufferSpec::data("surface_index", Usage::Storage, &t.surface_index),
            BufferSpec::data("rest_positions", Usage::Storage, &model.rest),
            BufferSpec::zeroed("contact_forces", Usage::Storage, 12 * n_surface),
            BufferSpec::zeroed(
                "tool_partials",
                Usage::Storage,
                4 * crate::cpu::tool_force::LANE as u64 * blocks,
            ),
            BufferSpec::zeroed("tool_report", Usage::Report, 4 * REPORT_LEN as u64),
        ],
    }
}

/// Per-run data of the particle stages, owned by the stepper and borrowed by the tables.
pub struct ParticleTables {
    /// The per-run uniform.
    pub params: crate::particles::params::ParticleParams,
    /// The reference grid.
    pub grid: crate::particles::params::GridParams,
    /// Uniforms of the setup prefix sums (cells, neighbour counts).
    pub setup_scans: [ScanParams; 2],
    /// Uniform of the per-update prefix sums (n + 1 marks).
    pub list_scan: [ScanParams; 1],
    /// Initial modes (PINNED bits).
    pub modes: Vec<u32>,
    /// Per vertex, 1 for a fixed vertex.
    pub node_fixed: Vec<u32>,
    /// Initial tet weights and contact weights (all 1).
    pub ones_tets: Vec<f32>,
    /// All-1 per vertex.
    pub ones_vertices: Vec<f32>,
    /// Initial indirect arguments: no work for the three lists; the fused contact +
    /// sph_stress dispatch over the tool's surface vertices.
    pub no_dispatch: [u32; 12],
    /// The activation gate's first contents: raised, so that the first update is a full one
    /// (`activate_gate`: raised, last verdict, full updates, skipped updates).
    pub gate: [u32; 4],
    /// Core steps between activation updates (for `ParticleParams::at_core_dt`).
    pub activation_interval: u32,
}

impl ParticleTables {
    /// The tables of `model` at step parameters `params` (None without particles).
    pub fn new(model: &Model, params: &StepParams) -> Option<ParticleTables> {
        let p = model.particles.as_ref()?;
        let pp = model.particle_params(params)?;
        let grid = crate::particles::params::GridParams::over(&p.rest, p.support);
        let n = p.len() as u32;
        Some(ParticleTables {
            params: pp,
            setup_scans: [ScanParams::new(grid.n_cells + 1), ScanParams::new(n + 1)],
            grid,
            list_scan: [ScanParams::new(n + 1)],
            modes: p.initial_modes(),
            node_fixed: model.inv_mass.iter().map(|&w| (w == 0.0) as u32).collect(),
            ones_tets: vec![1.0; model.n_tets()],
            ones_vertices: vec![1.0; model.n_vertices()],
            no_dispatch: {
                // The three lists' grids empty, the fused contact + sph_stress dispatch's
                // the contact's (compact.wgsl's `write_args`).
                let groups = pp
                    .n_surface
                    .div_ceil(crate::cpu::compact::PARTICLE_WORKGROUP);
                let (x, y) = crate::cpu::compact::grid(groups);
                [0, 1, 1, 0, 1, 1, 0, 1, 1, x, y, 1]
            },
            gate: [1, 0, 0, 0],
            activation_interval: p.settings.activation_interval,
        })
    }
}

/// The particle stages' state (checkpointed) and per-step arrays, the lists, the indirect
/// dispatch arguments and the per-batch report.
pub fn particle_step<'a>(model: &'a Model, t: &'a ParticleTables) -> BufferGroup<'a> {
    let n = t.params.n_particles as u64;
    let nv = model.n_vertices() as u64;
    let blocks = |k: u64| ScanParams::blocks_bytes(k as u32);
    let partial_blocks = n.div_ceil(crate::cpu::particle_reduce::WORKGROUP as u64);
    let n_slots = model.particles.as_ref().map_or(0, |p| p.slots.len()) as u64;
    let gated_args_bytes = 12 * crate::plan::ACTIVATE_GATED_PASSES as u64;
    BufferGroup {
        name: "particle step",
        specs: vec![
            BufferSpec::data(
                "particle_params",
                Usage::Uniform,
                std::slice::from_ref(&t.params),
            ),
            BufferSpec::zeroed("particle_displacements", Usage::State, 12 * n),
            BufferSpec::zeroed("particle_velocities", Usage::State, 12 * n),
            BufferSpec::data("particle_mode", Usage::State, &t.modes),
            BufferSpec::zeroed("particle_timer", Usage::State, 4 * n),
            BufferSpec::zeroed("particle_offset", Usage::State, 12 * n),
            BufferSpec::zeroed("particle_correction", Usage::Storage, 36 * n),
            BufferSpec::zeroed("particle_stress", Usage::Storage, 36 * n),
            BufferSpec::zeroed("particle_gradient", Usage::Storage, 36 * n),
            BufferSpec::zeroed("particle_energy", Usage::Storage, 4 * n),
            BufferSpec::zeroed("particle_forces", Usage::Storage, 12 * n),
            BufferSpec::zeroed("particle_force_sum", Usage::Storage, 12 * n),
            BufferSpec::zeroed("particle_contact", Usage::Storage, 12 * n),
            BufferSpec::data("list_scan_params", Usage::Uniform, &t.list_scan),
            BufferSpec::zeroed("dynamic_scan", Usage::Storage, 4 * (n + 1)),
            BufferSpec::zeroed("stress_scan", Usage::Storage, 4 * (n + 1)),
            BufferSpec::zeroed("force_scan", Usage::Storage, 4 * (n + 1)),
            BufferSpec::zeroed("dynamic_scan_blocks", Usage::Storage, blocks(n + 1)),
            BufferSpec::zeroed("stress_scan_blocks", Usage::Storage, blocks(n + 1)),
            BufferSpec::zeroed("force_scan_blocks", Usage::Storage, blocks(n + 1)),
            BufferSpec::zeroed("dynamic_list", Usage::Storage, 4 * n),
            BufferSpec::zeroed("stress_list", Usage::Storage, 4 * n),
            BufferSpec::zeroed("force_list", Usage::Storage, 4 * n),
            BufferSpec::zeroed("particle_counts", Usage::Report, 16),
            BufferSpec::data("particle_dispatch", Usage::Indirect, &t.no_dispatch),
            BufferSpec::data("activation_gate", Usage::Storage, &t.gate),
            // Filled by the stepper from its pipelines' grids (`GpuStepper::new`).
            BufferSpec::zeroed("activation_full_args", Usage::Storage, gated_args_bytes),
            BufferSpec::zeroed("activation_args", Usage::Indirect, gated_args_bytes),
            BufferSpec::data("tet_weight", Usage::Storage, &t.ones_tets),
            BufferSpec::data("node_fixed", Usage::Storage, &t.node_fixed),
            BufferSpec::zeroed("node_flags", Usage::Storage, 4 * nv),
            BufferSpec::data("contact_weight", Usage::Storage, &t.ones_vertices),
            BufferSpec::zeroed("coupled_slots", Usage::Storage, 4 * n_slots.max(1)),
            BufferSpec::zeroed("coupled_count", Usage::Storage, 4 * nv),
            BufferSpec::zeroed("coupled_valid", Usage::Storage, 4),
            BufferSpec::zeroed(
                "particle_partials",
                Usage::Storage,
                4 * crate::cpu::particle_reduce::LANE as u64 * partial_blocks.max(1),
            ),
            BufferSpec::zeroed("particle_stats", Usage::Report, 32),
        ],
    }
}

/// Without particles: 4-byte stand-ins for the bindings of the kernels' `PARTICLES = false`
/// variants (fem_forces, contact, gather_coupled, tool_force), which never read them (the
/// idle workgroup of tool_force_particles reads a zero count).
pub fn particle_stubs() -> BufferGroup<'static> {
    let names = [
        "tet_weight",
        "contact_weight",
        "node_flags",
        "particle_slot_offsets",
        "particle_slots",
        "particle_weights",
        "particle_mode",
        "particle_force_sum",
        "particle_rest",
        "particle_displacements",
        "particle_velocities",
        "particle_area",
        "particle_gradient",
        "particle_contact_offset",
        "particle_counts",
        "dynamic_list",
        "coupled_slots",
        "coupled_count",
        "coupled_valid",
    ];
    BufferGroup {
        name: "particle stand-ins",
        specs: names
            .iter()
            .map(|&n| BufferSpec::zeroed(n, Usage::Storage, 4))
            .collect(),
    }
}

/// Design 8's slaving as the GPU runs it (`particles.coupling = "exact"` under
/// `activation = "all"`: the model's slaving, fixed for the run): the vertex masses, and the
/// fits as two CSRs, vertex → (particle, s) and particle → (vertex, s) with vertices
/// ascending (the order `Slaving::transfer_forces` adds them in).
pub struct ExactTables {
    /// Per vertex, its lumped mass, kg (0 on slaved vertices).
    pub mass: Vec<f32>,
    /// Per vertex, 0 fixed, −1 slaved, else 1 / mass.
    pub inv_mass: Vec<f32>,
    /// CSR offsets (n_vertices + 1) of the vertices' fits.
    pub fit_offsets: Vec<u32>,
    /// The fits' particles.
    pub fit_particles: Vec<u32>,
    /// The fits' weights s.
    pub fit_weights: Vec<f32>,
    /// CSR offsets (n_particles + 1) of the particles' slaved vertices.
    pub slave_offsets: Vec<u32>,
    /// The slaved vertices each particle takes force from.
    pub slave_vertices: Vec<u32>,
    /// Their weights s.
    pub slave_weights: Vec<f32>,
}

impl ExactTables {
    /// The tables of `model` (None without the exact coupling): its slaving, and where the
    /// dynamic set follows the tool ([`crate::gpu::stepper::exact_activates_on_cpu`]) lists
    /// sized for every vertex–particle slot, which bounds every slaving's (a vertex fits
    /// over particles it hosts), so that each activation's slaving fits in the same buffers.
    pub fn new(model: &Model) -> Option<ExactTables> {
        let sl = model.slaving.as_ref()?;
        let capacity = crate::gpu::stepper::exact_activates_on_cpu(model)
            .then(|| model.particles.as_ref().map(|p| p.slots.len()))
            .flatten();
        let mut t = ExactTables::of(model, sl)?;
        if let Some(c) = capacity {
            t.fit_particles.resize(c.max(t.fit_particles.len()), 0);
            t.fit_weights.resize(c.max(t.fit_weights.len()), 0.0);
            t.slave_vertices.resize(c.max(t.slave_vertices.len()), 0);
            t.slave_weights.resize(c.max(t.slave_weights.len()), 0.0);
        }
        Some(t)
    }

    /// The tables of `sl`, a slaving of `model`'s particles (None without particles).
    pub fn of(model: &Model, sl: &crate::cpu::exact_coupling::Slaving) -> Option<ExactTables> {
        let n = model.particles.as_ref()?.len();
        let inv_mass = (0..model.n_vertices())
            .map(|v| {
                if model.inv_mass[v] == 0.0 {
                    0.0
                } else if sl.slaved[v] {
                    -1.0
                } else {
                    1.0 / sl.vertex_mass[v]
                }
            })
            .collect();
        let mut fit_offsets = vec![0u32];
        let (mut fit_particles, mut fit_weights) = (Vec::new(), Vec::new());
        let mut per_particle: Vec<Vec<(u32, f32)>> = vec![Vec::new(); n];
        for (v, fit) in sl.fit.iter().enumerate() {
            if sl.slaved[v] {
                for &(q, s) in fit {
                    fit_particles.push(q);
                    fit_weights.push(s);
                    per_particle[q as usize].push((v as u32, s));
                }
            }
            fit_offsets.push(fit_particles.len() as u32);
        }
        let mut slave_offsets = vec![0u32];
        let (mut slave_vertices, mut slave_weights) = (Vec::new(), Vec::new());
        for list in per_particle {
            for (v, s) in list {
                slave_vertices.push(v);
                slave_weights.push(s);
            }
            slave_offsets.push(slave_vertices.len() as u32);
        }
        Some(ExactTables {
            mass: sl.vertex_mass.clone(),
            inv_mass,
            fit_offsets,
            fit_particles,
            fit_weights,
            slave_offsets,
            slave_vertices,
            slave_weights,
        })
    }
}

/// Design 8's buffers: its per-step arrays (δ, the hosts' forces, the tangent corner forces),
/// the slaved vertices' fading offsets and their clocks (state), and the slaving
/// ([`ExactTables`]; state too where activations re-slave on the CPU, `reslaved`, so that a
/// checkpoint keeps the slaving its masses and lists were made with).
pub fn exact<'a>(
    t: &'a ExactTables,
    n_particles: u32,
    n_vertices: u32,
    reslaved: bool,
) -> BufferGroup<'a> {
    let n = n_particles as u64;
    let nv = n_vertices as u64;
    let usage = if reslaved {
        Usage::State
    } else {
        Usage::Storage
    };
    // An empty list still binds 4 bytes.
    let data_u32 = |name, v: &'a [u32]| match v.is_empty() {
        true => BufferSpec::zeroed(name, usage, 4),
        false => BufferSpec::data(name, usage, v),
    };
    let data_f32 = |name, v: &'a [f32]| match v.is_empty() {
        true => BufferSpec::zeroed(name, usage, 4),
        false => BufferSpec::data(name, usage, v),
    };
    BufferGroup {
        name: "exact coupling",
        specs: vec![
            BufferSpec::zeroed("exact_delta", Usage::Storage, 12 * n),
            BufferSpec::zeroed("exact_host_force", Usage::Storage, 12 * n),
            BufferSpec::zeroed("exact_tangent", Usage::Storage, 48 * n),
            BufferSpec::zeroed("exact_vertex_offset", Usage::State, 12 * nv),
            BufferSpec::zeroed("exact_vertex_timer", Usage::State, 4 * nv),
            BufferSpec::data("exact_mass", usage, &t.mass),
            BufferSpec::data("exact_inv_mass", usage, &t.inv_mass),
            BufferSpec::data("exact_fit_offsets", usage, &t.fit_offsets),
            data_u32("exact_fit_particles", &t.fit_particles),
            data_f32("exact_fit_weights", &t.fit_weights),
            BufferSpec::data("exact_slave_offsets", usage, &t.slave_offsets),
            data_u32("exact_slave_vertices", &t.slave_vertices),
            data_f32("exact_slave_weights", &t.slave_weights),
        ],
    }
}

/// Per-run data of the cardiac stages (split laws, nodal pressure, follower pressure), owned
/// by the stepper while the tables borrow it.
pub struct CardiacTables {
    /// The split laws' uniform.
    pub material: [crate::material::MaterialConstants; 1],
    /// The follower uniform (its load factor is rewritten per batch).
    pub follower_load: [crate::cpu::follower_pressure::FollowerLoad; 1],
    /// The model's constant loads (what `external_forces` starts from each step).
    pub dead_load: Vec<f32>,
}

impl CardiacTables {
    /// The tables of `model` (None when it has no split law and no follower pressure).
    pub fn new(model: &Model) -> Option<CardiacTables> {
        if model.hyperelastic.is_none() && model.follower.is_none() {
            return None;
        }
        Some(CardiacTables {
            material: [model.material_constants()],
            follower_load: [crate::cpu::follower_pressure::FollowerLoad {
                n_faces: model.follower.as_ref().map_or(0, |f| f.n_faces() as u32),
                load_factor: model.follower.as_ref().map_or(0.0, |f| f.load_factor(0.0)),
                _pad0: 0,
                _pad1: 0,
            }],
            dead_load: model.external_forces.clone(),
        })
    }
}

/// The cardiac stages' buffers: the split laws' uniform and per-tet fibres, the nodal
/// pressure arrays, and the follower faces, their CSR corner incidence and the dead loads.
/// Arrays a model does not use are 4-byte stand-ins (their kernels are not in the plan, or
/// their pipeline constant keeps them unread).
pub fn cardiac<'a>(model: &'a Model, t: &'a CardiacTables) -> BufferGroup<'a> {
    let n = model.n_vertices() as u64;
    let m = model.n_tets() as u64;
    let nodal = model.split_variant().is_some_and(|v| v.nodal_pressure);
    let or_stub = |name: &'static str, bytes: u64, used: bool| {
        BufferSpec::zeroed(name, Usage::Storage, if used { bytes.max(4) } else { 4 })
    };
    let mut specs = vec![
        BufferSpec::data("material_constants", Usage::Uniform, &t.material),
        if model.fibres.is_empty() {
            BufferSpec::zeroed("fibres", Usage::Storage, 4)
        } else {
            BufferSpec::data("fibres", Usage::Storage, &model.fibres)
        },
        or_stub("tet_delta_volume", 4 * m, nodal),
        or_stub("vertex_pressure", 4 * n, nodal),
        or_stub("vertex_volumetric_energy", 4 * n, nodal),
        BufferSpec::data("follower_load", Usage::Uniform, &t.follower_load),
    ];
    match &model.follower {
        Some(f) => {
            specs.push(BufferSpec::data("follower_faces", Usage::Storage, &f.faces));
            specs.push(BufferSpec::data(
                "follower_face_pressure",
                Usage::Storage,
                &f.face_pressure,
            ));
            specs.push(BufferSpec::zeroed(
                "follower_corner_forces",
                Usage::Storage,
                36 * f.n_faces() as u64,
            ));
            specs.push(BufferSpec::data(
                "follower_incidence_offsets",
                Usage::Storage,
                &f.incidence_offsets,
            ));
            specs.push(BufferSpec::data(
                "follower_incidence",
                Usage::Storage,
                &f.incidence,
            ));
            specs.push(BufferSpec::data(
                "dead_load_forces",
                Usage::Storage,
                &t.dead_load,
            ));
            if model.tool.is_none() && model.particles.is_none() {
                // The tool group holds `rest_positions` when there is a tool or particles.
                specs.push(BufferSpec::data(
                    "rest_positions",
                    Usage::Storage,
                    &model.rest,
                ));
            }
        }
        None => {
            for name in [
                "follower_faces",
                "follower_face_pressure",
                "follower_corner_forces",
                "follower_incidence_offsets",
                "follower_incidence",
                "dead_load_forces",
            ] {
                specs.push(BufferSpec::zeroed(name, Usage::Storage, 4));
            }
        }
    }
    BufferGroup {
        name: "cardiac",
        specs,
    }
}

/// Every group a model needs, in order (the neighbour lists come later, sized on the
/// device).
pub fn for_model<'a>(
    model: &'a Model,
    params: &'a StepParams,
    tool_params: &'a ToolParams,
    particles: Option<&'a ParticleTables>,
    cardiac: Option<&'a CardiacTables>,
    exact: Option<&'a ExactTables>,
    max_dim: u32,
) -> Vec<BufferGroup<'a>> {
    let mut groups = vec![fem(model, params, max_dim), tool(model, tool_params)];
    if let Some(t) = cardiac {
        groups.push(self::cardiac(model, t));
    }
    match (particles, &model.particles) {
        (Some(t), Some(p)) => {
            groups.push(self::particles(p, &t.grid, &t.setup_scans));
            groups.push(particle_step(model, t));
            if let Some(x) = exact {
                groups.push(self::exact(
                    x,
                    t.params.n_particles,
                    model.n_vertices() as u32,
                    crate::gpu::stepper::exact_activates_on_cpu(model),
                ));
            }
        }
        _ => groups.push(particle_stubs()),
    }
    groups
}

/// The uniform of one prefix-sum use (WGSL `ScanParams`): the number of values.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ScanParams {
    /// Values to scan.
    pub n: u32,
    /// Padding to 16 bytes.
    pub _pad: [u32; 3],
}

impl ScanParams {
    /// The uniform for `n` values.
    pub fn new(n: u32) -> ScanParams {
        ScanParams { n, _pad: [0; 3] }
    }

    /// Bytes of the block-totals buffer a scan of `n` values needs (one more for the total).
    pub fn blocks_bytes(n: u32) -> u64 {
        4 * (crate::cpu::scan::n_blocks(n as usize) as u64 + 1)
    }
}

/// The particles' static data and the reference grid of the neighbour build. `scans` holds
/// the uniforms of the two prefix sums (cells, neighbour counts), owned by the caller.
pub fn particles<'a>(
    p: &'a crate::particles::Particles,
    grid: &'a crate::particles::params::GridParams,
    scans: &'a [ScanParams; 2],
) -> BufferGroup<'a> {
    let n = p.len() as u64;
    let nc = grid.n_cells as u64;
    BufferGroup {
        name: "particles",
        specs: vec![
            BufferSpec::data("grid_params", Usage::Uniform, std::slice::from_ref(grid)),
            BufferSpec::data("particle_rest", Usage::Storage, &p.rest),
            BufferSpec::data("particle_host", Usage::Storage, &p.host),
            BufferSpec::data("particle_weights", Usage::Storage, &p.weights),
            BufferSpec::data("particle_area", Usage::Storage, &p.contact_area),
            BufferSpec::data("particle_contact_offset", Usage::Storage, &p.contact_offset),
            BufferSpec::data("particle_tet_offsets", Usage::Storage, &p.tet_offsets),
            BufferSpec::data("particle_slot_offsets", Usage::Storage, &p.slot_offsets),
            BufferSpec::data("particle_slots", Usage::Storage, &p.slots),
            BufferSpec::data("particle_core_mass", Usage::Storage, &p.core_mass),
            BufferSpec::zeroed("particle_cell", Usage::Storage, 4 * n),
            BufferSpec::zeroed("cell_offsets", Usage::Storage, 4 * (nc + 1)),
            BufferSpec::zeroed("cell_fill", Usage::Storage, 4 * nc),
            BufferSpec::zeroed("cell_particles", Usage::Storage, 4 * n),
            BufferSpec::zeroed("neighbour_offsets", Usage::Storage, 4 * (n + 1)),
            BufferSpec::data("cell_scan_params", Usage::Uniform, &scans[0..1]),
            BufferSpec::zeroed(
                "cell_scan_blocks",
                Usage::Storage,
                ScanParams::blocks_bytes(scans[0].n),
            ),
            BufferSpec::data("neighbour_scan_params", Usage::Uniform, &scans[1..2]),
            BufferSpec::zeroed(
                "neighbour_scan_blocks",
                Usage::Storage,
                ScanParams::blocks_bytes(scans[1].n),
            ),
        ],
    }
}
