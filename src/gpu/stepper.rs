//! The GPU backend: records the step plan, many steps per command buffer, each stage a
//! labelled debug group; bind groups are built once, dispatch sizes are chosen when a batch
//! is recorded (or read by the GPU from an indirect-argument buffer), and each batch copies
//! its small report into the next slot of a readback ring, mapped without blocking.

use crate::contact::ToolState;
use crate::error::{PalpateError, Result};
use crate::gpu::buffers::{GpuBuffers, Usage};
use crate::gpu::groups::{STATS_BYTES, STATUS_BYTES};
use crate::gpu::kernel::{ComputeKernel, Dispatch};
use crate::gpu::GpuContext;
use crate::model::Model;
use crate::params::{stat, StepParams};
use crate::plan::{Domain, Entry, Fusions, StepPlan};
use crate::stepper::{BatchInput, BatchReport, State, Stepper, RING};
use std::collections::VecDeque;
use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::Arc;

pub use crate::plan::Stage;

/// True when `model` has the exact coupling with a dynamic set the tool moves: its
/// activations re-slave on the CPU (a CPU twin beside the GPU stepper runs `ActivateExact`
/// at each activation step, `cpu/stepper/gpu_activation.rs`); under `activation = "all"`
/// the slaving is fixed and the GPU runs everything, and without a tool no particle stage
/// runs.
pub fn exact_activates_on_cpu(model: &Model) -> bool {
    model.slaving.is_some()
        && model.tool.is_some()
        && model
            .particles
            .as_ref()
            .is_some_and(|p| !p.settings.all_active)
}

/// `PALPATE_GPU_PRERECORD`: `0` records each batch when it is submitted, `1` (or unset, or
/// empty) records the next batch while the GPU runs this one; any other value is an error
/// naming the variable.
pub fn prerecord_from_env() -> Result<bool> {
    parse_prerecord(std::env::var("PALPATE_GPU_PRERECORD").ok().as_deref())
}

/// [`prerecord_from_env`] of the variable's value (None: unset).
pub fn parse_prerecord(value: Option<&str>) -> Result<bool> {
    match value {
        Some("0") => Ok(false),
        None | Some("") | Some("1") => Ok(true),
        Some(other) => Err(PalpateError::Usage(format!(
            "PALPATE_GPU_PRERECORD='{other}' is not one of 0 (record each batch at its submission), 1 (record ahead, the default)"
        ))),
    }
}

/// The pipeline-overridable constants a stage's kernels are built with for `model`.
pub fn stage_constants(stage: Stage, model: &Model) -> Vec<(&'static str, f64)> {
    match stage {
        Stage::FemForces => {
            let v = model.fem_variant();
            // Design 8's tets keep their full energy: no energy weights.
            let weighted = model.particles.is_some() && model.slaving.is_none();
            vec![
                ("MATERIAL", v.model as u32 as f64),
                ("VISCOUS", flag(v.viscous)),
                ("PARTICLES", flag(weighted)),
            ]
        }
        Stage::FemForcesSplit => {
            let v = model.split_variant().unwrap_or_default();
            vec![
                ("MATERIAL", v.model as u32 as f64),
                ("VISCOUS", flag(v.viscous)),
                ("VOLUMETRIC", v.volumetric as u32 as f64),
                ("NODAL_PRESSURE", flag(v.nodal_pressure)),
            ]
        }
        Stage::NodalPressure => {
            let v = model.split_variant().unwrap_or_default();
            vec![("VOLUMETRIC", v.volumetric as u32 as f64)]
        }
        _ => stage_flags(stage, model),
    }
}

fn flag(b: bool) -> f64 {
    if b {
        1.0
    } else {
        0.0
    }
}

/// The boolean and material constants of the coupled stages.
fn stage_flags(stage: Stage, model: &Model) -> Vec<(&'static str, f64)> {
    let tool = flag(model.tool.is_some());
    let particles = flag(model.particles.is_some());
    match stage {
        Stage::Reduce => vec![("CONTACT", tool)],
        Stage::GatherCoupled => vec![("CONTACT", tool), ("PARTICLES", particles)],
        Stage::Contact | Stage::ToolForce => vec![("PARTICLES", particles)],
        Stage::Activate | Stage::ActivateExact => vec![("TOOL", tool)],
        Stage::SphStress => {
            let v = model.fem_variant();
            vec![
                ("MATERIAL", v.model as u32 as f64),
                ("VISCOUS", flag(v.viscous)),
            ]
        }
        Stage::Follow => vec![("VISCOUS", flag(model.fem_variant().viscous))],
        Stage::ExactStress => {
            vec![("MATERIAL", model.fem_variant().model as u32 as f64)]
        }
        Stage::ExactForces => vec![("TOOL", tool)],
        Stage::ExactGather => vec![("CONTACT", tool)],
        Stage::SphForces => vec![("ACCUMULATE", 0.0), ("TOOL", tool)],
        Stage::SphForcesAccumulate => vec![("ACCUMULATE", 1.0), ("TOOL", tool)],
        _ => Vec::new(),
    }
}

/// The pipelines of one stage (stateless; shared by any simulation of the same variant).
pub struct StagePipelines {
    /// The stage.
    pub stage: Stage,
    /// One pipeline per entry point, in dispatch order.
    pub kernels: Vec<(Entry, ComputeKernel)>,
}

impl StagePipelines {
    /// Build the stage's pipelines for `model`.
    pub fn new(ctx: &GpuContext, stage: Stage, model: &Model) -> Result<Self> {
        StagePipelines::build(ctx, stage, stage.entries(), &stage_constants(stage, model))
    }

    /// The pipeline of fused dispatch `f`, with its host's constants and its rider's (the
    /// host's where both set one), under the host's stage.
    pub fn fused(ctx: &GpuContext, f: &crate::plan::Fusion, model: &Model) -> Result<Self> {
        let mut constants = stage_constants(f.host, model);
        for c in stage_constants(f.rider, model) {
            if !constants.iter().any(|(name, _)| *name == c.0) {
                constants.push(c);
            }
        }
        StagePipelines::build(ctx, f.host, &[f.entry], &constants)
    }

