//! The CPU backend: executes the step plan with the kernels' twins, on a pool of `threads`
//! worker threads. Every twin writes only per-index outputs, so the result is bit-identical
//! for any thread count; the reductions sum in the GPU's fixed tree order.

use super::activate::{
    mark_set, relump_vertex, ModeArrays, ModeInputs, ParticleStatic, RelumpInputs, VertexLump,
};
use super::active_region::ActiveRegion;
use super::gather::Coupling;
use super::{
    contact, fem_forces, gather, integrate, reduce_final, reduce_partial, tool_force_final,
    tool_force_partial, tool_motion,
};
use crate::contact::{ToolInput, ToolParams, ToolState, REPORT_LEN};
use crate::cpu::fem_forces::FemVariant;
use crate::cpu::integrate::ALL_FINITE;
use crate::cpu::neighbours::NeighbourLists;
use crate::cpu::reduce::{n_partials, PARTIAL_LEN};
use crate::error::{PalpateError, Result};
use crate::model::Model;
use crate::params::{stat, StepParams};
use crate::particles::params::{mode, ParticleParams};
use crate::plan::{Stage, StepPlan};
use crate::stepper::{
    BatchInput, BatchReport, BatchStats, ParticleReport, ParticleSnapshot, State, Stepper,
    ToolReport, RING,
};
use std::collections::VecDeque;
use std::sync::Arc;

/// Most threads `--threads` accepts, as a multiple of the machine's cores.
pub const MAX_THREADS_PER_CORE: usize = 4;

/// The cores this process may use (1 when unknown).
pub fn available_cores() -> usize {
    std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1)
}

/// A pool of `threads` worker threads, or a one-line error when the count is 0, above
/// [`MAX_THREADS_PER_CORE`] × the cores, or the threads cannot be started.
pub fn thread_pool(threads: usize) -> Result<Arc<rayon::ThreadPool>> {
    let cores = available_cores();
    if threads == 0 {
        return Err(PalpateError::Usage("--threads must be at least 1".into()));
    }
    if threads > MAX_THREADS_PER_CORE * cores {
        return Err(PalpateError::Usage(format!(
            "--threads {threads} is more than {MAX_THREADS_PER_CORE} x the {cores} cores this machine has"
        )));
    }
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .thread_name(|i| format!("palpate-cpu-{i}"))
        .start_handler(|_| super::par::flush_denormals_on_this_thread())
        .build()
        .map(Arc::new)
        .map_err(|e| PalpateError::Usage(format!("cannot start {threads} threads: {e}")))
}

thread_local! {
    /// This thread's [`this_thread_pool`], once built.
    static THIS_THREAD_POOL: std::cell::RefCell<Option<Arc<rayon::ThreadPool>>> =
        const { std::cell::RefCell::new(None) };
}

/// The calling thread as a pool of one thread (no worker beside it), the same pool for every
/// call on this thread; None when the thread already works for another pool or the pool
/// cannot be built. Work installed on it from this thread runs right here. From another
/// thread nothing would take it, so a [`CpuStepper`] stepped elsewhere moves to a worker of
/// its own. Rayon work this thread starts outside any pool afterwards also runs on it alone
/// (rayon keeps the thread as the pool's, and leaks the pool). Denormals are flushed on it, as
/// on every worker: for all its f32 and f64 arithmetic from then on.
pub fn this_thread_pool() -> Option<Arc<rayon::ThreadPool>> {
    THIS_THREAD_POOL.with(|here| {
        if let Some(pool) = here.borrow().as_ref() {
            return Some(pool.clone());
        }
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .use_current_thread()
            .build()
            .ok()?;
        super::par::flush_denormals_on_this_thread();
        let pool = Arc::new(pool);
        *here.borrow_mut() = Some(pool.clone());
        Some(pool)
    })
}

/// The tool's arrays (empty without a tool).
struct ToolArrays {
    params: ToolParams,
    input: ToolInput,
    state: ToolState,
    at: glam::DVec3,
    contact_forces: Vec<f32>,
    partials: Vec<f32>,
    report: Vec<f32>,
}

/// The mode machine's inputs from the stepper's tool and vertex state.
fn mode_inputs<'a>(
    m: &Model,
    pp: &'a ParticleParams,
    st: &'a ParticleStatic<'a>,
    tool: &'a ToolArrays,
    state: &'a State,
) -> ModeInputs<'a> {
    ModeInputs::new(
        pp,
        &tool.params,
        &tool.state,
        m.tool.is_some(),
        st,
        &state.displacements,
        &state.velocities,
    )
}

/// The particles' state (checkpointed with the vertices').
struct ParticleState {
    displacements: Vec<f32>,
    velocities: Vec<f32>,
    mode: Vec<u32>,
    timer: Vec<f32>,
    offset: Vec<f32>,
    mass: Vec<f32>,
    inv_mass: Vec<f32>,
}

impl ParticleState {
    /// The arrays the mode machine writes.
    fn mode_arrays(&mut self) -> ModeArrays<'_> {
        ModeArrays {
            displacements: &mut self.displacements,
            velocities: &mut self.velocities,
            mode: &mut self.mode,
            timer: &mut self.timer,
            offset: &mut self.offset,
        }
    }
}

impl Clone for ParticleState {
    fn clone(&self) -> Self {
        let mut c = ParticleState {
            displacements: Vec::new(),
            velocities: Vec::new(),
            mode: Vec::new(),
            timer: Vec::new(),
            offset: Vec::new(),
            mass: Vec::new(),
            inv_mass: Vec::new(),
        };
        c.clone_from(self);
        c
    }

    /// Copies into the existing buffers (a checkpoint every batch allocates nothing).
    fn clone_from(&mut self, s: &Self) {
        self.displacements.clone_from(&s.displacements);
        self.velocities.clone_from(&s.velocities);
        self.mode.clone_from(&s.mode);
        self.timer.clone_from(&s.timer);
        self.offset.clone_from(&s.offset);
        self.mass.clone_from(&s.mass);
        self.inv_mass.clone_from(&s.inv_mass);
    }
}

/// What an activation leaves for the steps until the next one: its lists, counts, indirect
/// arguments, tet weights, vertex flags and contact weights, the weighted tets and the coupled
/// vertices' slots. Saved with a checkpoint, so that a restore resumes with the ones its
/// modes were built with (the modes change only at an activation).
#[derive(Default, PartialEq)]
struct ActivationProducts {
    dynamic_list: Vec<u32>,
    stress_list: Vec<u32>,
    force_list: Vec<u32>,
    counts: [u32; 4],
    dispatch: [u32; 9],
    tet_weight: Vec<f32>,
    node_flags: Vec<u32>,
    contact_weight: Vec<f32>,
    /// Tets whose energy weight is not 1, ascending (the rest keep their whole energy); every
    /// tet on the reference path.
    weighted_tets: Vec<u32>,
    /// Per coupled vertex, the slots `gather_coupled` adds (valid until the state is replaced).
    coupled_slots: super::gather::CoupledSlots,
    /// The force-carrying pairs of the stress and force lists, each once (tlsph).
    pair_plan: super::sph_pairs::PairPlan,
}

impl ActivationProducts {
    /// Before the first activation: empty lists, no work, every weight 1, no flags.
    fn at_rest(n_tets: usize, n_vertices: usize) -> ActivationProducts {
        ActivationProducts {
            dispatch: [0, 1, 1, 0, 1, 1, 0, 1, 1],
            tet_weight: vec![1.0; n_tets],
            node_flags: vec![0; n_vertices],
            contact_weight: vec![1.0; n_vertices],
            ..Default::default()
        }
    }
}

impl Clone for ActivationProducts {
    fn clone(&self) -> Self {
        let mut c = ActivationProducts::default();
        c.clone_from(self);
        c
    }

    /// Copies into the existing buffers (a checkpoint every batch allocates nothing).
    fn clone_from(&mut self, s: &Self) {
        self.dynamic_list.clone_from(&s.dynamic_list);
        self.stress_list.clone_from(&s.stress_list);
        self.force_list.clone_from(&s.force_list);
        self.counts = s.counts;
        self.dispatch = s.dispatch;
        self.tet_weight.clone_from(&s.tet_weight);
        self.node_flags.clone_from(&s.node_flags);
        self.contact_weight.clone_from(&s.contact_weight);
        self.weighted_tets.clone_from(&s.weighted_tets);
        self.coupled_slots.clone_from(&s.coupled_slots);
        self.pair_plan.clone_from(&s.pair_plan);
    }
}

/// What the particle chain (the stages [`is_chain_stage`] names) reads besides the particle
/// arrays. The chain writes only those arrays (not the activation's products) and the
/// status, so it can run beside the core's element forces.
struct ChainInputs<'a> {
    model: &'a Model,
    params: &'a StepParams,
    material: crate::material::MaterialModel,
    tool: &'a ToolArrays,
    vertex_displacements: &'a [f32],
    /// The vertices' velocities (a viscous material's particle stress reads them through
    /// `follow`).
    vertex_velocities: &'a [f32],
}

/// The particle stages that read the vertices only through their displacements (and
/// velocities, for a viscous material's `follow`) and write
/// nothing but particle arrays and the status: everything after the activation.
fn is_chain_stage(stage: Stage) -> bool {
    matches!(
        stage,
        Stage::Follow
            | Stage::SphStress
            | Stage::SphForces
            | Stage::SphForcesAccumulate
            | Stage::IntegrateParticles
            | Stage::ParticleReduce
            | Stage::ExactStress
            | Stage::ExactForces
    )
}

