//! `palpate bench …`: studies that write tables and plots under `docs/`.
//!
//! * [`stability`]: the largest stable time step per material and mesh, and stress cases.
//! * [`accuracy`]: error against a converged reference versus run time, and its Pareto front.
//! * [`contact`]: the tool's contact force against Hertz's solution.
//! * [`land`]: the Land et al. 2015 cardiac benchmark (problems 1 and 2) under refinement.
//! * [`haptic`]: the servo loop and the physics thread together (rate, lateness, model age,
//!   realtime factor).

pub mod accuracy;
pub mod contact;
pub mod haptic;
pub mod land;
pub mod stability;

use crate::error::Result;
use crate::material::MaterialModel;
use crate::model::Model;
use crate::scene::Scene;
use crate::stepper::State;
use glam::Vec3;

/// The built-in `beam` scene with other cells and material model.
pub fn beam_scene(cells: [usize; 3], model: MaterialModel) -> Result<Scene> {
    let text = include_str!("../../scenes/beam.toml")
        .replace(
            "cells = [20, 4, 4]",
            &format!("cells = [{}, {}, {}]", cells[0], cells[1], cells[2]),
        )
        .replace("model = \"stvk\"", &format!("model = \"{}\"", model.name()));
    Scene::from_toml(
        &text,
        &format!("beam {cells:?} {}", model.name()),
        "beam",
        None,
    )
}

/// The built-in `lv` scene at resolution `k` with another material model.
pub fn lv_scene(k: usize, model: MaterialModel) -> Result<Scene> {
    let text = include_str!("../../scenes/lv.toml")
        .replace("resolution = 3 ", &format!("resolution = {k} "))
        .replace("model = \"stvk\"", &format!("model = \"{}\"", model.name()));
    Scene::from_toml(&text, &format!("lv k={k} {}", model.name()), "lv", None)
}

/// Work of the constant loads, Σ (m g + f_ext)·u, J.
pub fn load_work(model: &Model, state: &State) -> f64 {
    let g = Vec3::from_array(model.gravity);
    (0..model.n_vertices())
        .map(|i| {
            let f = g * model.mass[i] + crate::cpu::load3(&model.external_forces, i);
            f.dot(crate::cpu::load3(&state.displacements, i)) as f64
        })
        .sum()
}

/// Kinetic energy of a state, J.
pub fn kinetic(model: &Model, state: &State) -> f64 {
    (0..model.n_vertices())
        .map(|i| {
            let v = crate::cpu::load3(&state.velocities, i);
            0.5 * model.mass[i] as f64 * v.dot(v) as f64
        })
        .sum()
}

/// Elastic energy of a state, Σ V Ψ over tets (the CPU `fem_forces` twin), J.
pub fn elastic_energy(model: &Model, state: &State) -> f64 {
    let p = model.step_params(0.0, 0.0);
    let mut corner = vec![0.0; 12 * model.n_tets()];
    let mut energy = vec![0.0; model.n_tets()];
    crate::cpu::fem_forces(
        &p,
        &state.displacements,
        &state.velocities,
        &model.tets,
        &model.dm_inv,
        &model.rest_volume,
        &mut corner,
        &mut energy,
        model.fem_variant(),
    );
    energy.iter().map(|&e| e as f64).sum()
}