    /// Pipelines for `entries` under `stage`, each with those of `constants` its shader
    /// declares.
    fn build(
        ctx: &GpuContext,
        stage: Stage,
        entries: &[Entry],
        constants: &[(&'static str, f64)],
    ) -> Result<Self> {
        let kernels = entries
            .iter()
            .map(|e| {
                // Each entry gets the constants its shader declares.
                let source = crate::gpu::kernel_source(e.file).unwrap_or("");
                let own: Vec<(&str, f64)> = constants
                    .iter()
                    .copied()
                    .filter(|(name, _)| source.contains(&format!("override {name}")))
                    .collect();
                Ok((*e, ComputeKernel::new(ctx, e.file, e.entry, &own)?))
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(StagePipelines { stage, kernels })
    }
}

/// For each position of `plan`, its index in `stages` (the stage's own passes) and what a
/// batch records there with the fused dispatches in `stages`: the fused one at a fusion's
/// `at`, None at its `skipped`.
fn map_plan(plan: &StepPlan, stages: &[BoundStage]) -> Result<(Vec<usize>, Vec<Option<usize>>)> {
    let plan_stage = plan
        .stages
        .iter()
        .map(|p| {
            stages
                .iter()
                .position(|b| b.pipelines.stage == p.stage && b.carries.is_none())
                .ok_or_else(|| {
                    PalpateError::Gpu(format!("stage '{}' has no pipelines", p.stage.name()))
                })
        })
        .collect::<Result<Vec<_>>>()?;
    let mut fused_stage: Vec<Option<usize>> = plan_stage.iter().map(|&k| Some(k)).collect();
    for f in plan.gpu_fusions() {
        let built = stages
            .iter()
            .position(|b| b.pipelines.stage == f.host && b.carries == Some(f.rider));
        if let Some(b) = built {
            fused_stage[f.at] = Some(b);
            fused_stage[f.skipped] = None;
        }
    }
    Ok((plan_stage, fused_stage))
}

/// A stage's pipelines with their bind groups on one simulation's buffers.
struct BoundStage {
    pipelines: StagePipelines,
    bind_groups: Vec<wgpu::BindGroup>,
    /// Per kernel, the byte offset of its arguments in `activation_args` when it is gated
    /// ([`Domain::Gated`]).
    gated: Vec<Option<u64>>,
    /// The stage whose work rides on this one's dispatch ([`crate::plan::Fusion`]), if any.
    carries: Option<Stage>,
    /// The label of its pass and debug group: the stage's name, with the rider's after a
    /// `+`.
    label: String,
}

impl BoundStage {
    /// `pipelines` bound to `buffers`.
    fn bind(
        ctx: &GpuContext,
        buffers: &GpuBuffers,
        pipelines: StagePipelines,
        carries: Option<Stage>,
    ) -> Result<BoundStage> {
        let bind_groups = pipelines
            .kernels
            .iter()
            .map(|(e, k)| k.bind(ctx, buffers, e.aliases))
            .collect::<Result<Vec<_>>>()?;
        let label = match carries {
            Some(rider) => format!("{}+{}", pipelines.stage.name(), rider.name()),
            None => pipelines.stage.name().to_string(),
        };
        Ok(BoundStage {
            gated: vec![None; pipelines.kernels.len()],
            pipelines,
            bind_groups,
            carries,
            label,
        })
    }
}

/// Mean GPU time per stage of one step, from timestamp queries.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StageTimes {
    /// (stage, mean ns per run), in plan order. A fused dispatch is timed under its host.
    pub per_stage: Vec<(Stage, f64)>,
    /// (rider, host) of each fused dispatch: the rider's time is in its host's.
    pub carried: Vec<(Stage, Stage)>,
}

impl StageTimes {
    /// Mean ns of `stage` (0 when it is not in the plan, or rides on another's dispatch:
    /// see `carried`).
    pub fn ns(&self, stage: Stage) -> f64 {
        self.per_stage
            .iter()
            .find(|(s, _)| *s == stage)
            .map_or(0.0, |(_, t)| *t)
    }
}

/// State of one readback slot's mapping.
const SLOT_PENDING: u8 = 0;
const SLOT_MAPPED: u8 = 1;
const SLOT_FAILED: u8 = 2;

struct RingSlot {
    buffer: wgpu::Buffer,
    mapped: Arc<AtomicU8>,
}

struct InFlight {
    slot: usize,
    steps: u32,
    tool_to: glam::DVec3,
}

/// The buffers an activation writes for the steps until the next one (lists, counts,
/// indirect arguments, tet weights, vertex flags, contact weights, the coupled vertices'
/// slots): checkpointed with the state, so a restore resumes with those its modes were built
/// with.
pub const ACTIVATION_PRODUCTS: [&str; 11] = [
    "dynamic_list",
    "stress_list",
    "force_list",
    "particle_counts",
    "particle_dispatch",
    "tet_weight",
    "node_flags",
    "contact_weight",
    "coupled_slots",
    "coupled_count",
    "coupled_valid",
];

/// GPU stepper for one model.
pub struct GpuStepper {
    ctx: Arc<GpuContext>,
    plan: StepPlan,
    /// One bound stage per distinct stage of the plan (sub-steps repeat stages), then one
    /// per fused dispatch.
    stages: Vec<BoundStage>,
    /// For each plan position, its index in `stages`.
    plan_stage: Vec<usize>,
    /// For each plan position, what a batch records there with the plan's fusions: its
    /// index in `stages` (a fused dispatch's at the fusion's `at`), None where the pass
    /// rides on another.
    fused_stage: Vec<Option<usize>>,
    /// Whether batches record the fused dispatches that were built (`set_fusion`).
    fusion: bool,
    /// Whether `submit` records the next batch while the GPU runs the one it submitted
    /// ([`Ahead`]; `PALPATE_GPU_PRERECORD=0` turns it off).
    prerecord: bool,
    /// The batch recorded ahead, for the `submit` that asks for it.
    ahead: Option<Ahead>,
    /// How many submitted batches had been recorded ahead.
    ahead_used: u64,
    model_particles: Option<crate::gpu::groups::ParticleTables>,
    /// The follower uniform (None without follower pressures).
    follower_load: Option<crate::cpu::follower_pressure::FollowerLoad>,
    n_particles: u32,
    buffers: GpuBuffers,
    params: StepParams,
    n_vertices: u32,
    n_tets: u32,
    n_surface: u32,
    has_tool: bool,
    tool_at: glam::DVec3,
    ring: Vec<RingSlot>,
    report_layout: Vec<(&'static str, u64, u64)>,
    in_flight: VecDeque<InFlight>,
    next_slot: usize,
    steps_done: u64,
    counts: Vec<(Stage, u32)>,
    /// The last checkpoint (the state at rest until the first `checkpoint`): a copy of every
    /// checkpointed buffer, the step count and where the tool was.
    checkpoint: Vec<(&'static str, wgpu::Buffer)>,
    checkpoint_steps: (u64, glam::DVec3),
    readback_state: Option<wgpu::Buffer>,
    /// Design 8 under the tool: the CPU twin that runs its activations
    /// ([`exact_activates_on_cpu`]).
    exact_twin: Option<ExactTwin>,
    /// Where an activation on the CPU twin reads the GPU's arrays into.
    staging: Option<wgpu::Buffer>,
}

/// A batch recorded while the GPU ran the one before it. A batch's commands depend only on
/// where it starts, how many steps it takes, its readback slot and whether the fused
/// dispatches are recorded (the tool's motion, the parameters and the state are buffers
/// written before its submission), so `submit` uses it when it asks for the same batch, and
/// records afresh otherwise. On a real GPU a step is short enough that recording a batch on
/// the CPU (several µs per dispatch) would otherwise add to every batch waited for.
struct Ahead {
    /// Steps done before the batch.
    first: u64,
    steps: u32,
    /// Its ring slot.
    slot: usize,
    /// Whether it records the fused dispatches.
    fusion: bool,
    commands: wgpu::CommandBuffer,
}

/// The CPU stepper beside a GPU stepper whose design 8 activations re-slave on the CPU, and
/// the model it was made from (for the slaving's tables).
struct ExactTwin {
    stepper: Box<crate::cpu::CpuStepper>,
    model: Arc<Model>,
    /// The plan position of `ActivateExact`, which batches do not record.
    at: usize,
    /// 12 zeros per particle: δ after an activation that changed the sets (3 per particle),
    /// and the tangent forces of the particles that left S (12 each).
    zeros: Vec<u32>,
    /// The last activations' round trips, oldest first.
    round_trips: VecDeque<RoundTrip>,
}

/// One design 8 activation done on the CPU twin ([`GpuStepper::take_exact_round_trips`]),
/// seconds of wall clock on the stepping thread.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RoundTrip {
    /// Waiting for the GPU to finish the steps recorded before the activation.
    pub drain: f64,
    /// Copying the arrays the twin reads into the staging buffer and mapping it.
    pub read: f64,
    /// The twin's `ActivateExact`.
    pub activate: f64,
    /// Queueing the writes of what it changed (uploaded with the next submission), and the
    /// slaving's tables when a set changed.
    pub write: f64,
    /// Whether the dynamic or blending set changed (the tables were written).
    pub changed: bool,
}

impl RoundTrip {
    /// What the round trip adds to the steps: read + activate + write (the drain is the GPU's
    /// own steps finishing).
    pub fn cost(&self) -> f64 {
        self.read + self.activate + self.write
    }
}

/// How many round trips [`GpuStepper::take_exact_round_trips`] keeps.
const ROUND_TRIPS_KEPT: usize = 4096;

impl GpuStepper {
    /// Upload `model`, build its plan's pipelines and bind groups and the readback ring, with
    /// the fused dispatches `PALPATE_GPU_FUSION` asks for ([`Fusions::from_env`]).
    pub fn new(ctx: Arc<GpuContext>, model: &Model, params: StepParams) -> Result<GpuStepper> {
        GpuStepper::with_fusions(ctx, model, params, Fusions::from_env()?)
    }

    /// [`Self::new`] with the fused dispatches `fusions` builds.
    pub fn with_fusions(
        ctx: Arc<GpuContext>,
        model: &Model,
        params: StepParams,
        fusions: Fusions,
    ) -> Result<GpuStepper> {
        let n = model.n_vertices() as u64;
        let m = model.n_tets() as u64;
        if n > u32::MAX as u64 / 4 || m > u32::MAX as u64 / 4 {
            return Err(PalpateError::Gpu(format!(
                "{n} vertices / {m} tets exceed the 32-bit indices of the kernels"
            )));
        }
        let max_dim = ctx.limits.max_compute_workgroups_per_dimension;
        let tool_params = model.tool_params();
        let tables = crate::gpu::groups::ParticleTables::new(model, &params);
        let cardiac = crate::gpu::groups::CardiacTables::new(model);
        let exact = crate::gpu::groups::ExactTables::new(model);
        let groups = crate::gpu::groups::for_model(
            model,
            &params,
            &tool_params,
            tables.as_ref(),
            cardiac.as_ref(),
            exact.as_ref(),
            max_dim,
        );
        let mut buffers = GpuBuffers::new(&ctx, &groups)?;
        drop(groups);
        if let Some(t) = &tables {
            crate::gpu::setup::build_neighbour_lists(&ctx, &mut buffers, &t.grid)?;
            crate::gpu::setup::run_passes(
                &ctx,
                &buffers,
                &[crate::gpu::setup::SetupPass {
                    file: "sph_setup",
                    entry: "sph_setup",
                    dispatch: crate::gpu::setup::SetupDispatch::Items(t.params.n_particles),
                    aliases: &[],
                }],
            )?;
        }
        let plan = StepPlan::for_model_at(model, model.particle_substeps(params.dt as f64));
        // Bound for the plan and for the plan at another sub-step count (SphForcesAccumulate
        // runs only from two sub-steps; [`crate::substeps`] changes the count during a run).
        let other = plan.with_particle_substeps(if plan.contains(Stage::SphForcesAccumulate) {
            1
        } else {
            2
        });
        let mut stages: Vec<BoundStage> = Vec::new();
        for p in plan.stages.iter().chain(&other.stages) {
            if !stages.iter().any(|b| b.pipelines.stage == p.stage) {
                let pipelines = StagePipelines::new(&ctx, p.stage, model)?;
                stages.push(BoundStage::bind(&ctx, &buffers, pipelines, None)?);
            }
        }
        // The fused dispatches `fusions` asks for. A fused kernel binds both stages' arrays:
        // where the adapter cannot build it (fewer storage buffers per stage than it binds, a
        // driver that refuses it), the two keep their own passes.
        for f in plan.gpu_fusions().into_iter().chain(other.gpu_fusions()) {
            let built = |b: &BoundStage| b.pipelines.stage == f.host && b.carries == Some(f.rider);
            if !fusions.builds(&f) || stages.iter().any(built) {
                continue;
            }
            let bound = StagePipelines::fused(&ctx, &f, model)
                .and_then(|p| BoundStage::bind(&ctx, &buffers, p, Some(f.rider)));
            if let Ok(bound) = bound {
                stages.push(bound);
            }
        }
        let (plan_stage, fused_stage) = map_plan(&plan, &stages)?;
        let mut report_layout = Vec::new();
        let mut offset = 0;
        for (name, buf) in buffers.with_usage(Usage::Report) {
            report_layout.push((name, offset, buf.size()));
            offset += buf.size();
        }
        let ring = (0..RING)
            .map(|k| RingSlot {
                buffer: ctx.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(&format!("readback ring {k}")),
                    size: offset.max(4),
                    usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                }),
                mapped: Arc::new(AtomicU8::new(SLOT_PENDING)),
            })
            .collect();
        ctx.check_errors()?;
        let mut stepper = GpuStepper {
            counts: plan.stages.iter().map(|p| (p.stage, 0)).collect(),
            plan,
            stages,
            plan_stage,
            fused_stage,
            fusion: fusions != Fusions::None,
            n_particles: tool_params.n_particles,
            model_particles: tables,
            follower_load: model
                .follower
                .as_ref()
                .and(cardiac.as_ref())
                .map(|c| c.follower_load[0]),
            buffers,
            params,
            n_vertices: n as u32,
            n_tets: m as u32,
            n_surface: tool_params.n_surface,
            has_tool: model.tool.is_some(),
            tool_at: model
                .tool
                .as_ref()
                .map_or(glam::DVec3::ZERO, |t| t.tool.position_at(0.0)),
            ring,
            report_layout,
            in_flight: VecDeque::new(),
            next_slot: 0,
            steps_done: 0,
            checkpoint: Vec::new(),
            checkpoint_steps: (0, glam::DVec3::ZERO),
            readback_state: None,
            exact_twin: None,
            staging: None,
            prerecord: prerecord_from_env()?,
            ahead: None,
            ahead_used: 0,
            ctx,
        };
        if exact_activates_on_cpu(model) {
            let model = Arc::new(model.clone());
            let at = stepper
                .plan
                .stages
                .iter()
                .position(|p| p.stage == Stage::ActivateExact)
                .ok_or_else(|| PalpateError::Internal("design 8 plans no activation".into()))?;
            // On the thread that steps this stepper (a pool of one): the activation runs while
            // the GPU waits, and a haptic session's other core stays the servo's.
            let twin = crate::cpu::CpuStepper::on_this_thread(model.clone(), params)?;
            stepper.check_neighbour_lists(&twin)?;
            stepper.exact_twin = Some(ExactTwin {
                stepper: Box::new(twin),
                zeros: vec![0; 12 * stepper.n_particles as usize],
                model,
                at,
                round_trips: VecDeque::new(),
            });
        }
        stepper.fill_gated_args()?;
        // The state at rest is the first checkpoint.
        stepper.checkpoint()?;
        Ok(stepper)
    }

    /// Give each gated pass its slot in `activation_args` and write its whole grid into
    /// `activation_full_args`, which `activate_gate` copies when the dynamic set changed.
    fn fill_gated_args(&mut self) -> Result<()> {
        let max_dim = self.ctx.limits.max_compute_workgroups_per_dimension;
        let mut full: Vec<u32> = Vec::new();
        let mut slots = Vec::new();
        for (k, bound) in self.stages.iter().enumerate() {
            for (j, (entry, kernel)) in bound.pipelines.kernels.iter().enumerate() {
                let Domain::Gated(base) = entry.domain else {
                    continue;
                };
                let (x, y) = match self.dispatch_for(*base, kernel)? {
                    Dispatch::Items(n) => {
                        crate::gpu::kernel::grid_for(n, kernel.items_per_workgroup, max_dim)
                    }
                    Dispatch::One => (1, 1),
                    Dispatch::Indirect(..) => {
                        return Err(PalpateError::Gpu(format!(
                            "{}: a gated pass needs a direct domain",
                            kernel.label
                        )))
                    }
                };
                slots.push((k, j, 4 * full.len() as u64));
                full.extend([x, y, 1]);
            }
        }
        if full.is_empty() {
            return Ok(());
        }
        let buf = self.buffers.require("activation_full_args")?;
        if 4 * full.len() as u64 > buf.size() {
            return Err(PalpateError::Gpu(format!(
                "{} gated passes do not fit 'activation_full_args'",
                full.len() / 3
            )));
        }
        self.ctx
            .queue
            .write_buffer(buf, 0, bytemuck::cast_slice(&full));
        for (k, j, offset) in slots {
            self.stages[k].gated[j] = Some(offset);
        }
        Ok(())
    }

    /// Make the next activation a full one: every pass runs, as if the dynamic set had
    /// changed. The stepper does this after the host writes a buffer (the gated passes'
    /// products may no longer match the modes); tests use it to compare against the full
    /// update.
    pub fn raise_activation_gate(&self) -> Result<()> {
        if self.n_particles > 0 {
            self.ctx.queue.write_buffer(
                self.buffers.require("activation_gate")?,
                0,
                bytemuck::bytes_of(&1u32),
            );
        }
        Ok(())
    }

    /// How many activations rebuilt the sets and lists (the dynamic set changed, or the host
    /// wrote a buffer) and how many skipped that, since the stepper was made: (full,
    /// skipped). (0, 0) without particles. Design 8 under the tool: its CPU twin's counts
    /// (full and region passes, unchanged ones).
    pub fn activation_counts(&self) -> Result<(u32, u32)> {
        if self.n_particles == 0 {
            return Ok((0, 0));
        }
        if let Some(t) = &self.exact_twin {
            let c = t.stepper.activation_counts().unwrap_or_default();
            return Ok(((c.full + c.region) as u32, c.unchanged as u32));
        }
        let gate = self.read_f32("activation_gate")?;
        Ok((gate[2].to_bits(), gate[3].to_bits()))
    }

    /// The context this stepper runs on.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// The step plan this stepper records.
    pub fn plan(&self) -> &StepPlan {
        &self.plan
    }

    /// The dispatch of `kernel` over `domain` (its lanes size a covering grid).
    fn dispatch_for(&self, domain: Domain, kernel: &ComputeKernel) -> Result<Dispatch<'_>> {
        Ok(match domain {
            Domain::Tets => Dispatch::Items(self.n_tets),
            Domain::Vertices => Dispatch::Items(self.n_vertices),
            Domain::VerticesAndTets => Dispatch::Items(self.n_vertices.max(self.n_tets)),
            Domain::SurfaceVertices => Dispatch::Items(self.n_surface),
            Domain::FollowerFaces => Dispatch::Items(self.follower_load.map_or(0, |f| f.n_faces)),
            Domain::Particles => Dispatch::Items(self.n_particles),
            Domain::ParticlesPlusOne => Dispatch::Items(self.n_particles + 1),
            Domain::ParticleScanRuns => {
                Dispatch::Items(crate::cpu::scan::n_runs(self.n_particles + 1))
            }
            Domain::DynamicParticles if self.n_particles > 0 => {
                Dispatch::Indirect(self.buffers.require("particle_dispatch")?, 0)
            }
            Domain::DynamicParticles => Dispatch::Items(0),
            Domain::OneWorkgroup => Dispatch::One,
            Domain::Indirect(name, offset) => {
                Dispatch::Indirect(self.buffers.require(name)?, offset)
            }
            // Items such that the grid's threads cover every particle in at most
            // MAX_RIDER_ROUNDS rounds.
            Domain::CoveringParticles(base) => match self.dispatch_for(*base, kernel)? {
                Dispatch::Items(n) => {
                    let lanes = (kernel.workgroup_size / kernel.items_per_workgroup.max(1)).max(1);
                    let per_item = lanes * crate::plan::MAX_RIDER_ROUNDS;
                    Dispatch::Items(n.max(self.n_particles.div_ceil(per_item)))
                }
                other => other,
            },
            Domain::Gated(_) => {
                return Err(PalpateError::Gpu(
                    "a gated pass has no slot in 'activation_args'".into(),
                ))
            }
        })
    }

    /// Record the plan's fused dispatches (the default; those the stepper built: none with
    /// `PALPATE_GPU_FUSION=0`) or every stage's own passes. The two run the same WGSL
    /// expressions (bit for bit on lavapipe: `particles::fused_gpu_passes_equal_the_plan_s`).
    pub fn set_fusion(&mut self, on: bool) {
        self.fusion = on;
    }

    /// Record each batch when it is submitted (`false`), or also the next one while the GPU
    /// runs it where nothing else is in flight (`true`, the default unless
    /// `PALPATE_GPU_PRERECORD=0`: `Ahead`). The same commands either way.
    pub fn set_prerecord(&mut self, on: bool) {
        self.prerecord = on;
        self.ahead = None;
    }

    /// How many submitted batches had been recorded ahead ([`Self::set_prerecord`]).
    pub fn batches_recorded_ahead(&self) -> u64 {
        self.ahead_used
    }

    /// The fused dispatches batches record now: (host, rider) in plan order (empty with the
    /// fusion off, or where none was built).
    pub fn fused_passes(&self) -> Vec<(Stage, Stage)> {
        (0..self.plan.stages.len())
            .filter_map(|k| self.recorded_at(k))
            .filter_map(|b| {
                let bound = &self.stages[b];
                bound.carries.map(|rider| (bound.pipelines.stage, rider))
            })
            .collect()
    }

    /// What a batch records at plan position `k`: an index in `stages`, None where the pass
    /// rides on a fused dispatch.
    fn recorded_at(&self, k: usize) -> Option<usize> {
        if self.fusion {
            self.fused_stage[k]
        } else {
            Some(self.plan_stage[k])
        }
    }

    fn record_stage_at(&self, pass: &mut wgpu::ComputePass<'_>, k: usize) -> Result<()> {
        let bound = &self.stages[k];
        let max_dim = self.ctx.limits.max_compute_workgroups_per_dimension;
        pass.push_debug_group(&bound.label);
        for (((entry, kernel), bind_group), gated) in bound
            .pipelines
            .kernels
            .iter()
            .zip(&bound.bind_groups)
            .zip(&bound.gated)
        {
            let dispatch = match gated {
                Some(offset) => {
                    Dispatch::Indirect(self.buffers.require("activation_args")?, *offset)
                }
                None => self.dispatch_for(entry.domain, kernel)?,
            };
            kernel.record(pass, bind_group, dispatch, max_dim);
        }
        pass.pop_debug_group();
        Ok(())
    }

    fn read_particles(&mut self) -> Result<Option<crate::stepper::ParticleSnapshot>> {
        if self.n_particles == 0 {
            return Ok(None);
        }
        self.drain()?;
        let n = self.n_particles as usize;
        Ok(Some(crate::stepper::ParticleSnapshot {
            displacements: self.read_f32("particle_displacements")?[..3 * n].to_vec(),
            velocities: self.read_f32("particle_velocities")?[..3 * n].to_vec(),
            modes: self.read_f32("particle_mode")?[..n]
                .iter()
                .map(|x| x.to_bits())
                .collect(),
            offsets: self.read_f32("particle_offset")?[..3 * n].to_vec(),
            timers: self.read_f32("particle_timer")?[..n].to_vec(),
        }))
    }

    fn stage_index(&self, stage: Stage) -> Result<usize> {
        self.stages
            .iter()
            .position(|s| s.pipelines.stage == stage && s.carries.is_none())
            .ok_or_else(|| {
                PalpateError::Gpu(format!("stage '{}' is not in this step plan", stage.name()))
            })
    }

    /// Record `steps` steps of the plan into `encoder` (one compute pass), counting stage runs.
    /// Under design 8 with the tool ([`exact_activates_on_cpu`]) each activation step ends the
    /// pass after the stages before `ActivateExact`: what is recorded is submitted and waited
    /// for, the CPU twin activates ([`Self::activate_on_cpu`]), and the rest goes into a new
    /// encoder that replaces `encoder`.
    fn record_batch(&mut self, encoder: &mut wgpu::CommandEncoder, steps: u32) -> Result<()> {
        let first = self.steps_done;
        if let Some(at) = self.exact_twin.as_ref().map(|t| t.at) {
            let mut from = (0, 0);
            for s in 0..steps {
                if self.plan.stages[at].runs_at(first + s as u64, s, steps) {
                    self.record_range(encoder, (first, steps), from, (s, at))?;
                    let done = std::mem::replace(
                        encoder,
                        self.ctx.device.create_command_encoder(&Default::default()),
                    );
                    self.ctx.queue.submit([done.finish()]);
                    self.activate_on_cpu(first + s as u64)?;
                    from = (s, at + 1);
                }
            }
            self.record_range(encoder, (first, steps), from, (steps, 0))?;
        } else {
            self.record_range(encoder, (first, steps), (0, 0), (steps, 0))?;
        }
        self.count_batch(first, steps);
        Ok(())
    }

    /// The runs of each plan stage in the `steps`-step batch that starts after `first` steps.
    fn stage_runs(&self, first: u64, steps: u32) -> Vec<u32> {
        self.plan
            .stages
            .iter()
            .map(|p| {
                (0..steps)
                    .filter(|&s| p.runs_at(first + s as u64, s, steps))
                    .count() as u32
            })
            .collect()
    }

    /// A batch of `steps` steps after `first` was recorded: its stage runs, and the steps
    /// done.
    fn count_batch(&mut self, first: u64, steps: u32) {
        let runs = self.stage_runs(first, steps);
        for (c, r) in self.counts.iter_mut().zip(runs) {
            c.1 = r;
        }
        self.steps_done = first + steps as u64;
    }

    fn batch_encoder(&self) -> wgpu::CommandEncoder {
        self.ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("batch"),
            })
    }

    /// Copy what a batch reports into ring slot `slot`.
    fn record_report_copies(&self, enc: &mut wgpu::CommandEncoder, slot: usize) -> Result<()> {
        for &(name, offset, size) in &self.report_layout {
            enc.copy_buffer_to_buffer(
                self.buffers.require(name)?,
                0,
                &self.ring[slot].buffer,
                offset,
                size,
            );
        }
        Ok(())
    }

    /// The next batch of `steps` steps, recorded now ([`Ahead`]; not under a CPU twin).
    fn record_ahead(&self, steps: u32) -> Result<Ahead> {
        let (first, slot) = (self.steps_done, self.next_slot);
        let mut enc = self.batch_encoder();
        self.record_range(&mut enc, (first, steps), (0, 0), (steps, 0))?;
        self.record_report_copies(&mut enc, slot)?;
        Ok(Ahead {
            first,
            steps,
            slot,
            fusion: self.fusion,
            commands: enc.finish(),
        })
    }

    /// Record, as one compute pass, the stages of the `steps`-step batch that starts after
    /// `first` steps, from (step, plan position) `from` up to but not including `to`; the CPU
    /// twin's `ActivateExact` is never recorded.
    fn record_range(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        (first, steps): (u64, u32),
        from: (u32, usize),
        to: (u32, usize),
    ) -> Result<()> {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("steps"),
            timestamp_writes: None,
        });
        let on_cpu = self.exact_twin.as_ref().map(|t| t.at);
        for s in from.0..steps.min(to.0 + 1) {
            for k in 0..self.plan.stages.len() {
                let here = (s, k);
                if here < from || here >= to || on_cpu == Some(k) {
                    continue;
                }
                if self.plan.stages[k].runs_at(first + s as u64, s, steps) {
                    if let Some(b) = self.recorded_at(k) {
                        self.record_stage_at(&mut pass, b)?;
                    }
                }
            }
        }
        Ok(())
    }

    /// Design 8 under the tool: the twin's stress and force sets come from its CPU-built
    /// neighbour lists and the GPU's kernels walk the GPU-built ones, so the two must be the
    /// same (they are built by the same rule; a GPU compiler that contracts the distance test
    /// differently could move a pair at the kernel radius). An error naming what differs.
    fn check_neighbour_lists(&mut self, twin: &crate::cpu::CpuStepper) -> Result<()> {
        let Some(l) = twin.neighbour_lists() else {
            return Ok(());
        };
        let bits = |v: &[f32]| -> Vec<u32> { bytemuck::cast_slice(v).to_vec() };
        let offsets = self.read_prefixes(&[("neighbour_offsets", l.neighbour_offsets.len())])?;
        let same = bits(&offsets) == l.neighbour_offsets
            && bits(&self.read_prefixes(&[("neighbours", l.neighbours.len())])?) == l.neighbours;
        if !same {
            return Err(PalpateError::Gpu(
                "particles.coupling = \"exact\" under the tool: this GPU built other particle neighbour lists than the CPU (a pair at particles.kernel_radius); run it with --backend cpu, or move kernel_radius off a lattice shell".into(),
            ));
        }
        Ok(())
    }

    /// The first `len` floats of each named buffer (u32 buffers as their bits), one after the
    /// other, copied in one submission into one staging buffer (kept for the next call) and
    /// read with one wait.
    fn read_prefixes(&mut self, which: &[(&str, usize)]) -> Result<Vec<f32>> {
        let bytes: u64 = which.iter().map(|&(_, len)| 4 * len as u64).sum();
        if self.staging.as_ref().is_none_or(|b| b.size() < bytes) {
            self.staging = Some(self.ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("activation readback"),
                size: bytes.max(4),
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }));
        }
        let Some(staging) = self.staging.as_ref() else {
            return Err(PalpateError::Internal("no staging buffer".into()));
        };
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        let mut at = 0;
        for &(name, len) in which {
            let size = 4 * len as u64;
            if size > 0 {
                enc.copy_buffer_to_buffer(self.buffers.require(name)?, 0, staging, at, size);
            }
            at += size;
        }
        self.ctx.queue.submit([enc.finish()]);
        let raw = self.ctx.read_mapped(staging, bytes.max(4))?;
        let mut all: Vec<f32> = bytemuck::pod_collect_to_vec(&raw);
        all.truncate(bytes as usize / 4);
        Ok(all)
    }

    /// Design 8's activation at step `step` (0-based, the tool already moved) on the CPU twin:
    /// read what the steps changed, activate, and write back what the activation wrote
    /// (`cpu/stepper/gpu_activation.rs`). The writes go ahead of the next submission.
    fn activate_on_cpu(&mut self, step: u64) -> Result<()> {
        let (nv, n) = (self.n_vertices as usize, self.n_particles as usize);
        let tool_len = std::mem::size_of::<ToolState>() / 4;
        let clock = std::time::Instant::now();
        self.ctx.wait()?;
        let drained = clock.elapsed().as_secs_f64();
        let all = self.read_prefixes(&[
            ("displacements", 3 * nv),
            ("velocities", 3 * nv),
            ("particle_displacements", 3 * n),
            ("particle_velocities", 3 * n),
            ("particle_mode", n),
            ("particle_timer", n),
            ("particle_offset", 3 * n),
            ("exact_vertex_timer", nv),
            ("tool_state", tool_len),
        ])?;
        let mut rest = &all[..];
        let mut next = |len: usize| {
            let (head, tail) = rest.split_at(len.min(rest.len()));
            rest = tail;
            head
        };
        let (u, v) = (next(3 * nv), next(3 * nv));
        let (pu, pv) = (next(3 * n), next(3 * n));
        let mode: &[u32] = bytemuck::cast_slice(next(n));
        let (timer, offset) = (next(n), next(3 * n));
        let vertex_timer = next(nv);
        let tool = next(tool_len);
        if tool.len() != tool_len {
            return Err(PalpateError::Internal("the tool state was not read".into()));
        }
        let tool_state: ToolState = bytemuck::pod_read_unaligned(bytemuck::cast_slice(tool));
        let input = crate::cpu::stepper::ExactActivationInput {
            displacements: u,
            velocities: v,
            particle_displacements: pu,
            particle_velocities: pv,
            particle_mode: mode,
            particle_timer: timer,
            particle_offset: offset,
            tool_state,
            vertex_timer,
            steps_done: step,
        };
        let twin = self
            .exact_twin
            .as_mut()
            .ok_or_else(|| PalpateError::Internal("no CPU twin to activate on".into()))?;
        let read = clock.elapsed().as_secs_f64();
        let out = twin
            .stepper
            .activate_exact_for_gpu(&input)?
            .ok_or_else(|| PalpateError::Internal("the CPU twin has no design 8".into()))?;
        let activated = clock.elapsed().as_secs_f64();
        let (queue, buffers) = (&self.ctx.queue, &self.buffers);
        // Writes `words` (f32 or u32 as bits) at word `at` of buffer `name`.
        let write_at = |name: &str, at: usize, words: &[u32]| -> Result<()> {
            let buf = buffers.require(name)?;
            let end = 4 * (at + words.len()) as u64;
            if end > buf.size() {
                return Err(PalpateError::Internal(format!(
                    "{end} bytes from the CPU twin's activation do not fit buffer '{name}'"
                )));
            }
            if !words.is_empty() {
                queue.write_buffer(buf, 4 * at as u64, bytemuck::cast_slice(words));
            }
            Ok(())
        };
        let write = |name: &str, words: &[u32]| write_at(name, 0, words);
        // Only the span where the activation changed what was read (bitwise): an activation
        // that keeps its sets moves the modes and clocks of a few particles.
        let write_changed = |name: &str, new: &[u32], old: &[u32]| -> Result<()> {
            if new.len() != old.len() {
                return write(name, new);
            }
            let differ = |(a, b): (&u32, &u32)| a != b;
            match new.iter().zip(old).position(differ) {
                None => Ok(()),
                Some(first) => {
                    let last = new.iter().zip(old).rposition(differ).unwrap_or(first);
                    write_at(name, first, &new[first..=last])
                }
            }
        };
        fn bits(a: &[f32]) -> &[u32] {
            bytemuck::cast_slice(a)
        }
        write_changed("displacements", bits(out.displacements), bits(u))?;
        write_changed("velocities", bits(out.velocities), bits(v))?;
        write_changed(
            "particle_displacements",
            bits(out.particle_displacements),
            bits(pu),
        )?;
        write_changed(
            "particle_velocities",
            bits(out.particle_velocities),
            bits(pv),
        )?;
        write_changed("particle_mode", out.particle_mode, mode)?;
        write_changed("particle_timer", bits(out.particle_timer), bits(timer))?;
        write_changed("particle_offset", bits(out.particle_offset), bits(offset))?;
        if out.changed {
            write("mass", bits(out.mass))?;
            write("inv_mass", bits(out.inv_mass))?;
            write("dynamic_list", out.dynamic_list)?;
            write("stress_list", out.stress_list)?;
            write("force_list", out.force_list)?;
            write("particle_counts", &out.counts)?;
            write("particle_dispatch", &out.dispatch)?;
            write("tet_weight", bits(out.tet_weight))?;
            write("contact_weight", bits(out.contact_weight))?;
            write("exact_vertex_offset", bits(out.vertex_offset))?;
            write("exact_vertex_timer", bits(out.vertex_timer))?;
            // The particles that left S lose their tangent forces, in runs of consecutive
            // indices.
            let mut left = out.left_stress.to_vec();
            left.sort_unstable();
            let mut k = 0;
            while k < left.len() {
                let mut end = k + 1;
                while end < left.len() && left[end] == left[end - 1] + 1 {
                    end += 1;
                }
                let run = 12 * (end - k);
                write_at("exact_tangent", 12 * left[k] as usize, &twin.zeros[..run])?;
                k = end;
            }
            write("exact_delta", &twin.zeros[..3 * n])?;
            let t = crate::gpu::groups::ExactTables::of(&twin.model, out.slaving)
                .ok_or_else(|| PalpateError::Internal("design 8 without particles".into()))?;
            write("exact_mass", bits(&t.mass))?;
            write("exact_inv_mass", bits(&t.inv_mass))?;
            write("exact_fit_offsets", &t.fit_offsets)?;
            write("exact_fit_particles", &t.fit_particles)?;
            write("exact_fit_weights", bits(&t.fit_weights))?;
            write("exact_slave_offsets", &t.slave_offsets)?;
            write("exact_slave_vertices", &t.slave_vertices)?;
            write("exact_slave_weights", bits(&t.slave_weights))?;
        }
        let trip = RoundTrip {
            drain: drained,
            read: read - drained,
            activate: activated - read,
            write: clock.elapsed().as_secs_f64() - activated,
            changed: out.changed,
        };
        if twin.round_trips.len() == ROUND_TRIPS_KEPT {
            twin.round_trips.pop_front();
        }
        twin.round_trips.push_back(trip);
        self.ctx.check_errors()
    }

    /// Design 8 under the tool: the round trips to the CPU twin since the last call (the last
    /// 4,096 at most, oldest first), which it forgets; None when this stepper's activations
    /// run on the GPU.
    pub fn take_exact_round_trips(&mut self) -> Option<Vec<RoundTrip>> {
        self.exact_twin
            .as_mut()
            .map(|t| t.round_trips.drain(..).collect())
    }

    /// Run a single stage on the current buffers and wait (tests, bisecting a mismatch).
    /// Design 8's activation under the tool runs on the CPU twin only, within a batch: an
    /// error here.
    pub fn run_stage(&self, stage: Stage) -> Result<()> {
        if self
            .exact_twin
            .as_ref()
            .is_some_and(|t| self.plan.stages[t.at].stage == stage)
        {
            return Err(PalpateError::Usage(format!(
                "stage '{}' runs on the CPU twin within a batch (design 8 under the tool); it has no GPU pass to run alone",
                stage.name()
            )));
        }
        let k = self.stage_index(stage)?;
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            self.record_stage_at(&mut pass, k)?;
        }
        self.ctx.queue.submit([enc.finish()]);
        self.ctx.wait()
    }

    /// Time each stage of the plan with timestamp queries over `reps` runs (one compute pass
    /// per stage as a batch records them: a fused dispatch is one, timed under its host);
    /// None when the device has no timestamp queries.
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
        // What a batch records, each once, in plan order.
        let mut units: Vec<usize> = Vec::new();
        let on_cpu = self.exact_twin.as_ref().map(|t| t.at);
        for k in (0..self.plan.stages.len()).filter(|&k| Some(k) != on_cpu) {
            if let Some(b) = self.recorded_at(k).filter(|b| !units.contains(b)) {
                units.push(b);
            }
        }
        let n_stages = units.len() as u32;
        let count = 2 * n_stages * reps;
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
        for r in 0..reps {
            for k in 0..n_stages {
                let q = 2 * (n_stages * r + k);
                let unit = units[k as usize];
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some(&self.stages[unit].label),
                    timestamp_writes: Some(wgpu::ComputePassTimestampWrites {
                        query_set: &queries,
                        beginning_of_pass_write_index: Some(q),
                        end_of_pass_write_index: Some(q + 1),
                    }),
                });
                self.record_stage_at(&mut pass, unit)?;
            }
        }
        enc.resolve_query_set(&queries, 0..count, &resolve, 0);
        enc.copy_buffer_to_buffer(&resolve, 0, &staging, 0, bytes);
        self.ctx.queue.submit([enc.finish()]);
        let raw = self.ctx.read_mapped(&staging, bytes)?;
        let ticks: &[u64] = bytemuck::cast_slice(&raw);
        let period = self.ctx.queue.get_timestamp_period() as f64;
        let per_stage = (0..n_stages as usize)
            .map(|k| {
                let total: f64 = (0..reps as usize)
                    .map(|r| {
                        let q = 2 * (n_stages as usize * r + k);
                        ticks[q + 1].saturating_sub(ticks[q]) as f64 * period
                    })
                    .sum();
                (self.stages[units[k]].pipelines.stage, total / reps as f64)
            })
            .collect();
        let carried = units
            .iter()
            .filter_map(|&u| {
                let b = &self.stages[u];
                b.carries.map(|rider| (rider, b.pipelines.stage))
            })
            .collect();
        Ok(Some(StageTimes { per_stage, carried }))
    }

    /// Overwrite any buffer from its start with f32 (or raw u32 bits) data (tests, debugging).
    pub fn write_f32(&self, which: &str, data: &[f32]) -> Result<()> {
        let buf = self.buffers.require(which)?;
        if (data.len() * 4) as u64 > buf.size() {
            return Err(PalpateError::Gpu(format!(
                "{} floats do not fit buffer '{which}'",
                data.len()
            )));
        }
        self.ctx
            .queue
            .write_buffer(buf, 0, bytemuck::cast_slice(data));
        if which != "activation_gate" {
            self.raise_activation_gate()?;
        }
        self.ctx.wait()
    }

    /// Read any buffer as f32 (u32 buffers such as `status` read as bits).
    pub fn read_f32(&self, which: &str) -> Result<Vec<f32>> {
        let buf = self.buffers.require(which)?;
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

    /// The particles' per-run uniform as last written to the GPU (None without particles).
    pub fn particle_params(&self) -> Option<crate::particles::params::ParticleParams> {
        self.model_particles.as_ref().map(|t| t.params)
    }

    /// Run `steps` steps without any readback (benchmarks); waits for completion.
    pub fn run_no_readback(&mut self, steps: u32) -> Result<()> {
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        self.record_batch(&mut enc, steps)?;
        self.ctx.queue.submit([enc.finish()]);
        self.ctx.wait()
    }

    /// Parse a mapped ring slot into a report.
    fn parse_report(&self, bytes: &[u8], steps: u32, tool_to: glam::DVec3) -> BatchReport {
        let mut report = BatchReport {
            steps,
            ..Default::default()
        };
        let mut counts = [0u32; 4];
        let mut pstats = [0f32; 8];
        for &(name, offset, size) in &self.report_layout {
            let data = &bytes[offset as usize..(offset + size) as usize];
            match name {
                "stats" => {
                    let floats: &[f32] = bytemuck::cast_slice(&data[..STATS_BYTES as usize]);
                    report.stats.stats.copy_from_slice(&floats[..stat::LEN]);
                }
                "status" => {
                    let words: &[u32] = bytemuck::cast_slice(&data[..STATUS_BYTES as usize]);
                    report.stats.non_finite_vertex = (words[0] != u32::MAX).then_some(words[0]);
                }
                "tool_report" => {
                    let floats: &[f32] = bytemuck::cast_slice(data);
                    report.tool = Some(crate::stepper::ToolReport::from_floats(tool_to, floats));
                }
                "particle_counts" => counts.copy_from_slice(&bytemuck::cast_slice(data)[..4]),
                "particle_stats" => pstats.copy_from_slice(&bytemuck::cast_slice(data)[..8]),
                _ => {}
            }
        }
        if self.n_particles > 0 {
            report.particles = Some(crate::stepper::ParticleReport::from_parts(&counts, &pstats));
        }
        report
    }

    /// Take the front batch's report if its slot is mapped.
    fn take_front(&mut self) -> Result<Option<BatchReport>> {
        let Some(front) = self.in_flight.front() else {
            return Ok(None);
        };
        let slot = &self.ring[front.slot];
        match slot.mapped.load(Ordering::Acquire) {
            SLOT_PENDING => Ok(None),
            SLOT_FAILED => {
                // The slot is free again (a failed mapping leaves it unmapped): a later batch
                // that takes it must not read this failure as its own.
                slot.mapped.store(SLOT_PENDING, Ordering::Release);
                self.in_flight.pop_front();
                Err(PalpateError::Gpu("mapping a readback slot failed".into()))
            }
            _ => {
                let (steps, tool_to) = (front.steps, front.tool_to);
                let data = {
                    let view = slot
                        .buffer
                        .slice(..)
                        .get_mapped_range()
                        .map_err(|e| PalpateError::Gpu(format!("mapped range: {e}")))?;
                    view.to_vec()
                };
                slot.buffer.unmap();
                slot.mapped.store(SLOT_PENDING, Ordering::Release);
                self.in_flight.pop_front();
                Ok(Some(self.parse_report(&data, steps, tool_to)))
            }
        }
    }

    /// Wait for all work, dropping the reports of batches in flight.
    fn drain(&mut self) -> Result<()> {
        while !self.in_flight.is_empty() {
            self.wait()?;
        }
        self.ctx.wait()
    }

    /// What a checkpoint saves: the state buffers and, with particles, what the last
    /// activation left for the steps until the next one ([`ACTIVATION_PRODUCTS`]).
    fn checkpointed_buffers(&self) -> Result<Vec<(&'static str, &wgpu::Buffer)>> {
        let mut all: Vec<_> = self.buffers.with_usage(Usage::State).collect();
        if self.n_particles > 0 {
            for name in ACTIVATION_PRODUCTS {
                all.push((name, self.buffers.require(name)?));
            }
        }
        Ok(all)
    }
}