/// Design 8's chain stages (`ExactStress`, `ExactForces`: see [`is_chain_stage`]), which
/// write only particle arrays and design 8's per-step arrays; other stages do nothing here.
fn run_exact_chain_stage(
    stage: Stage,
    c: &ChainInputs,
    pa: &mut ParticleArrays,
    x: &mut super::exact_stages::ExactArrays,
) {
    use super::exact_stages as ex;
    let (m, p) = (c.model, c.params);
    let Some(pd) = m.particles.as_ref() else {
        return;
    };
    let pp = pa.params;
    match stage {
        Stage::ExactStress => {
            ex::embedded_offsets(
                m,
                pd,
                &x.delta_list,
                c.vertex_displacements,
                &pa.state.displacements,
                &mut x.delta,
            );
            ex::exact_stress(
                &ex::StressInputs {
                    model: m,
                    pd,
                    pp: &pp,
                    material: (c.material, p.lambda, p.mu),
                    lists: (&pa.lists.neighbour_offsets, &pa.lists.neighbours),
                    pairs: &pa.pairs,
                    correction: &pa.correction,
                    delta: &x.delta,
                    vertex_u: c.vertex_displacements,
                },
                &pa.act.stress_list,
                &mut pa.stress,
                &mut pa.gradient,
                &mut pa.energy,
                &mut x.tangent,
            );
        }
        Stage::ExactForces => {
            let t = c.tool;
            let inp = super::sph_forces::ForceInputs {
                params: p,
                pp: &pp,
                tool: m.tool.as_ref().map(|_| (&t.params, &t.input, &t.state)),
                mode: &pa.state.mode,
                rest: &pd.rest,
                displacements: &pa.state.displacements,
                velocities: &pa.state.velocities,
                neighbour_offsets: &pa.lists.neighbour_offsets,
                neighbours: &pa.lists.neighbours,
                stress: &pa.stress,
                gradient: &pa.gradient,
                area: &pd.contact_area,
                contact_offset: &pd.contact_offset,
                pairs: Some(&pa.pairs),
            };
            // Each pair once where the activation could list them (tlsph; the
            // per-particle gather is the kernel's twin and the reference).
            if pa.act.pair_plan.valid && pp.model == 0 {
                pa.act.pair_plan.exact_forces(
                    &inp,
                    (&pa.act.stress_list, &pa.act.force_list, &pa.pairs),
                    &mut pa.exact_pair_scratch,
                    &mut pa.forces,
                    &mut pa.contact,
                    &mut x.host_force,
                );
            } else {
                ex::exact_forces(
                    &inp,
                    &pa.act.force_list,
                    &mut pa.forces,
                    &mut pa.contact,
                    &mut x.host_force,
                );
            }
        }
        _ => {}
    }
}

/// The twin of a chain stage (see [`is_chain_stage`]; other stages do nothing here).
fn run_chain_stage(stage: Stage, c: &ChainInputs, pa: &mut ParticleArrays, status: &mut [u32]) {
    let (m, p) = (c.model, c.params);
    let (Some(pd), Some(st)) = (m.particles.as_ref(), ParticleStatic::of(m)) else {
        return;
    };
    let pp = pa.params;
    let (noff, nbrs) = (&pa.lists.neighbour_offsets, &pa.lists.neighbours);
    // A viscous material's particle stress reads velocities (`follow` gives the embedded
    // particles their host's), as the kernels' VISCOUS constant does.
    let viscous = m.fem_variant().viscous;
    match stage {
        Stage::Follow => super::follow::follow(
            &pp,
            &pa.act.force_list,
            &pa.state.mode,
            &st,
            c.vertex_displacements,
            &mut pa.state.timer,
            &pa.state.offset,
            &mut pa.state.displacements,
            viscous.then_some((c.vertex_velocities, &mut pa.state.velocities[..])),
        ),
        Stage::SphStress => super::sph_stress::sph_stress(
            p,
            &pp,
            c.material,
            &pa.act.stress_list,
            &pd.rest,
            &pa.state.displacements,
            viscous.then_some(&pa.state.velocities[..]),
            noff,
            nbrs,
            &pa.correction,
            Some(&pa.pairs),
            &mut pa.stress,
            &mut pa.gradient,
            &mut pa.energy,
        ),
        Stage::SphForces | Stage::SphForcesAccumulate => {
            let tool = m
                .tool
                .as_ref()
                .map(|_| (&c.tool.params, &c.tool.input, &c.tool.state));
            let inp = super::sph_forces::ForceInputs {
                params: p,
                pp: &pp,
                tool,
                mode: &pa.state.mode,
                rest: &pd.rest,
                displacements: &pa.state.displacements,
                velocities: &pa.state.velocities,
                neighbour_offsets: noff,
                neighbours: nbrs,
                stress: &pa.stress,
                gradient: &pa.gradient,
                area: &pd.contact_area,
                contact_offset: &pd.contact_offset,
                pairs: Some(&pa.pairs),
            };
            let accumulate = stage == Stage::SphForcesAccumulate;
            if pa.act.pair_plan.valid {
                pa.act.pair_plan.sph_forces(
                    &inp,
                    &pa.act.stress_list,
                    &pa.act.force_list,
                    accumulate,
                    &mut pa.pair_scratch,
                    &mut pa.forces,
                    &mut pa.force_sum,
                    &mut pa.contact,
                );
            } else {
                super::sph_forces::sph_forces(
                    &inp,
                    &pa.act.force_list,
                    accumulate,
                    &mut pa.forces,
                    &mut pa.force_sum,
                    &mut pa.contact,
                );
            }
        }
        Stage::IntegrateParticles => super::integrate_particles::integrate_particles(
            p,
            &pp,
            &pa.act.dynamic_list,
            &pa.forces,
            &mut pa.state.displacements,
            &mut pa.state.velocities,
            status,
        ),
        Stage::ParticleReduce => super::particle_reduce::particle_reduce(
            &pp,
            &pa.act.stress_list,
            &pa.state.mode,
            &pa.state.displacements,
            &pa.state.velocities,
            &pa.forces,
            &pa.energy,
            &pa.gradient,
            &mut pa.partials,
            &mut pa.stats,
        ),
        _ => {}
    }
}

/// The follower pressures' vertex forces added to the model's dead loads in
/// `external_forces` (nothing without a follower load).
fn follower_pressure_forces(
    m: &Model,
    p: &StepParams,
    state: &State,
    c: &mut CardiacArrays,
    external_forces: &mut [f32],
) {
    let Some(f) = &m.follower else {
        return;
    };
    super::follower_pressure::follower_pressure(
        &c.follower_load,
        &m.rest,
        &state.displacements,
        &f.faces,
        &f.face_pressure,
        &mut c.follower_corner_forces,
    );
    super::follower_pressure_gather::follower_pressure_gather(
        p,
        &c.follower_corner_forces,
        &f.incidence_offsets,
        &f.incidence,
        &m.external_forces,
        external_forces,
    );
}

/// The core's element forces and energies (`fem_forces`, every tet at full weight).
fn core_element_forces(
    m: &Model,
    p: &StepParams,
    state: &State,
    corner_forces: &mut [f32],
    tet_energy: &mut [f32],
    variant: FemVariant,
) {
    fem_forces(
        p,
        &state.displacements,
        &state.velocities,
        &m.tets,
        &m.dm_inv,
        &m.rest_volume,
        corner_forces,
        tet_energy,
        variant,
    );
}

/// The PARTICLES variant of `fem_forces`: each tet keeps 1 − φₑ of its energy and forces
/// (only the weighted tets: × 1 changes nothing), in parallel over every tet when most are
/// weighted.
fn weigh_element_forces(
    m: &Model,
    particles: Option<&ParticleArrays>,
    corner_forces: &mut [f32],
    tet_energy: &mut [f32],
) {
    let Some(pa) = particles else {
        return;
    };
    if 4 * pa.act.weighted_tets.len() > m.n_tets() {
        super::par::for_each_chunk2::<12, 1>(
            corner_forces,
            tet_energy,
            m.n_tets(),
            |e, corner, energy| {
                let w = pa.act.tet_weight[e];
                corner.iter_mut().for_each(|c| *c *= w);
                energy[0] *= w;
            },
        );
    } else {
        for &e in &pa.act.weighted_tets {
            let (e, w) = (e as usize, pa.act.tet_weight[e as usize]);
            corner_forces[12 * e..12 * e + 12]
                .iter_mut()
                .for_each(|c| *c *= w);
            tet_energy[e] *= w;
        }
    }
}

/// Where the plan runs particle chain stages (see [`is_chain_stage`]) every step before the
/// core's `FemForces`, with at most a `FollowerPressure` between them: the indices of both
/// (`FemForces` at `end`). The chain reads the vertices' displacements; `FollowerPressure`
/// writes only its corner forces and the external forces, and `FemForces` only the element
/// forces and energies, so the chain can run beside the other two (the tets' energy weights,
/// which the chain does not touch, are applied after both).
fn chain_before_core_forces(plan: &StepPlan) -> Option<std::ops::Range<usize>> {
    use crate::plan::When;
    let every = |k: usize| plan.stages[k].when == When::EveryStep;
    let end = plan
        .stages
        .iter()
        .position(|s| s.stage == Stage::FemForces)
        .filter(|&e| every(e))?;
    let pressure = (end > 0
        && plan.stages[end - 1].stage == Stage::FollowerPressure
        && every(end - 1)) as usize;
    let start = (0..end - pressure)
        .rev()
        .take_while(|&k| is_chain_stage(plan.stages[k].stage) && every(k))
        .last()?;
    Some(start..end)
}

/// What the relump reads, from the model and the particle arrays.
fn relump_inputs<'a>(
    m: &'a Model,
    pd: &'a crate::particles::Particles,
    pa: &'a ParticleArrays,
) -> RelumpInputs<'a> {
    RelumpInputs {
        pp: &pa.params,
        slot_offsets: &pd.slot_offsets,
        slots: &pd.slots,
        weights: &pd.weights,
        particle_mode: &pa.state.mode,
        particle_velocities: &pa.state.velocities,
        particle_rest: &pd.rest,
        rest: &m.rest,
        core_mass: &pd.core_mass,
        node_fixed: &pa.node_fixed,
        incidence_offsets: &m.incidence_offsets,
        incidence: &m.incidence,
        tet_weight: &pa.act.tet_weight,
    }
}

