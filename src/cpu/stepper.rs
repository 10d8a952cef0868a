//! The CPU backend: executes the step plan with the kernels' twins, on a pool of `threads`
//! worker threads. Every twin writes only per-index outputs, so the result is bit-identical
//! for any thread count; the reduction sums in the GPU's fixed tree order.

use super::{
    contact, fem_forces, gather, integrate, reduce_final, reduce_partial, tool_force_final,
    tool_force_partial, tool_motion,
};
use crate::contact::{ToolInput, ToolParams, ToolState, REPORT_LEN};
use crate::cpu::fem_forces::FemVariant;
use crate::cpu::integrate::ALL_FINITE;
use crate::cpu::reduce::{n_partials, PARTIAL_LEN};
use crate::error::{PalpateError, Result};
use crate::model::Model;
use crate::params::{stat, StepParams};
use crate::plan::{Stage, StepPlan};
use crate::stepper::{BatchInput, BatchReport, BatchStats, State, Stepper, ToolReport, RING};
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

/// CPU stepper: the reference path, parallel over tets and vertices.
pub struct CpuStepper {
    model: Arc<Model>,
    plan: StepPlan,
    params: StepParams,
    variant: FemVariant,
    pool: Arc<rayon::ThreadPool>,
    threads: usize,
    state: State,
    checkpoint: Option<State>,
    corner_forces: Vec<f32>,
    tet_energy: Vec<f32>,
    forces: Vec<f32>,
    partials: Vec<f32>,
    stats: Vec<f32>,
    status: Vec<u32>,
    tool: ToolArrays,
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
        let plan = StepPlan::for_model(&model);
        let tool_params = model.tool.as_ref().map(|t| t.params()).unwrap_or_default();
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
        CpuStepper {
            tool,
            counts: plan.stages.iter().map(|p| (p.stage, 0)).collect(),
            plan,
            variant: model.fem_variant(),
            corner_forces: vec![0.0; 12 * model.n_tets()],
            tet_energy: vec![0.0; model.n_tets()],
            forces: vec![0.0; 3 * model.n_vertices()],
            partials: vec![0.0; PARTIAL_LEN * n_partials(&params)],
            stats: vec![0.0; stat::LEN],
            status: vec![ALL_FINITE; 4],
            checkpoint: None,
            state,
            model,
            params,
            pool,
            threads,
            steps_done: 0,
            reports: VecDeque::new(),
        }
    }

    /// Worker threads.
    pub fn threads(&self) -> usize {
        self.threads
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
            ),
            Stage::ToolForce => {
                tool_force_partial(
                    p,
                    &t.params,
                    &t.input,
                    surface_vertices,
                    surface_area,
                    &m.rest,
                    &self.state.displacements,
                    &self.state.velocities,
                    &mut t.partials,
                );
                tool_force_final(&t.params, &t.partials, &mut t.report);
            }
            Stage::FemForces => fem_forces(
                p,
                &self.state.displacements,
                &self.state.velocities,
                &m.tets,
                &m.dm_inv,
                &m.rest_volume,
                &mut self.corner_forces,
                &mut self.tet_energy,
                self.variant,
            ),
            Stage::Gather => gather(
                p,
                &self.corner_forces,
                &m.incidence_offsets,
                &m.incidence,
                &m.mass,
                &m.external_forces,
                &mut self.forces,
                surface_index,
                &t.contact_forces,
                has_tool,
            ),
            Stage::Integrate => integrate(
                p,
                &self.forces,
                &m.inv_mass,
                &mut self.state.displacements,
                &mut self.state.velocities,
                &mut self.status,
            ),
            Stage::Reduce => {
                reduce_partial(
                    p,
                    &self.state.displacements,
                    &self.state.velocities,
                    &m.mass,
                    &m.inv_mass,
                    &self.forces,
                    &m.external_forces,
                    &self.tet_energy,
                    &mut self.partials,
                    surface_index,
                    &t.contact_forces,
                    has_tool,
                );
                reduce_final(p, &self.partials, &mut self.stats);
            }
        }
    }

    /// Run one stage's twin on the stepper's thread pool.
    pub fn run_stage_pooled(&mut self, stage: Stage) {
        let pool = self.pool.clone();
        pool.install(|| self.run_stage(stage));
    }

    /// One step of the plan (`reduce`: run the last-step-of-batch stages too), on the pool.
    pub fn step(&mut self, reduce: bool) {
        let pool = self.pool.clone();
        pool.install(|| self.step_in_batch(0, if reduce { 1 } else { 2 }));
    }

    fn step_in_batch(&mut self, s: u32, len: u32) {
        for k in 0..self.plan.stages.len() {
            let planned = self.plan.stages[k];
            if planned.runs_at(self.steps_done, s, len) {
                self.run_stage(planned.stage);
                self.counts[k].1 += 1;
            }
        }
        self.steps_done += 1;
    }

    /// The last computed per-vertex forces (internal + gravity), packed xyz.
    pub fn forces(&self) -> &[f32] {
        &self.forces
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
        Ok(())
    }

    fn submit(&mut self, steps: u32, input: &BatchInput) -> Result<()> {
        if self.reports.len() >= RING {
            return Err(PalpateError::Gpu(format!(
                "{RING} batches are already in flight; poll or wait first"
            )));
        }
        let (from, to) = input.tool.unwrap_or((self.tool.at, self.tool.at));
        self.tool.input = crate::contact::batch_input(from, to, steps);
        self.tool.state = ToolState {
            position: self.tool.input.start,
            step: 0,
        };
        self.tool.at = to;
        self.status[0] = ALL_FINITE;
        self.counts.iter_mut().for_each(|(_, c)| *c = 0);
        let pool = self.pool.clone();
        pool.install(|| {
            for s in 0..steps {
                self.step_in_batch(s, steps);
            }
        });
        let mut stats = BatchStats::default();
        stats.stats.copy_from_slice(&self.stats);
        stats.non_finite_vertex = (self.status[0] != ALL_FINITE).then_some(self.status[0]);
        let tool = self
            .model
            .tool
            .is_some()
            .then(|| ToolReport::from_floats(to, &self.tool.report));
        self.reports.push_back(BatchReport { steps, stats, tool });
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
        self.checkpoint = Some(self.state.clone());
        Ok(())
    }

    fn restore(&mut self) -> Result<()> {
        self.reports.clear();
        match &self.checkpoint {
            Some(state) => self.state = state.clone(),
            None => {
                self.state.displacements.iter_mut().for_each(|x| *x = 0.0);
                self.state.velocities.iter_mut().for_each(|x| *x = 0.0);
            }
        }
        // A restored state has no reduction yet (as on the GPU).
        self.stats.iter_mut().for_each(|x| *x = 0.0);
        Ok(())
    }

    fn read_state(&mut self) -> Result<State> {
        Ok(self.state.clone())
    }

    fn write_state(&mut self, state: &State) -> Result<()> {
        self.state = state.clone();
        self.stats.iter_mut().for_each(|s| *s = 0.0);
        Ok(())
    }

    fn stage_counts(&self) -> Vec<(Stage, u32)> {
        self.counts.clone()
    }
}