impl Stepper for GpuStepper {
    fn name(&self) -> String {
        self.ctx.describe()
    }

    fn set_params(&mut self, params: &StepParams) -> Result<()> {
        if let Some(t) = &mut self.exact_twin {
            t.stepper.set_params(params)?;
        }
        self.params = *params;
        self.ctx.queue.write_buffer(
            self.buffers.require("params")?,
            0,
            bytemuck::bytes_of(params),
        );
        if let Some(t) = &mut self.model_particles {
            // Keep the plan's sub-step count; the sub-step and interval follow dt.
            t.params = t.params.at_core_dt(params.dt, t.activation_interval);
            self.ctx.queue.write_buffer(
                self.buffers.require("particle_params")?,
                0,
                bytemuck::bytes_of(&t.params),
            );
        }
        Ok(())
    }

    fn set_particle_substeps(&mut self, substeps: u32) -> Result<()> {
        let substeps = substeps.clamp(1, crate::model::MAX_PARTICLE_SUBSTEPS);
        let Some(t) = &mut self.model_particles else {
            return Ok(());
        };
        if self.exact_twin.is_some() || t.params.substeps == substeps {
            return Ok(());
        }
        let plan = self.plan.with_particle_substeps(substeps);
        if plan == self.plan {
            return Ok(());
        }
        let (plan_stage, fused_stage) = map_plan(&plan, &self.stages)?;
        t.params.substeps = substeps;
        t.params = t.params.at_core_dt(self.params.dt, t.activation_interval);
        // Ordered after the batches already submitted, before the next.
        self.ctx.queue.write_buffer(
            self.buffers.require("particle_params")?,
            0,
            bytemuck::bytes_of(&t.params),
        );
        self.counts = plan.stages.iter().map(|p| (p.stage, 0)).collect();
        self.plan = plan;
        self.plan_stage = plan_stage;
        self.fused_stage = fused_stage;
        // Recorded with the old plan.
        self.ahead = None;
        Ok(())
    }