/// How the CPU stepper's activations ran (see `cpu/active_region.rs`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ActivationCounts {
    /// Over every particle, tet and vertex (the first, after a restore, on the reference
    /// path, or without a deciding tool).
    pub full: u64,
    /// Over the region the tool can change, with some set changed.
    pub region: u64,
    /// Over the region, with no set changed: only the mode machine and the massless
    /// vertices' velocities ran.
    pub unchanged: u64,
}

/// A new version number for an [`ActivationProducts`], unique in the process.
fn next_act_version() -> u64 {
    use std::sync::atomic::{AtomicU64, Ordering};
    static NEXT: AtomicU64 = AtomicU64::new(1);
    NEXT.fetch_add(1, Ordering::Relaxed)
}

/// Copy what a checkpoint or restore carries of the particle state from `src` into `dst`:
/// the particles in `touched`'s blocks (those of the others are equal already) and the
/// vertex masses whole.
fn copy_particle_state(
    touched: &super::touched::Touched,
    src: &ParticleState,
    dst: &mut ParticleState,
) {
    if touched.all() || dst.displacements.len() != src.displacements.len() {
        dst.clone_from(src);
        return;
    }
    use super::touched::copy_ranges;
    let ranges = touched.ranges();
    copy_ranges(&ranges, 3, &src.displacements, &mut dst.displacements);
    copy_ranges(&ranges, 3, &src.velocities, &mut dst.velocities);
    copy_ranges(&ranges, 3, &src.offset, &mut dst.offset);
    copy_ranges(&ranges, 1, &src.mode, &mut dst.mode);
    copy_ranges(&ranges, 1, &src.timer, &mut dst.timer);
    dst.mass.clone_from(&src.mass);
    dst.inv_mass.clone_from(&src.inv_mass);
}

/// A saved state: the vertices', the particles' with their activation's products, the step
/// count (which steps activate) and where the tool is.
struct Checkpoint {
    state: State,
    /// The particle state, the activation's products and their version
    /// ([`ParticleArrays::act_version`]).
    particles: Option<(ParticleState, ActivationProducts, u64)>,
    /// Design 8's slaving and offsets (they change with each activation under the tool).
    exact: Option<super::exact_stages::ExactArrays>,
    steps_done: u64,
    tool_at: glam::DVec3,
}

/// The particles' arrays.
struct ParticleArrays {
    params: ParticleParams,
    lists: NeighbourLists,
    pairs: super::sph::PairTable,
    correction: Vec<f32>,
    state: ParticleState,
    stress: Vec<f32>,
    gradient: Vec<f32>,
    energy: Vec<f32>,
    forces: Vec<f32>,
    force_sum: Vec<f32>,
    contact: Vec<f32>,
    /// What the last activation left (checkpointed).
    act: ActivationProducts,
    /// Changes whenever `act` does ([`next_act_version`]): a checkpoint or restore whose
    /// copy has the same version skips copying it.
    act_version: u64,
    /// The blocks of particles whose state (displacement, velocity, offset, mode, blend
    /// clock) may have changed since the last checkpoint (see `CpuStepper::checkpoint`).
    touched: super::touched::Touched,
    node_fixed: Vec<u32>,
    partials: Vec<f32>,
    stats: Vec<f32>,
    /// What the next activation must visit (see `cpu/active_region.rs`).
    region: ActiveRegion,
    /// Run every activation over all particles, tets and vertices (tests compare the two).
    full_activation: bool,
    /// How the activations ran.
    activations: ActivationCounts,
    /// Per neighbour slot, the same pair's slot in the neighbour's list.
    transpose: Vec<u32>,
    /// Scratch of the pair plan's build.
    plan_scratch: super::sph_pairs::PlanScratch,
    /// Scratch of the paired force stage.
    pair_scratch: super::sph_pairs::PairScratch,
    /// Scratch of design 8's paired force stage.
    exact_pair_scratch: super::sph_pairs::PairScratch<super::sph_pairs::Split>,
}

impl ParticleArrays {
    /// The particle state was replaced: the next activation is a full pass, and until then
    /// `gather_coupled` walks every slot.
    fn forget_region(&mut self) {
        self.region.forget();
        self.act.coupled_slots.valid = false;
        self.act_version = next_act_version();
    }

    /// After an activation: the weighted tets among `reweighed` (every tet whose weight may
    /// differ from 1) and the coupled vertices' slots. With `full_activation` (the reference
    /// the tests compare against) every tet is weighted and `gather_coupled` walks every slot.
    fn after_activation(
        &mut self,
        reweighed: impl Iterator<Item = u32>,
        pd: &crate::particles::Particles,
    ) {
        self.act_version = next_act_version();
        if self.full_activation {
            self.act.weighted_tets = (0..self.act.tet_weight.len() as u32).collect();
            self.act.coupled_slots.valid = false;
            return;
        }
        let w = &self.act.tet_weight;
        self.act.weighted_tets = reweighed.filter(|&e| w[e as usize] != 1.0).collect();
        self.act.coupled_slots.rebuild(
            &self.act.node_flags,
            &pd.slot_offsets,
            &pd.slots,
            &self.state.mode,
        );
    }

    /// Mark the stress set S (the particles whose mode has a bit of `moving`, and their
    /// neighbours) and the force set F (S and its neighbours) among the first `n` particles,
    /// then compact the dynamic, stress and force lists and their dispatch arguments.
    fn mark_sets_and_compact(&mut self, n: usize, moving: u32) {
        self.act_version = next_act_version();
        let (noff, nbrs) = (&self.lists.neighbour_offsets, &self.lists.neighbours);
        mark_set(n, moving, mode::IN_S, noff, nbrs, &mut self.state.mode);
        mark_set(n, mode::IN_S, mode::IN_F, noff, nbrs, &mut self.state.mode);
        super::compact::compact(
            &self.state.mode,
            &mut self.act.dynamic_list,
            &mut self.act.stress_list,
            &mut self.act.force_list,
            &mut self.act.counts,
            &mut self.act.dispatch,
        );
    }

    /// After an activation has set the lists: list the force-carrying pairs once (tlsph;
    /// the paper model's one-sided eq. 13 is not antisymmetric and keeps the twin's gather).
    fn rebuild_pair_plan(&mut self) {
        self.act_version = next_act_version();
        if self.params.model != 0 {
            self.act.pair_plan.valid = false;
            return;
        }
        self.act.pair_plan.rebuild(
            &self.act.stress_list,
            &self.act.force_list,
            &self.state.mode,
            (
                &self.lists.neighbour_offsets,
                &self.lists.neighbours,
                &self.transpose,
            ),
            &mut self.plan_scratch,
        );
    }
}

impl ParticleArrays {
    fn new(model: &Model, params: &StepParams) -> Option<ParticleArrays> {
        let p = model.particles.as_ref()?;
        let pp = model.particle_params(params)?;
        let n = p.len();
        let (lists, correction) = super::sph_setup::lists_and_corrections(&pp, &p.rest, p.support);
        let modes = p.initial_modes();
        let pairs =
            super::sph::PairTable::new(&pp, &p.rest, &lists.neighbour_offsets, &lists.neighbours);
        let transpose =
            super::sph_pairs::transpose_slots(&lists.neighbour_offsets, &lists.neighbours);
        let node_fixed: Vec<u32> = model.inv_mass.iter().map(|&w| (w == 0.0) as u32).collect();
        let region = ActiveRegion::new(p, &node_fixed);
        Some(ParticleArrays {
            params: pp,
            lists,
            pairs,
            correction,
            state: ParticleState {
                displacements: vec![0.0; 3 * n],
                velocities: vec![0.0; 3 * n],
                mode: modes,
                timer: vec![0.0; n],
                offset: vec![0.0; 3 * n],
                mass: model.mass.clone(),
                inv_mass: model.inv_mass.clone(),
            },
            stress: vec![0.0; 9 * n],
            gradient: vec![0.0; 9 * n],
            energy: vec![0.0; n],
            forces: vec![0.0; 3 * n],
            force_sum: vec![0.0; 3 * n],
            contact: vec![0.0; 3 * n],
            act: ActivationProducts::at_rest(model.n_tets(), model.n_vertices()),
            act_version: next_act_version(),
            touched: super::touched::Touched::new(n),
            node_fixed,
            partials: vec![
                0.0;
                super::particle_reduce::LANE * super::particle_reduce::n_partials(&pp)
            ],
            stats: vec![0.0; 8],
            region,
            full_activation: false,
            activations: ActivationCounts::default(),
            transpose,
            plan_scratch: Default::default(),
            pair_scratch: Default::default(),
            exact_pair_scratch: Default::default(),
        })
    }
}

/// The cardiac stages' arrays (empty when the plan does not use them).
struct CardiacArrays {
    split: Option<super::fem_forces_split::SplitVariant>,
    material: crate::material::MaterialConstants,
    tet_delta_volume: Vec<f32>,
    vertex_pressure: Vec<f32>,
    vertex_volumetric_energy: Vec<f32>,
    follower_load: super::follower_pressure::FollowerLoad,
    follower_corner_forces: Vec<f32>,
}

impl CardiacArrays {
    fn new(model: &Model) -> CardiacArrays {
        let split = model.split_variant();
        let nodal = split.is_some_and(|v| v.nodal_pressure);
        let n_faces = model.follower.as_ref().map_or(0, |f| f.n_faces());
        CardiacArrays {
            split,
            material: model.material_constants(),
            tet_delta_volume: vec![0.0; if nodal { model.n_tets() } else { 0 }],
            vertex_pressure: vec![0.0; if nodal { model.n_vertices() } else { 0 }],
            vertex_volumetric_energy: vec![0.0; if nodal { model.n_vertices() } else { 0 }],
            follower_load: super::follower_pressure::FollowerLoad {
                n_faces: n_faces as u32,
                load_factor: model.follower.as_ref().map_or(0.0, |f| f.load_factor(0.0)),
                _pad0: 0,
                _pad1: 0,
            },
            follower_corner_forces: vec![0.0; 9 * n_faces],
        }
    }
}

