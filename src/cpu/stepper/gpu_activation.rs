//! Design 8's activation under the tool for the GPU stepper. Its re-slave (the closure, the
//! fits, the momentum-keeping re-lump: `cpu/exact_activation.rs`) has no kernel; the GPU
//! stepper keeps a CPU stepper of the same model beside it that runs only `ActivateExact`.
//! At each activation step the GPU hands it what its steps since the last one changed
//! ([`ExactActivationInput`], read from the buffers of the same names), the twin runs the
//! activation as the CPU backend does, and the GPU takes back what it wrote
//! ([`ExactActivationOutput`]). Everything else the activation reads (the slaving, the fading
//! offsets, the last sets, the region) changes only at activations and stays in the twin.

use super::CpuStepper;
use crate::contact::ToolState;
use crate::cpu::exact_coupling::Slaving;
use crate::error::{PalpateError, Result};
use crate::plan::Stage;

/// What design 8's activation reads that the steps change, as the GPU holds it.
pub struct ExactActivationInput<'a> {
    /// Vertex displacements, packed xyz, m (`displacements`).
    pub displacements: &'a [f32],
    /// Vertex velocities, m/s (`velocities`).
    pub velocities: &'a [f32],
    /// Particle displacements, m (`particle_displacements`).
    pub particle_displacements: &'a [f32],
    /// Particle velocities, m/s (`particle_velocities`).
    pub particle_velocities: &'a [f32],
    /// Particle mode bits (`particle_mode`).
    pub particle_mode: &'a [u32],
    /// Particle dwell and blend clocks, s (`particle_timer`).
    pub particle_timer: &'a [f32],
    /// Particle blend offsets, m (`particle_offset`).
    pub particle_offset: &'a [f32],
    /// The tool after this step's `tool_motion` (`tool_state`).
    pub tool_state: ToolState,
    /// The slaved vertices' offset clocks, s (`exact_vertex_timer`).
    pub vertex_timer: &'a [f32],
    /// Steps done before this activation's step (named in an error).
    pub steps_done: u64,
}

/// What design 8's activation wrote, for the GPU's buffers of the same names.
pub struct ExactActivationOutput<'a> {
    /// The slaving, sets or lists changed (false: only the mode machine's modes and clocks
    /// moved; everything from `slaving` on is as before).
    pub changed: bool,
    /// Vertex displacements (`displacements`).
    pub displacements: &'a [f32],
    /// Vertex velocities (`velocities`).
    pub velocities: &'a [f32],
    /// Vertex masses, kg (`mass`, and `exact_mass` for the relump).
    pub mass: &'a [f32],
    /// Vertex inverse masses, −1 on slaved vertices (`inv_mass`, `exact_inv_mass`).
    pub inv_mass: &'a [f32],
    /// `particle_displacements`.
    pub particle_displacements: &'a [f32],
    /// `particle_velocities`.
    pub particle_velocities: &'a [f32],
    /// `particle_mode`.
    pub particle_mode: &'a [u32],
    /// `particle_timer`.
    pub particle_timer: &'a [f32],
    /// `particle_offset`.
    pub particle_offset: &'a [f32],
    /// `dynamic_list`.
    pub dynamic_list: &'a [u32],
    /// `stress_list`.
    pub stress_list: &'a [u32],
    /// `force_list`.
    pub force_list: &'a [u32],
    /// `particle_counts`: (|D|, |S|, |F|, 0).
    pub counts: [u32; 4],
    /// `particle_dispatch`: the three lists' indirect arguments.
    pub dispatch: [u32; 9],
    /// `tet_weight`.
    pub tet_weight: &'a [f32],
    /// `contact_weight`.
    pub contact_weight: &'a [f32],
    /// The slaving (`exact_fit_*`, `exact_slave_*` through `gpu::groups::ExactTables::of`).
    pub slaving: &'a Slaving,
    /// The slaved vertices' fading offsets, m (`exact_vertex_offset`).
    pub vertex_offset: &'a [f32],
    /// Their clocks, s (`exact_vertex_timer`).
    pub vertex_timer: &'a [f32],
    /// The particles this activation took out of S: their 12 tangent corner forces each
    /// become zero in `exact_tangent` (only S's are ever nonzero, and S's the next
    /// `exact_stress` rewrites, so the twin neither reads nor returns the array).
    pub left_stress: &'a [u32],
}

impl CpuStepper {
    /// Run design 8's activation (`ActivateExact`) on `input`, the GPU's state at an
    /// activation step, and return what it wrote (see the module doc). An error where the
    /// dynamic set cannot be slaved, as the CPU backend's batch reports it; None without the
    /// exact coupling.
    pub fn activate_exact_for_gpu(
        &mut self,
        input: &ExactActivationInput,
    ) -> Result<Option<ExactActivationOutput<'_>>> {
        let (Some(pa), Some(x)) = (self.particles.as_mut(), self.exact.as_mut()) else {
            return Ok(None);
        };
        self.state
            .displacements
            .copy_from_slice(input.displacements);
        self.state.velocities.copy_from_slice(input.velocities);
        pa.touched.mark_all();
        let ps = &mut pa.state;
        ps.displacements
            .copy_from_slice(input.particle_displacements);
        ps.velocities.copy_from_slice(input.particle_velocities);
        ps.mode.copy_from_slice(input.particle_mode);
        ps.timer.copy_from_slice(input.particle_timer);
        ps.offset.copy_from_slice(input.particle_offset);
        x.offsets.timer.copy_from_slice(input.vertex_timer);
        self.tool.state = input.tool_state;
        self.steps_done = input.steps_done;
        let unchanged = pa.activations.unchanged;
        self.run_stage_pooled(Stage::ActivateExact);
        let (Some(pa), Some(x)) = (self.particles.as_mut(), self.exact.as_mut()) else {
            return Ok(None);
        };
        if let Some(why) = x.failure.take() {
            return Err(PalpateError::Internal(format!(
                "particles.coupling = \"exact\": an activation by step {} could not slave its dynamic set: {why}",
                self.steps_done
            )));
        }
        Ok(Some(ExactActivationOutput {
            changed: pa.activations.unchanged == unchanged,
            displacements: &self.state.displacements,
            velocities: &self.state.velocities,
            mass: &pa.state.mass,
            inv_mass: &pa.state.inv_mass,
            particle_displacements: &pa.state.displacements,
            particle_velocities: &pa.state.velocities,
            particle_mode: &pa.state.mode,
            particle_timer: &pa.state.timer,
            particle_offset: &pa.state.offset,
            dynamic_list: &pa.act.dynamic_list,
            stress_list: &pa.act.stress_list,
            force_list: &pa.act.force_list,
            counts: pa.act.counts,
            dispatch: pa.act.dispatch,
            tet_weight: &pa.act.tet_weight,
            contact_weight: &pa.act.contact_weight,
            slaving: &x.slaving,
            vertex_offset: &x.offsets.offset,
            vertex_timer: &x.offsets.timer,
            left_stress: &x.left_stress,
        }))
    }
}