    fn set_load_factor(&mut self, load_factor: f32) -> Result<()> {
        if let Some(f) = &mut self.follower_load {
            if f.load_factor != load_factor {
                f.load_factor = load_factor;
                self.ctx.queue.write_buffer(
                    self.buffers.require("follower_load")?,
                    0,
                    bytemuck::bytes_of(f),
                );
            }
        }
        Ok(())
    }

    fn submit(&mut self, steps: u32, input: &BatchInput) -> Result<()> {
        if self.in_flight.len() >= RING {
            return Err(PalpateError::Gpu(format!(
                "{RING} batches are already in flight; poll or wait first"
            )));
        }
        let q = &self.ctx.queue;
        q.write_buffer(
            self.buffers.require("status")?,
            0,
            bytemuck::cast_slice(&[u32::MAX; 4]),
        );
        let (tool_input, state, to) = input.tool_plan(steps, self.tool_at);
        if self.has_tool {
            q.write_buffer(
                self.buffers.require("tool_input")?,
                0,
                bytemuck::bytes_of(&tool_input),
            );
            q.write_buffer(
                self.buffers.require("tool_state")?,
                0,
                bytemuck::bytes_of(&state),
            );
        }
        self.tool_at = to;
        let slot = self.next_slot;
        let (first, fusion) = (self.steps_done, self.fusion);
        let ahead = self
            .ahead
            .take()
            .filter(|a| (a.first, a.steps, a.slot, a.fusion) == (first, steps, slot, fusion));
        let commands = match ahead {
            Some(a) => {
                self.count_batch(first, steps);
                self.ahead_used += 1;
                a.commands
            }
            None => {
                let mut enc = self.batch_encoder();
                self.record_batch(&mut enc, steps)?;
                self.record_report_copies(&mut enc, slot)?;
                enc.finish()
            }
        };
        self.next_slot = (self.next_slot + 1) % RING;
        self.ctx.queue.submit([commands]);
        let flag = self.ring[slot].mapped.clone();
        self.ring[slot]
            .buffer
            .slice(..)
            .map_async(wgpu::MapMode::Read, move |r| {
                flag.store(
                    if r.is_ok() { SLOT_MAPPED } else { SLOT_FAILED },
                    Ordering::Release,
                );
            });
        self.in_flight.push_back(InFlight {
            slot,
            steps,
            tool_to: to,
        });
        // The caller will wait for this batch before the next (nothing else in flight):
        // record the next one, of as many steps, while the GPU runs this. Not under design 8
        // with the tool, whose batches stop at each activation for the CPU twin.
        // A failure here leaves the next batch to be recorded at its submission (where the
        // same failure, if it is one, is reported).
        if self.prerecord && self.exact_twin.is_none() && self.in_flight.len() == 1 {
            self.ahead = self.record_ahead(steps).ok();
        }
        self.ctx.check_errors()
    }