/// CPU stepper: the reference path, parallel over tets and vertices.
pub struct CpuStepper {
    model: Arc<Model>,
    plan: StepPlan,
    /// The plan's particle chain that runs beside `FemForces` (see
    /// [`chain_before_core_forces`]; on more than one thread).
    chain: Option<std::ops::Range<usize>>,
    params: StepParams,
    variant: FemVariant,
    pool: Arc<rayon::ThreadPool>,
    /// The thread `pool` is made of, when it is a [`this_thread_pool`].
    pool_thread: Option<std::thread::ThreadId>,
    threads: usize,
    state: State,
    /// The last checkpoint; the state at rest until the first `checkpoint`.
    checkpoint: Checkpoint,
    corner_forces: Vec<f32>,
    tet_energy: Vec<f32>,
    forces: Vec<f32>,
    /// The external forces `gather` and `reduce` read: the model's dead loads, plus the
    /// follower pressures when the plan has them (rewritten every step).
    external_forces: Vec<f32>,
    cardiac: CardiacArrays,
    partials: Vec<f32>,
    stats: Vec<f32>,
    status: Vec<u32>,
    tool: ToolArrays,
    particles: Option<ParticleArrays>,
    /// Design 8's arrays (`particles.coupling = "exact"`; None for the energy blend).
    exact: Option<super::exact_stages::ExactArrays>,
    steps_done: u64,
    reports: VecDeque<BatchReport>,
    counts: Vec<(Stage, u32)>,
}

impl CpuStepper {
    /// A stepper at rest on all cores.
    pub fn new(model: Arc<Model>, params: StepParams) -> CpuStepper {
        let threads = available_cores();
        let pool = thread_pool(threads)
            .or_else(|_| thread_pool(1))
            .expect("a single worker thread can always start");
        CpuStepper::with_pool(model, params, pool, threads)
    }

    /// A stepper at rest on `threads` threads (see [`thread_pool`] for the errors).
    pub fn with_threads(model: Arc<Model>, params: StepParams, threads: usize) -> Result<Self> {
        Ok(CpuStepper::with_pool(
            model,
            params,
            thread_pool(threads)?,
            threads,
        ))
    }

    /// A stepper at rest on one thread, the calling one ([`this_thread_pool`]): its stages
    /// run on the thread that steps it, with no pool worker beside it (a haptic session's
    /// physics thread then leaves the other core to the servo). Stepped from another thread
    /// it moves to a worker of its own. A pool of one worker when this thread cannot be one.
    pub fn on_this_thread(model: Arc<Model>, params: StepParams) -> Result<Self> {
        match this_thread_pool() {
            Some(pool) => {
                let mut s = CpuStepper::with_pool(model, params, pool, 1);
                s.pool_thread = Some(std::thread::current().id());
                Ok(s)
            }
            None => CpuStepper::with_threads(model, params, 1),
        }
    }

    /// The thread this stepper's pool is made of, when it steps on the thread that made it
    /// ([`Self::on_this_thread`]) and has not moved off it.
    pub fn steps_on(&self) -> Option<std::thread::ThreadId> {
        self.pool_thread
    }

    /// The pool to run on from the calling thread: a [`this_thread_pool`] of another thread
    /// is swapped for a pool of one worker (its own thread would never take the work); the
    /// error of [`thread_pool`] when that worker cannot start.
    fn pool_here(&mut self) -> Result<Arc<rayon::ThreadPool>> {
        if let Some(home) = self.pool_thread {
            if home != std::thread::current().id() {
                self.pool = thread_pool(1)?;
                self.pool_thread = None;
            }
        }
        Ok(self.pool.clone())
    }

    /// Run `f` on [`Self::pool_here`] (for the helpers that return no `Result`: tests,
    /// profiling); on the calling thread when no worker can start (the results do not
    /// depend on the threads they run on).
    fn on_pool_here<R: Send>(&mut self, f: impl FnOnce(&mut Self) -> R + Send) -> R {
        match self.pool_here() {
            Ok(pool) => pool.install(|| f(self)),
            Err(_) => f(self),
        }
    }

    fn with_pool(
        model: Arc<Model>,
        params: StepParams,
        pool: Arc<rayon::ThreadPool>,
        threads: usize,
    ) -> Self {
        let state = State {
            displacements: vec![0.0; model.rest.len()],
            velocities: vec![0.0; model.rest.len()],
        };
        let plan = StepPlan::for_model_at(&model, model.particle_substeps(params.dt as f64));
        let tool_params = model.tool_params();
        let tool = ToolArrays {
            params: tool_params,
            input: ToolInput::default(),
            state: ToolState::default(),
            at: model
                .tool
                .as_ref()
                .map_or(glam::DVec3::ZERO, |t| t.tool.position_at(0.0)),
            contact_forces: vec![0.0; 3 * tool_params.n_surface as usize],
            partials: vec![
                0.0;
                crate::cpu::tool_force::LANE
                    * crate::cpu::tool_force::n_partials(&tool_params)
            ],
            report: vec![0.0; REPORT_LEN],
        };
        let particles = pool.install(|| ParticleArrays::new(&model, &params));
        let checkpoint = Checkpoint {
            exact: None,
            state: state.clone(),
            particles: particles
                .as_ref()
                .map(|pa| (pa.state.clone(), pa.act.clone(), pa.act_version)),
            steps_done: 0,
            tool_at: tool.at,
        };
        let exact = super::exact_stages::ExactArrays::new(&model);
        let checkpoint = Checkpoint {
            exact: exact.clone(),
            ..checkpoint
        };
        CpuStepper {
            tool,
            particles,
            counts: plan.stages.iter().map(|p| (p.stage, 0)).collect(),
            chain: chain_before_core_forces(&plan),
            exact,
            plan,
            variant: model.fem_variant(),
            corner_forces: vec![0.0; 12 * model.n_tets()],
            tet_energy: vec![0.0; model.n_tets()],
            forces: vec![0.0; 3 * model.n_vertices()],
            external_forces: model.external_forces.clone(),
            cardiac: CardiacArrays::new(&model),
            partials: vec![0.0; PARTIAL_LEN * n_partials(&params)],
            stats: vec![0.0; stat::LEN],
            status: vec![ALL_FINITE; 4],
            checkpoint,
            state,
            model,
            params,
            pool,
            pool_thread: None,
            threads,
            steps_done: 0,
            reports: VecDeque::new(),
        }
    }

    /// Worker threads.
    pub fn threads(&self) -> usize {
        self.threads
    }

    /// The core time step, s.
    pub fn dt(&self) -> f32 {
        self.params.dt
    }

    /// The step plan this stepper executes.
    pub fn plan(&self) -> &StepPlan {
        &self.plan
    }

