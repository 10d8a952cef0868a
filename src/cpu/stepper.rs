//! The CPU backend: the twins of the kernels called in the order of one GPU step.

use super::{fem_forces, gather, integrate, reduce_final, reduce_partial};
use crate::cpu::fem_forces::FemVariant;
use crate::cpu::integrate::ALL_FINITE;
use crate::cpu::reduce::{n_partials, PARTIAL_LEN};
use crate::error::Result;
use crate::model::Model;
use crate::params::{stat, StepParams};
use crate::stepper::{BatchStats, State, Stepper};
use std::sync::Arc;

/// CPU reference stepper (single thread).
pub struct CpuStepper {
    model: Arc<Model>,
    params: StepParams,
    variant: FemVariant,
    state: State,
    snapshot: (State, Vec<f32>),
    corner_forces: Vec<f32>,
    tet_energy: Vec<f32>,
    forces: Vec<f32>,
    partials: Vec<f32>,
    stats: Vec<f32>,
    status: Vec<u32>,
}

impl CpuStepper {
    /// A stepper at rest.
    pub fn new(model: Arc<Model>, params: StepParams) -> CpuStepper {
        let state = State {
            displacements: vec![0.0; model.rest.len()],
            velocities: vec![0.0; model.rest.len()],
        };
        CpuStepper {
            variant: model.fem_variant(),
            corner_forces: vec![0.0; 12 * model.n_tets()],
            tet_energy: vec![0.0; model.n_tets()],
            forces: vec![0.0; 3 * model.n_vertices()],
            partials: vec![0.0; PARTIAL_LEN * n_partials(&params)],
            stats: vec![0.0; stat::LEN],
            status: vec![ALL_FINITE; 4],
            snapshot: (state.clone(), vec![0.0; stat::LEN]),
            state,
            model,
            params,
        }
    }

    /// One step: fem_forces → gather → integrate (→ reduce).
    pub fn step(&mut self, reduce: bool) {
        let m = &*self.model;
        let p = &self.params;
        fem_forces(
            p,
            &self.state.displacements,
            &self.state.velocities,
            &m.tets,
            &m.dm_inv,
            &m.rest_volume,
            &mut self.corner_forces,
            &mut self.tet_energy,
            self.variant,
        );
        gather(
            p,
            &self.corner_forces,
            &m.incidence_offsets,
            &m.incidence,
            &m.mass,
            &m.external_forces,
            &mut self.forces,
        );
        integrate(
            p,
            &self.forces,
            &m.inv_mass,
            &mut self.state.displacements,
            &mut self.state.velocities,
            &mut self.status,
        );
        if reduce {
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
            );
            reduce_final(p, &self.partials, &mut self.stats);
        }
    }

    /// The last computed per-vertex forces (internal + gravity), packed xyz.
    pub fn forces(&self) -> &[f32] {
        &self.forces
    }
}

impl Stepper for CpuStepper {
    fn name(&self) -> String {
        "cpu (reference, 1 thread)".into()
    }

    fn set_params(&mut self, params: &StepParams) -> Result<()> {
        self.params = *params;
        Ok(())
    }

    fn run(&mut self, steps: u32) -> Result<BatchStats> {
        self.snapshot = (self.state.clone(), self.stats.clone());
        self.status[0] = ALL_FINITE;
        for s in 0..steps {
            self.step(s + 1 == steps);
        }
        let mut out = BatchStats::default();
        out.stats.copy_from_slice(&self.stats);
        out.non_finite_vertex = (self.status[0] != ALL_FINITE).then_some(self.status[0]);
        Ok(out)
    }

    fn restore(&mut self) -> Result<()> {
        self.state = self.snapshot.0.clone();
        self.stats = self.snapshot.1.clone();
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
}