    fn poll(&mut self) -> Result<Option<BatchReport>> {
        if self.in_flight.is_empty() {
            return Ok(None);
        }
        self.ctx
            .device
            .poll(wgpu::PollType::Poll)
            .map_err(|e| PalpateError::Gpu(format!("poll: {e}")))?;
        self.ctx.check_errors()?;
        self.take_front()
    }

    fn wait(&mut self) -> Result<BatchReport> {
        if self.in_flight.is_empty() {
            return Err(PalpateError::Gpu("wait: no batch in flight".into()));
        }
        loop {
            self.ctx.wait()?;
            if let Some(r) = self.take_front()? {
                return Ok(r);
            }
        }
    }

    fn in_flight(&self) -> usize {
        self.in_flight.len()
    }

    fn checkpoint(&mut self) -> Result<()> {
        if self.checkpoint.is_empty() {
            let d = &self.ctx.device;
            let scope = d.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
            let saved = self.checkpointed_buffers()?;
            let bytes: u64 = saved.iter().map(|(_, b)| b.size()).sum();
            self.checkpoint = saved
                .into_iter()
                .map(|(name, b)| {
                    (
                        name,
                        d.create_buffer(&wgpu::BufferDescriptor {
                            label: Some(&format!("checkpoint {name}")),
                            size: b.size(),
                            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
                            mapped_at_creation: false,
                        }),
                    )
                })
                .collect();
            if let Some(e) = pollster::block_on(scope.pop()) {
                self.checkpoint.clear();
                return Err(PalpateError::Gpu(format!(
                    "out of GPU memory creating the {bytes}-byte checkpoint of the state on '{}': {e}",
                    self.ctx.info.name
                )));
            }
            self.ctx.check_errors()?;
        }
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        for (name, saved) in &self.checkpoint {
            let b = self.buffers.require(name)?;
            enc.copy_buffer_to_buffer(b, 0, saved, 0, b.size());
        }
        self.ctx.queue.submit([enc.finish()]);
        self.checkpoint_steps = (self.steps_done, self.tool_at);
        if let Some(t) = &mut self.exact_twin {
            t.stepper.checkpoint()?;
        }
        self.ctx.check_errors()
    }