    /// Run one stage's twin on the current arrays.
    pub fn run_stage(&mut self, stage: Stage) {
        let m = &*self.model;
        let p = &self.params;
        let t = &mut self.tool;
        let surface = m.tool.as_ref();
        let (surface_vertices, surface_area, surface_index): (&[u32], &[f32], &[u32]) =
            match surface {
                Some(s) => (&s.surface_vertices, &s.surface_area, &s.surface_index),
                None => (&[], &[], &[]),
            };
        let has_tool = surface.is_some();
        // Vertex masses: the model's, or the particles' re-lumped ones.
        let (mass, inv_mass): (&[f32], &[f32]) = match &self.particles {
            Some(pa) => (&pa.state.mass, &pa.state.inv_mass),
            None => (&m.mass, &m.inv_mass),
        };
        let pdata = m.particles.as_ref();
        match stage {
            Stage::ToolMotion => tool_motion(&t.input, &mut t.state),
            Stage::Contact => contact(
                p,
                &t.params,
                &t.input,
                &t.state,
                surface_vertices,
                surface_area,
                &m.rest,
                &self.state.displacements,
                &self.state.velocities,
                &mut t.contact_forces,
                self.particles
                    .as_ref()
                    .map(|pa| pa.act.contact_weight.as_slice()),
            ),
            Stage::ToolForce => {
                tool_force_partial(
                    p,
                    &t.params,
                    &t.input,
                    &t.state,
                    surface_vertices,
                    surface_area,
                    &m.rest,
                    &self.state.displacements,
                    &self.state.velocities,
                    &mut t.partials,
                    self.particles
                        .as_ref()
                        .map(|pa| pa.act.contact_weight.as_slice()),
                );
                if let (Some(pa), Some(pd)) = (&self.particles, pdata) {
                    super::tool_force::tool_force_particles(
                        p,
                        &t.params,
                        &t.input,
                        &t.state,
                        &pa.state.mode,
                        &pd.rest,
                        &pa.state.displacements,
                        &pa.state.velocities,
                        &pd.contact_area,
                        &pa.gradient,
                        &pd.contact_offset,
                        &pa.act.dynamic_list,
                        &mut t.partials,
                    );
                }
                let dynamic = self
                    .particles
                    .as_ref()
                    .map_or(0, |pa| pa.act.dynamic_list.len());
                tool_force_final(&t.params, dynamic, &t.partials, &mut t.report);
            }
            Stage::FemForces => {
                core_element_forces(
                    m,
                    p,
                    &self.state,
                    &mut self.corner_forces,
                    &mut self.tet_energy,
                    self.variant,
                );
                // Design 8: every tet keeps its full energy.
                weigh_element_forces(
                    m,
                    self.particles.as_ref().filter(|_| self.exact.is_none()),
                    &mut self.corner_forces,
                    &mut self.tet_energy,
                );
            }
            Stage::FollowerPressure => follower_pressure_forces(
                m,
                p,
                &self.state,
                &mut self.cardiac,
                &mut self.external_forces,
            ),
            Stage::NodalPressure => {
                let c = &mut self.cardiac;
                super::tet_volume_change::tet_volume_change(
                    p,
                    &self.state.displacements,
                    &m.tets,
                    &m.dm_inv,
                    &m.rest_volume,
                    &mut c.tet_delta_volume,
                );
                super::nodal_pressure::nodal_pressure(
                    p,
                    &c.material,
                    &m.incidence_offsets,
                    &m.incidence,
                    &m.rest_volume,
                    &c.tet_delta_volume,
                    &mut c.vertex_pressure,
                    &mut c.vertex_volumetric_energy,
                    c.split.map(|v| v.volumetric).unwrap_or_default(),
                );
            }
            Stage::FemForcesSplit => {
                let c = &self.cardiac;
                let Some(variant) = c.split else {
                    return;
                };
                super::fem_forces_split::fem_forces_split(
                    p,
                    &c.material,
                    &self.state.displacements,
                    &self.state.velocities,
                    &m.tets,
                    &m.dm_inv,
                    &m.rest_volume,
                    &m.fibres,
                    &c.vertex_pressure,
                    &c.vertex_volumetric_energy,
                    &mut self.corner_forces,
                    &mut self.tet_energy,
                    variant,
                );
            }
            Stage::Gather => gather(
                p,
                &self.corner_forces,
                &m.incidence_offsets,
                &m.incidence,
                mass,
                &self.external_forces,
                &mut self.forces,
            ),
            Stage::GatherCoupled => {
                type CouplingSlices<'a> = (
                    &'a [u32],
                    &'a [u32],
                    &'a [u32],
                    &'a [f32],
                    &'a [u32],
                    &'a [f32],
                );
                let empty: CouplingSlices = (&[], &[], &[], &[], &[], &[]);
                let (node_flags, slot_offsets, slots, weights, pmode, force_sum) =
                    match (&self.particles, pdata) {
                        (Some(pa), Some(pd)) if pa.act.coupled_slots.valid => (
                            pa.act.node_flags.as_slice(),
                            pa.act.coupled_slots.offsets.as_slice(),
                            pa.act.coupled_slots.slots.as_slice(),
                            pd.weights.as_slice(),
                            pa.state.mode.as_slice(),
                            pa.force_sum.as_slice(),
                        ),
                        (Some(pa), Some(pd)) => (
                            pa.act.node_flags.as_slice(),
                            pd.slot_offsets.as_slice(),
                            pd.slots.as_slice(),
                            pd.weights.as_slice(),
                            pa.state.mode.as_slice(),
                            pa.force_sum.as_slice(),
                        ),
                        _ => empty,
                    };
                super::gather::gather_coupled(
                    p,
                    &self.corner_forces,
                    &m.incidence_offsets,
                    &m.incidence,
                    mass,
                    &self.external_forces,
                    &mut self.forces,
                    &Coupling {
                        surface_index,
                        contact_forces: &t.contact_forces,
                        contact: has_tool,
                        node_flags,
                        slot_offsets,
                        slots,
                        weights,
                        mode: pmode,
                        force_sum,
                        particles: self.particles.is_some(),
                    },
                );
            }
            Stage::Integrate => integrate(
                p,
                &self.forces,
                inv_mass,
                &mut self.state.displacements,
                &mut self.state.velocities,
                &mut self.status,
            ),
            Stage::Reduce => {
                reduce_partial(
                    p,
                    &self.state.displacements,
                    &self.state.velocities,
                    mass,
                    inv_mass,
                    &self.forces,
                    &self.external_forces,
                    &self.tet_energy,
                    &mut self.partials,
                    surface_index,
                    &t.contact_forces,
                    has_tool,
                );
                reduce_final(p, &self.partials, &mut self.stats);
            }
            Stage::Activate
            | Stage::Follow
            | Stage::SphStress
            | Stage::SphForces
            | Stage::SphForcesAccumulate
            | Stage::IntegrateParticles
            | Stage::ParticleReduce => self.run_particle_stage(stage),
            Stage::ActivateExact
            | Stage::ExactStress
            | Stage::ExactForces
            | Stage::ExactGather
            | Stage::ExactIntegrate => self.run_exact_stage(stage),
        }
    }

    /// Design 8's stages (`particles.coupling = "exact"`, see `cpu/exact_stages.rs`); the
    /// others do nothing here, as does any of them on a model without the exact coupling.
    fn run_exact_stage(&mut self, stage: Stage) {
        use super::exact_stages as ex;
        if stage == Stage::ActivateExact {
            self.activate_exact();
            return;
        }
        let m = &*self.model;
        let p = &self.params;
        let (Some(pa), Some(pd), Some(x)) = (
            self.particles.as_mut(),
            m.particles.as_ref(),
            self.exact.as_mut(),
        ) else {
            return;
        };
        let pp = pa.params;
        match stage {
            Stage::ExactStress | Stage::ExactForces => run_exact_chain_stage(
                stage,
                &ChainInputs {
                    model: m,
                    params: p,
                    material: self.variant.model,
                    tool: &self.tool,
                    vertex_displacements: &self.state.displacements,
                    vertex_velocities: &self.state.velocities,
                },
                pa,
                x,
            ),
            Stage::ExactGather => {
                let surface_index = m.tool.as_ref().map_or(&[][..], |s| &s.surface_index);
                ex::exact_gather(
                    p,
                    &self.corner_forces,
                    (&m.incidence_offsets, &m.incidence),
                    &pa.state.mass,
                    &self.external_forces,
                    &ex::ExactGather {
                        surface_index,
                        contact_forces: &self.tool.contact_forces,
                        slots: (&x.gather_slots.0, &x.gather_slots.1),
                        weights: &pd.weights,
                        host_force: &x.host_force,
                        tangent: &x.tangent,
                    },
                    &mut self.forces,
                );
            }
            Stage::ExactIntegrate => {
                x.slaving.transfer_forces(&mut self.forces, &mut pa.forces);
                integrate(
                    p,
                    &self.forces,
                    &pa.state.inv_mass,
                    &mut self.state.displacements,
                    &mut self.state.velocities,
                    &mut self.status,
                );
                super::integrate_particles::integrate_particles(
                    p,
                    &pp,
                    &pa.act.dynamic_list,
                    &pa.forces,
                    &mut pa.state.displacements,
                    &mut pa.state.velocities,
                    &mut self.status,
                );
                x.offsets.advance(p.dt);
                super::exact_activation::place_slaved(
                    &x.slaving,
                    &x.offsets,
                    pp.blend,
                    (&mut self.state.displacements, &mut self.state.velocities),
                    (&pa.state.displacements, &pa.state.velocities),
                );
            }
            _ => {}
        }
    }

    /// An activation under design 8 (`cpu/exact_activation.rs`): the mode machine over every
    /// particle, then the closure, the slaving and the momentum-keeping re-lump
    /// ([`super::exact_activation::reslave`]); the vertex masses (slaved vertices carry none
    /// and are moved by their particles: inverse mass −1); the stress set marked from the
    /// dynamic particles and those blending back (their fading δ still strains their
    /// neighbours), the force set from it; the lists; and the blend's tet weights, which design
    /// 8 uses only for the vertices' contact weights (the dynamic particles take the tool's
    /// contact where they cover a vertex's tets). The tets keep full energy: `FemForces` does not
    /// weigh them. After one full pass the mode machine visits the region the tool can change
    /// (`cpu/active_region.rs`). An activation whose mode machine asks for the same dynamic
    /// set as the last one, and leaves the same particles dynamic and blending, keeps the
    /// slaving, masses, lists, weights and slots (`activation_counts().unchanged`; `region`
    /// counts the others after the first).
    fn activate_exact(&mut self) {
        let m = &*self.model;
        let p = &self.params;
        let (Some(pa), Some(pd), Some(x)) = (
            self.particles.as_mut(),
            m.particles.as_ref(),
            self.exact.as_mut(),
        ) else {
            return;
        };
        let Some(st) = ParticleStatic::of(m) else {
            return;
        };
        let pp = pa.params;
        let n = pd.len();
        pa.touched.mark_all();
        // The mode machine over the region the tool can change (the blend's, see
        // cpu/active_region.rs), or over everything.
        let over_region = {
            let inp = mode_inputs(m, &pp, &st, &self.tool, &self.state);
            let region = pa.region.primed() && !pa.full_activation && inp.tool_active;
            if region {
                let candidates = pa.region.candidates(&inp, &pd.tet_offsets);
                ActiveRegion::update(&inp, &candidates, pa.state.mode_arrays());
            } else {
                super::activate::activate(&inp, pa.state.mode_arrays());
            }
            region
        };
        if pa.full_activation {
            // The reference path: every activation re-slaves and rebuilds everything.
            x.asked.clear();
            x.moving.clear();
        }
        let reslaved = super::exact_activation::reslave(
            m,
            pd,
            &pp,
            (&x.slaving, &mut x.asked),
            super::exact_activation::ExactParticleState {
                mode: &mut pa.state.mode,
                displacements: &mut pa.state.displacements,
                velocities: &mut pa.state.velocities,
                timer: &mut pa.state.timer,
                offset: &mut pa.state.offset,
            },
            &mut self.state.displacements,
            &mut self.state.velocities,
            &mut x.offsets,
        );
        let same_slaving = match reslaved {
            Ok((slaving, counts)) => {
                x.counts.add(counts);
                slaving.map(|s| x.slaving = s).is_none()
            }
            // The model checked the whole zone dynamic and at rest; keep the last slaving
            // and stop the run at the end of the batch with this message.
            Err(e) => {
                x.failure = Some(e.to_string());
                false
            }
        };
        // The same slaving and the same dynamic and blending particles: the same sets, lists,
        // masses, weights and force-set slots as the last activation left. The mode machine
        // cleared the set bits; they go back on the same particles.
        let moving: Vec<u8> = pa
            .state
            .mode
            .iter()
            .map(|&q| (q & (mode::DYNAMIC | mode::BLENDING)) as u8)
            .collect();
        if same_slaving && moving == x.moving {
            for &q in &pa.act.stress_list {
                pa.state.mode[q as usize] |= mode::IN_S;
            }
            for &q in &pa.act.force_list {
                pa.state.mode[q as usize] |= mode::IN_F;
            }
            pa.activations.unchanged += 1;
            let blending = &x.delta_list[pa.act.dynamic_list.len()..];
            pa.region.settle(&pa.act.force_list, blending);
            return;
        }
        if over_region {
            pa.activations.region += 1;
        } else {
            pa.activations.full += 1;
        }
        x.moving = moving;
        let sl = &x.slaving;
        for v in 0..sl.vertex_mass.len() {
            let mass = sl.vertex_mass[v];
            pa.state.mass[v] = mass;
            pa.state.inv_mass[v] = if pa.node_fixed[v] != 0 {
                0.0
            } else if sl.slaved[v] {
                -1.0
            } else {
                1.0 / mass
            };
        }
        let mut left = std::mem::take(&mut x.left_stress);
        left.clone_from(&pa.act.stress_list);
        pa.mark_sets_and_compact(n, mode::DYNAMIC | mode::BLENDING);
        x.delta.iter_mut().for_each(|d| *d = 0.0);
        // The gather adds every force-set slot's tangent force; only S's are written each
        // step, so only S's can be nonzero: a particle that has left S keeps none.
        left.retain(|&q| pa.state.mode[q as usize] & mode::IN_S == 0);
        for &q in &left {
            x.tangent[12 * q as usize..12 * q as usize + 12].fill(0.0);
        }
        x.left_stress = left;
        super::exact_stages::force_set_slots(
            m,
            pd,
            (&pa.act.force_list, &pa.state.mode),
            &mut x.gather_slots,
        );
        x.delta_list.clone_from(&pa.act.dynamic_list);
        x.delta_list.extend(
            pa.act
                .stress_list
                .iter()
                .filter(|&&q| pa.state.mode[q as usize] & mode::BLENDING != 0),
        );
        super::activate::tet_weights(p, &pd.tet_offsets, &pa.state.mode, &mut pa.act.tet_weight);
        for v in 0..m.n_vertices() {
            pa.act.contact_weight[v] = (m.incidence_offsets[v]..m.incidence_offsets[v + 1])
                .map(|k| pa.act.tet_weight[m.incidence[k as usize] as usize / 4])
                .fold(1.0f32, f32::min);
        }
        // The live particles for the next activation's region: the force set (which holds
        // every dynamic one) and the blending ones (all in S: the end of the δ list).
        let blending = &x.delta_list[pa.act.dynamic_list.len()..];
        pa.region.settle(&pa.act.force_list, blending);
        pa.after_activation(0..m.n_tets() as u32, pd);
        pa.rebuild_pair_plan();
    }

    /// The activation over every particle, tet and vertex, as the kernel runs it; then the
    /// active region is rebuilt from the modes.
    fn activate_everywhere(&mut self) {
        let m = &*self.model;
        let p = &self.params;
        let (Some(pa), Some(pd)) = (self.particles.as_mut(), m.particles.as_ref()) else {
            return;
        };
        let Some(st) = ParticleStatic::of(m) else {
            return;
        };
        let pp = pa.params;
        let n = pd.len();
        let inp = mode_inputs(m, &pp, &st, &self.tool, &self.state);
        pa.activations.full += 1;
        pa.touched.mark_all();
        super::activate::activate(&inp, pa.state.mode_arrays());
        pa.mark_sets_and_compact(n, mode::DYNAMIC);
        super::activate::tet_weights(p, &pd.tet_offsets, &pa.state.mode, &mut pa.act.tet_weight);
        // The relump writes four of the arrays its inputs sit beside: lend them out (no copy).
        let mut mass = std::mem::take(&mut pa.state.mass);
        let mut inv_mass = std::mem::take(&mut pa.state.inv_mass);
        let mut node_flags = std::mem::take(&mut pa.act.node_flags);
        let mut contact_weight = std::mem::take(&mut pa.act.contact_weight);
        super::activate::relump(
            p,
            &relump_inputs(m, pd, pa),
            &mut mass,
            &mut inv_mass,
            &mut self.state.velocities,
            &mut node_flags,
            &mut contact_weight,
        );
        pa.state.mass = mass;
        pa.state.inv_mass = inv_mass;
        pa.act.node_flags = node_flags;
        pa.act.contact_weight = contact_weight;
        pa.region.prime(
            &pa.state.mode,
            &pa.act.force_list,
            &pa.act.stress_list,
            &pd.host,
            &m.tets,
        );
        pa.after_activation(0..m.n_tets() as u32, pd);
        pa.rebuild_pair_plan();
    }

    /// What the last activation left besides the particle state: the tets' energy weights,
    /// the vertices' coupling flags and contact weights (None without particles).
    pub fn activation_outputs(&self) -> Option<(&[f32], &[u32], &[f32])> {
        self.particles.as_ref().map(|pa| {
            (
                &pa.act.tet_weight[..],
                &pa.act.node_flags[..],
                &pa.act.contact_weight[..],
            )
        })
    }

    /// How the activations so far ran (None without particles).
    pub fn activation_counts(&self) -> Option<ActivationCounts> {
        self.particles.as_ref().map(|pa| pa.activations)
    }

    /// The reference path (`true`): every activation runs over all particles, tets and
    /// vertices, every tet's forces are weighted and `gather_coupled` walks every slot. The
    /// default (`false`) does each only where it can change anything; the results are
    /// bit-equal. Takes effect at the next activation.
    pub fn set_full_activation(&mut self, full: bool) {
        if let Some(pa) = &mut self.particles {
            pa.full_activation = full;
        }
    }

    /// The particle stages' twins.
    fn run_particle_stage(&mut self, stage: Stage) {
        let m = &*self.model;
        let p = &self.params;
        let (Some(pa), Some(pd)) = (self.particles.as_mut(), m.particles.as_ref()) else {
            return;
        };
        let pp = pa.params;
        let Some(st) = ParticleStatic::of(m) else {
            return;
        };
        let (noff, nbrs) = (&pa.lists.neighbour_offsets, &pa.lists.neighbours);
        match stage {
            Stage::Activate => {
                let incremental = pa.region.primed() && !pa.full_activation;
                let inp = mode_inputs(m, &pp, &st, &self.tool, &self.state);
                if !(incremental && inp.tool_active) {
                    self.activate_everywhere();
                    return;
                }
                let candidates = pa.region.candidates(&inp, &pd.tet_offsets);
                pa.touched.mark(&candidates);
                let changed = ActiveRegion::update(&inp, &candidates, pa.state.mode_arrays());
                if !changed {
                    // No particle became dynamic, was released or finished blending: the
                    // lists, counts, tet weights, masses, flags, slot lists and pair plan of
                    // the last activation stand. The mode machine cleared the per-update set
                    // bits, which go back on the same particles; the vertices that move with
                    // their dynamic particles take those particles' velocity again.
                    for &q in &pa.act.stress_list {
                        pa.state.mode[q as usize] |= mode::IN_S;
                    }
                    for &q in &pa.act.force_list {
                        pa.state.mode[q as usize] |= mode::IN_F;
                    }
                    let inputs = relump_inputs(m, pd, pa);
                    for i in pa.region.kinematic_vertices(&pa.state.inv_mass) {
                        let i = i as usize;
                        let lump =
                            relump_vertex(&inputs, i, super::load3(&self.state.velocities, i));
                        super::store3(&mut self.state.velocities, i, lump.velocity);
                    }
                    pa.activations.unchanged += 1;
                    return;
                }
                pa.activations.region += 1;
                let with = |bit: u32, modes: &[u32]| -> Vec<u32> {
                    candidates
                        .iter()
                        .copied()
                        .filter(|&p| modes[p as usize] & bit != 0)
                        .collect()
                };
                let dynamic = with(mode::DYNAMIC, &pa.state.mode);
                let blending = with(mode::BLENDING, &pa.state.mode);
                let stress =
                    ActiveRegion::mark(&dynamic, mode::IN_S, noff, nbrs, &mut pa.state.mode);
                let force = ActiveRegion::mark(&stress, mode::IN_F, noff, nbrs, &mut pa.state.mode);
                super::compact::counts_and_dispatch(
                    [&dynamic, &stress, &force],
                    &mut pa.act.counts,
                    &mut pa.act.dispatch,
                );
                let reweighed = pa.region.tets_to_weigh(&stress, &pd.host);
                for &e in &reweighed {
                    pa.act.tet_weight[e as usize] =
                        super::activate::tet_weight_of(e as usize, &pd.tet_offsets, &pa.state.mode);
                }
                let mut coupled = force.clone();
                coupled.extend(
                    blending
                        .iter()
                        .filter(|&&p| pa.state.mode[p as usize] & mode::RELEASED != 0),
                );
                let vertices = pa.region.vertices_to_relump(&coupled, &pd.host, &m.tets);
                let inputs = relump_inputs(m, pd, pa);
                let lumps: Vec<VertexLump> = {
                    use rayon::prelude::*;
                    let v = &self.state.velocities;
                    vertices
                        .par_iter()
                        .with_min_len(64)
                        .map(|&i| relump_vertex(&inputs, i as usize, super::load3(v, i as usize)))
                        .collect()
                };
                for (&i, lump) in vertices.iter().zip(lumps) {
                    let i = i as usize;
                    pa.state.mass[i] = lump.mass;
                    pa.state.inv_mass[i] = lump.inv_mass;
                    super::store3(&mut self.state.velocities, i, lump.velocity);
                    pa.act.node_flags[i] = lump.flags;
                    pa.act.contact_weight[i] = lump.contact_weight;
                }
                pa.region.settle(&force, &blending);
                pa.after_activation(reweighed.into_iter(), pd);
                pa.act.dynamic_list = dynamic;
                pa.act.stress_list = stress;
                pa.act.force_list = force;
                pa.touched.mark(&pa.act.force_list);
                pa.rebuild_pair_plan();
            }
            _ => run_chain_stage(
                stage,
                &ChainInputs {
                    model: m,
                    params: p,
                    material: self.variant.model,
                    tool: &self.tool,
                    vertex_displacements: &self.state.displacements,
                    vertex_velocities: &self.state.velocities,
                },
                pa,
                &mut self.status,
            ),
        }
    }

    /// Run one stage's twin on the stepper's thread pool.
    pub fn run_stage_pooled(&mut self, stage: Stage) {
        self.on_pool_here(|s| s.run_stage(stage));
    }

    /// One step of the plan (`reduce`: run the last-step-of-batch stages too), on the pool.
    pub fn step(&mut self, reduce: bool) {
        self.on_pool_here(|s| s.step_in_batch(0, if reduce { 1 } else { 2 }));
    }

    /// Step `steps` steps (one batch, the tool held where it is) timing every stage: mean
    /// wall ns per step spent in each stage of the plan, in plan order (stages that run
    /// every k steps are averaged over all steps).
    pub fn profile_stages(&mut self, steps: u32) -> crate::gpu::stepper::StageTimes {
        let steps = steps.max(1);
        let totals = self.on_pool_here(|c| {
            let mut totals = vec![0.0f64; c.plan.stages.len()];
            for s in 0..steps {
                for (k, total) in totals.iter_mut().enumerate() {
                    let planned = c.plan.stages[k];
                    if planned.runs_at(c.steps_done, s, steps) {
                        let t = std::time::Instant::now();
                        c.run_stage(planned.stage);
                        *total += t.elapsed().as_nanos() as f64;
                        c.counts[k].1 += 1;
                    }
                }
                c.steps_done += 1;
            }
            totals
        });
        let mut per_stage: Vec<(Stage, f64)> = Vec::new();
        for (k, total) in totals.iter().enumerate() {
            let stage = self.plan.stages[k].stage;
            match per_stage.iter_mut().find(|(st, _)| *st == stage) {
                Some((_, t)) => *t += total / steps as f64,
                None => per_stage.push((stage, total / steps as f64)),
            }
        }
        crate::gpu::stepper::StageTimes {
            per_stage,
            carried: Vec::new(),
        }
    }

    fn step_in_batch(&mut self, s: u32, len: u32) {
        let overlap = self
            .chain
            .clone()
            .filter(|_| rayon::current_num_threads() > 1);
        let mut k = 0;
        while k < self.plan.stages.len() {
            if let Some(chain) = overlap.clone().filter(|c| c.start == k) {
                self.run_chain_beside_core_forces(chain.clone());
                for j in chain.start..=chain.end {
                    self.counts[j].1 += 1;
                }
                k = chain.end + 1;
                continue;
            }
            let planned = self.plan.stages[k];
            if planned.runs_at(self.steps_done, s, len) {
                self.run_stage(planned.stage);
                self.counts[k].1 += 1;
            }
            k += 1;
        }
        self.steps_done += 1;
    }

    /// The plan's chain stages in `chain` (see [`chain_before_core_forces`]) on one side of
    /// a `rayon::join`; on the other the follower pressures when `chain` ends with them and
    /// the core's element forces (the stage at `chain.end`); then the tets' energy weights.
    /// Neither side writes what the other reads, and each keeps its own arithmetic, so the
    /// result is that of the plan's order.
    fn run_chain_beside_core_forces(&mut self, chain: std::ops::Range<usize>) {
        let m = &*self.model;
        let stages = &self.plan.stages[chain];
        let pressure = stages
            .last()
            .is_some_and(|s| s.stage == Stage::FollowerPressure);
        let inputs = ChainInputs {
            model: m,
            params: &self.params,
            material: self.variant.model,
            tool: &self.tool,
            vertex_displacements: &self.state.displacements,
            vertex_velocities: &self.state.velocities,
        };
        let (state, params, variant) = (&self.state, &self.params, self.variant);
        let (corner_forces, tet_energy) = (&mut self.corner_forces, &mut self.tet_energy);
        let (cardiac, external_forces) = (&mut self.cardiac, &mut self.external_forces);
        let mut core = move || {
            if pressure {
                follower_pressure_forces(m, params, state, cardiac, external_forces);
            }
            core_element_forces(m, params, state, corner_forces, tet_energy, variant);
        };
        let status = &mut self.status;
        let mut exact = self.exact.as_mut();
        if let Some(pa) = self.particles.as_mut() {
            // The core's stages on the calling thread (they start at once), the chain on a
            // worker (it steals it; its own loops' tasks stay on that worker while the
            // caller's deque has element forces left, and the caller joins in when done).
            rayon::join(core, || {
                for planned in stages.iter().filter(|s| is_chain_stage(s.stage)) {
                    match exact.as_deref_mut() {
                        Some(x)
                            if matches!(planned.stage, Stage::ExactStress | Stage::ExactForces) =>
                        {
                            run_exact_chain_stage(planned.stage, &inputs, pa, x)
                        }
                        _ => run_chain_stage(planned.stage, &inputs, pa, status),
                    }
                }
            });
        } else {
            core();
        }
        // Design 8: every tet keeps its full energy.
        weigh_element_forces(
            m,
            self.particles.as_ref().filter(|_| self.exact.is_none()),
            &mut self.corner_forces,
            &mut self.tet_energy,
        );
    }

    /// The last computed per-vertex forces (internal + gravity), packed xyz.
    pub fn forces(&self) -> &[f32] {
        &self.forces
    }

    /// The particles' state (embedded ones as of their last `follow`), or None without
    /// particles.
    pub fn particle_state(&self) -> Option<ParticleSnapshot> {
        self.particles.as_ref().map(|pa| ParticleSnapshot {
            displacements: pa.state.displacements.clone(),
            velocities: pa.state.velocities.clone(),
            modes: pa.state.mode.clone(),
            offsets: pa.state.offset.clone(),
            timers: pa.state.timer.clone(),
        })
    }

    /// The particles' per-run uniform as the stages see it now (None without particles).
    pub fn particle_params(&self) -> Option<ParticleParams> {
        self.particles.as_ref().map(|pa| pa.params)
    }

    /// The particles' modes (bits of [`crate::particles::params::mode`]).
    pub fn particle_modes(&self) -> Option<&[u32]> {
        self.particles.as_ref().map(|pa| pa.state.mode.as_slice())
    }

    /// The current vertex masses (re-lumped with the particles', kg) and inverse masses
    /// (negative: moved kinematically by dynamic particles).
    pub fn vertex_masses(&self) -> (&[f32], &[f32]) {
        match &self.particles {
            Some(pa) => (&pa.state.mass, &pa.state.inv_mass),
            None => (&self.model.mass, &self.model.inv_mass),
        }
    }

    /// An array by the name of its GPU buffer (`GpuStepper::read_f32` reads the same one
    /// there), for stage-by-stage comparisons: the vertices' `displacements`, `velocities`,
    /// `forces`, `mass`, `inv_mass`, `corner_forces`; the particles' `particle_displacements`,
    /// `particle_velocities`, `particle_stress`, `particle_gradient`, `particle_energy`,
    /// `particle_forces`, `particle_contact`, the activation's `tet_weight` and
    /// `contact_weight`; design 8's `exact_delta`, `exact_host_force`, `exact_tangent`,
    /// `exact_vertex_offset`, `exact_vertex_timer`. None for another name or an array the
    /// model does not have.
    pub fn array(&self, name: &str) -> Option<&[f32]> {
        let pa = self.particles.as_ref();
        let x = self.exact.as_ref();
        Some(match name {
            "displacements" => &self.state.displacements,
            "velocities" => &self.state.velocities,
            "forces" => &self.forces,
            "corner_forces" => &self.corner_forces,
            "mass" => self.vertex_masses().0,
            "inv_mass" => self.vertex_masses().1,
            "particle_displacements" => &pa?.state.displacements,
            "particle_velocities" => &pa?.state.velocities,
            "particle_stress" => &pa?.stress,
            "particle_gradient" => &pa?.gradient,
            "particle_energy" => &pa?.energy,
            "particle_forces" => &pa?.forces,
            "particle_contact" => &pa?.contact,
            "exact_delta" => &x?.delta,
            "exact_host_force" => &x?.host_force,
            "exact_tangent" => &x?.tangent,
            "exact_vertex_offset" => &x?.offsets.offset,
            "exact_vertex_timer" => &x?.offsets.timer,
            "tet_weight" => &pa?.act.tet_weight,
            "contact_weight" => &pa?.act.contact_weight,
            _ => return None,
        })
    }

    /// Overwrite design 8's per-step array `name` (`exact_delta`, `exact_host_force` or
    /// `exact_tangent`, as [`Self::array`] names them) from its start with `data` (tests,
    /// debugging; `GpuStepper::write_f32` writes the GPU's, and also raises its activation
    /// gate). False when the model has no such array or `data` is longer than it.
    pub fn write_exact_array(&mut self, name: &str, data: &[f32]) -> bool {
        let Some(x) = self.exact.as_mut() else {
            return false;
        };
        let a = match name {
            "exact_delta" => &mut x.delta,
            "exact_host_force" => &mut x.host_force,
            "exact_tangent" => &mut x.tangent,
            _ => return false,
        };
        match a.get_mut(..data.len()) {
            Some(head) => {
                head.copy_from_slice(data);
                true
            }
            None => false,
        }
    }

    /// The last SPH forces on the particles (None without particles).
    pub fn particle_forces(&self) -> Option<&[f32]> {
        self.particles.as_ref().map(|pa| pa.forces.as_slice())
    }

    /// Whether the last checkpoint's particle state and activation products equal the
    /// current ones, bit for bit (true without particles). Right after
    /// [`Stepper::checkpoint`] they must, whatever ran before: a checkpoint copies only the
    /// particles written since the one before (`cpu/touched.rs`), and this is how the tests
    /// catch a write that was not marked.
    pub fn checkpoint_matches_state(&self) -> bool {
        let (Some((state, act, _)), Some(pa)) = (&self.checkpoint.particles, &self.particles)
        else {
            return true;
        };
        let bits = |a: &[f32], b: &[f32]| {
            a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
        };
        let (s, c) = (&pa.state, state);
        bits(&s.displacements, &c.displacements)
            && bits(&s.velocities, &c.velocities)
            && bits(&s.offset, &c.offset)
            && bits(&s.timer, &c.timer)
            && bits(&s.mass, &c.mass)
            && bits(&s.inv_mass, &c.inv_mass)
            && s.mode == c.mode
            && pa.act == *act
    }

    /// Overwrite the particles' displacements and velocities.
    pub fn set_particle_state(&mut self, state: &State) {
        // (modes, offsets and timers keep their values)
        if let Some(pa) = &mut self.particles {
            pa.state.displacements.clone_from(&state.displacements);
            pa.state.velocities.clone_from(&state.velocities);
            pa.touched.mark_all();
            pa.forget_region();
        }
    }

    /// Design 8's current slaving, the slaved vertices' fading offsets and what the
    /// activations so far changed (None unless `particles.coupling = "exact"`).
    pub fn exact_slaving(
        &self,
    ) -> Option<(
        &super::exact_coupling::Slaving,
        &super::exact_activation::SlaveOffsets,
        super::exact_activation::ReslaveCounts,
    )> {
        self.exact
            .as_ref()
            .map(|x| (&x.slaving, &x.offsets, x.counts))
    }

    /// The CPU-built neighbour lists (None without particles).
    pub fn neighbour_lists(&self) -> Option<&NeighbourLists> {
        self.particles.as_ref().map(|pa| &pa.lists)
    }
}

