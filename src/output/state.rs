//! The state of a model as a `.vtu` file: points at rest, point data `displacement`,
//! `velocity` and `fixed`, cell data `material` (region id) and `fibres` where the mesh has
//! them. ParaView's *Warp By Vector* on `displacement` shows the deformed shape.

use super::vtu;
use crate::model::Model;
use crate::stepper::State;

/// The `.vtu` text of `state` on `model`.
pub fn state_vtu(model: &Model, state: &State) -> String {
    let fixed: Vec<i32> = model.inv_mass.iter().map(|&w| (w == 0.0) as i32).collect();
    let material: Vec<i32> = model.regions.iter().map(|&r| r as i32).collect();
    let mut cell_data = vec![vtu::DataArray::I32("material", &material)];
    if !model.fibres.is_empty() {
        cell_data.push(vtu::DataArray::F32("fibres", 3, &model.fibres));
    }
    vtu::vtu(
        &model.rest,
        &model.tets,
        &[
            vtu::DataArray::F32("displacement", 3, &state.displacements),
            vtu::DataArray::F32("velocity", 3, &state.velocities),
            vtu::DataArray::I32("fixed", &fixed),
        ],
        &cell_data,
    )
}