    fn restore(&mut self) -> Result<()> {
        self.drain()?;
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        for (name, saved) in &self.checkpoint {
            let b = self.buffers.require(name)?;
            enc.copy_buffer_to_buffer(saved, 0, b, 0, b.size());
        }
        enc.clear_buffer(self.buffers.require("stats")?, 0, None);
        if let Some(t) = &mut self.exact_twin {
            // As the CPU backend's restore: design 8's per-step arrays start from zero, which
            // is what they hold where a step reads them before writing them.
            t.stepper.restore()?;
            for name in ["exact_delta", "exact_host_force", "exact_tangent"] {
                enc.clear_buffer(self.buffers.require(name)?, 0, None);
            }
        }
        self.ctx.queue.submit([enc.finish()]);
        (self.steps_done, self.tool_at) = self.checkpoint_steps;
        self.raise_activation_gate()?;
        self.ctx.wait()
    }

    fn read_state(&mut self) -> Result<State> {
        self.drain()?;
        let bytes = 12 * self.n_vertices as u64;
        if self.readback_state.is_none() {
            self.readback_state = Some(self.ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("readback state"),
                size: (2 * bytes).max(4),
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }));
        }
        let staging = self.readback_state.as_ref().expect("created above");
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(self.buffers.require("displacements")?, 0, staging, 0, bytes);
        enc.copy_buffer_to_buffer(
            self.buffers.require("velocities")?,
            0,
            staging,
            bytes,
            bytes,
        );
        self.ctx.queue.submit([enc.finish()]);
        let data = self.ctx.read_mapped(staging, 2 * bytes)?;
        let all: &[f32] = bytemuck::cast_slice(&data);
        let k = 3 * self.n_vertices as usize;
        Ok(State {
            displacements: all[..k].to_vec(),
            velocities: all[k..].to_vec(),
        })
    }

    fn write_state(&mut self, state: &State) -> Result<()> {
        // (the particle modes stay, so gather_coupled's short lists stay valid)
        self.drain()?;
        if let Some(t) = &mut self.exact_twin {
            // (the twin's next activation is then a full one, as the CPU backend's)
            t.stepper.write_state(state)?;
        }
        let q = &self.ctx.queue;
        q.write_buffer(
            self.buffers.require("displacements")?,
            0,
            bytemuck::cast_slice(&state.displacements),
        );
        q.write_buffer(
            self.buffers.require("velocities")?,
            0,
            bytemuck::cast_slice(&state.velocities),
        );
        q.write_buffer(
            self.buffers.require("stats")?,
            0,
            bytemuck::cast_slice(&[0f32; stat::LEN]),
        );
        self.raise_activation_gate()?;
        self.ctx.wait()
    }

    fn stage_counts(&self) -> Vec<(Stage, u32)> {
        self.counts.clone()
    }

    fn read_particle_state(&mut self) -> Result<Option<crate::stepper::ParticleSnapshot>> {
        self.read_particles()
    }
}