impl Stepper for CpuStepper {
    fn name(&self) -> String {
        format!(
            "cpu ({} thread{})",
            self.threads,
            if self.threads == 1 { "" } else { "s" }
        )
    }

    fn set_params(&mut self, params: &StepParams) -> Result<()> {
        self.params = *params;
        if let (Some(pa), Some(pd)) = (&mut self.particles, self.model.particles.as_ref()) {
            // Keep the plan's sub-step count; only the sub-step and interval follow dt.
            pa.params = pa
                .params
                .at_core_dt(params.dt, pd.settings.activation_interval);
        }
        Ok(())
    }

    fn set_particle_substeps(&mut self, substeps: u32) -> Result<()> {
        let substeps = substeps.clamp(1, crate::model::MAX_PARTICLE_SUBSTEPS);
        let (Some(pa), Some(pd)) = (&mut self.particles, self.model.particles.as_ref()) else {
            return Ok(());
        };
        if self.model.slaving.is_some() || pa.params.substeps == substeps {
            return Ok(());
        }
        // Batches are run at submit: nothing in flight runs with the new plan.
        pa.params.substeps = substeps;
        pa.params = pa
            .params
            .at_core_dt(self.params.dt, pd.settings.activation_interval);
        self.plan = StepPlan::for_model_at(&self.model, substeps);
        self.chain = chain_before_core_forces(&self.plan);
        self.counts = self.plan.stages.iter().map(|p| (p.stage, 0)).collect();
        Ok(())
    }

    fn set_load_factor(&mut self, load_factor: f32) -> Result<()> {
        if self.model.follower.is_some() {
            self.cardiac.follower_load.load_factor = load_factor;
        }
        Ok(())
    }

    fn submit(&mut self, steps: u32, input: &BatchInput) -> Result<()> {
        if self.reports.len() >= RING {
            return Err(PalpateError::Gpu(format!(
                "{RING} batches are already in flight; poll or wait first"
            )));
        }
        let pool = self.pool_here()?;
        let (tool_input, tool_state, to) = input.tool_plan(steps, self.tool.at);
        self.tool.input = tool_input;
        self.tool.state = tool_state;
        self.tool.at = to;
        self.status[0] = ALL_FINITE;
        self.counts.iter_mut().for_each(|(_, c)| *c = 0);
        pool.install(|| {
            for s in 0..steps {
                self.step_in_batch(s, steps);
            }
        });
        if let Some(why) = self.exact.as_mut().and_then(|x| x.failure.take()) {
            return Err(PalpateError::Internal(format!(
                "particles.coupling = \"exact\": an activation by step {} could not slave its dynamic set: {why}",
                self.steps_done
            )));
        }
        let mut stats = BatchStats::default();
        stats.stats.copy_from_slice(&self.stats);
        stats.non_finite_vertex = (self.status[0] != ALL_FINITE).then_some(self.status[0]);
        let tool = self
            .model
            .tool
            .is_some()
            .then(|| ToolReport::from_floats(to, &self.tool.report));
        let particles = self
            .particles
            .as_ref()
            .map(|pa| ParticleReport::from_parts(&pa.act.counts, &pa.stats));
        self.reports.push_back(BatchReport {
            steps,
            stats,
            tool,
            particles,
        });
        Ok(())
    }

    fn poll(&mut self) -> Result<Option<BatchReport>> {
        Ok(self.reports.pop_front())
    }

    fn wait(&mut self) -> Result<BatchReport> {
        self.reports
            .pop_front()
            .ok_or_else(|| PalpateError::Gpu("wait: no batch in flight".into()))
    }

    fn in_flight(&self) -> usize {
        self.reports.len()
    }

    fn checkpoint(&mut self) -> Result<()> {
        // Into the last checkpoint's buffers (a haptic session checkpoints every batch).
        // Of the particles, only the blocks written since the last checkpoint (`Touched`;
        // design 8 copies everything), and the activation's products when they changed.
        let cp = &mut self.checkpoint;
        cp.state.clone_from(&self.state);
        let exact = self.exact.is_some();
        if let (Some((state, act, version)), Some(pa)) = (&mut cp.particles, &mut self.particles) {
            if exact {
                pa.touched.mark_all();
            }
            copy_particle_state(&pa.touched, &pa.state, state);
            if exact || *version != pa.act_version {
                act.clone_from(&pa.act);
                *version = pa.act_version;
            }
            // The steps until the next activation write the force set and its dynamic part
            // (marked too: it lies in the force set as the activations build them, and
            // costs nothing to mark should that ever change).
            pa.touched.reset_to(&pa.act.force_list);
            pa.touched.mark(&pa.act.dynamic_list);
        }
        if let (Some(saved), Some(x)) = (&mut cp.exact, &self.exact) {
            x.save_into(saved);
        }
        cp.steps_done = self.steps_done;
        cp.tool_at = self.tool.at;
        Ok(())
    }

    fn restore(&mut self) -> Result<()> {
        self.reports.clear();
        let cp = &self.checkpoint;
        self.state.clone_from(&cp.state);
        let exact = self.exact.is_some();
        if let (Some((state, act, version)), Some(pa)) = (&cp.particles, &mut self.particles) {
            if exact {
                pa.touched.mark_all();
            }
            copy_particle_state(&pa.touched, state, &mut pa.state);
            // The next activation visits everything; until then the restored lists, weights
            // and flags are those the restored modes were built with.
            pa.region.forget();
            if exact || *version != pa.act_version {
                pa.act.clone_from(act);
            }
            pa.act_version = *version;
            pa.touched.reset_to(&pa.act.force_list);
            pa.touched.mark(&pa.act.dynamic_list);
        }
        if let (Some(saved), Some(x)) = (&cp.exact, &mut self.exact) {
            x.restore_from(saved);
        }
        self.steps_done = cp.steps_done;
        self.tool.at = cp.tool_at;
        // A restored state has no reduction yet (as on the GPU).
        self.stats.iter_mut().for_each(|x| *x = 0.0);
        Ok(())
    }

    fn read_state(&mut self) -> Result<State> {
        Ok(self.state.clone())
    }

    fn write_state(&mut self, state: &State) -> Result<()> {
        self.state = state.clone();
        if let Some(pa) = &mut self.particles {
            pa.forget_region();
        }
        self.stats.iter_mut().for_each(|s| *s = 0.0);
        Ok(())
    }

    fn stage_counts(&self) -> Vec<(Stage, u32)> {
        self.counts.clone()
    }

    fn read_particle_state(&mut self) -> Result<Option<ParticleSnapshot>> {
        Ok(self.particle_state())
    }
}

mod gpu_activation;
pub use gpu_activation::{ExactActivationInput, ExactActivationOutput};

#[cfg(test)]
mod tests {
    use super::chain_before_core_forces;
    use crate::model::Model;
    use crate::plan::StepPlan;

    /// The chain the stepper runs beside the element forces: on hm1 the four particle stages
    /// after the activation, on a plan of 3 sub-steps all twelve, on lv_touch with a
    /// follower pressure; none without particles or when another stage stands between the
    /// chain and `FemForces`.
    #[test]
    fn the_particle_chain_before_the_element_forces_is_found() {
        let scene = crate::Scene::load("hm1").unwrap();
        let m = Model::from_scene(&scene);
        let one = StepPlan::for_model(&m);
        assert_eq!(chain_before_core_forces(&one), Some(2..6), "{one:?}");
        let three = StepPlan::for_model_at(&m, 3);
        assert_eq!(chain_before_core_forces(&three), Some(2..14), "{three:?}");
        let mut between = one.clone();
        between.stages.insert(6, between.stages[0]);
        assert_eq!(chain_before_core_forces(&between), None);
        // A chain stage that does not run every step ends the chain (right before
        // `FemForces`, it leaves none).
        let mut last = one.clone();
        let reduce = *last.stages.last().unwrap();
        assert_eq!(reduce.stage, crate::plan::Stage::ParticleReduce);
        last.stages.insert(6, reduce);
        assert_eq!(chain_before_core_forces(&last), None);
        let lv = Model::from_scene(&crate::Scene::load("lv").unwrap());
        assert_eq!(chain_before_core_forces(&StepPlan::for_model(&lv)), None);
        // lv_touch with its blood pressure as a follower load: the pressure stands between
        // the chain and `FemForces` and runs on the core's side.
        let text = crate::Scene::builtin_text("lv_touch")
            .unwrap()
            .replace("[[loads.pressure]]", "[[loads.follower_pressure]]");
        let scene = crate::Scene::from_toml(&text, "lv_touch, follower", "lv_f", None).unwrap();
        let touch = StepPlan::for_model(&Model::from_scene(&scene));
        assert_eq!(
            touch.stages[6].stage,
            crate::plan::Stage::FollowerPressure,
            "{touch:?}"
        );
        assert_eq!(chain_before_core_forces(&touch), Some(2..7), "{touch:?}");
        // A pressure before a chain stage ends the chain there.
        let mut swapped = touch.clone();
        swapped.stages.swap(5, 6);
        assert_eq!(chain_before_core_forces(&swapped), Some(6..7));
    }
}
