//! palpate: a GPU compute-first engine for deformable soft tissue under haptic interaction,
//! after Mero & Susin, "Deformable Hybrid Model for Haptic Interaction".
//!
//! The public path is [`scene::Scene`] → [`sim::Simulation`] → `advance` (DESIGN's "step":
//! a batch of steps) / `state` / `contact`. Every
//! per-element and per-vertex stage is a WGSL kernel in `kernels/` with a CPU twin in
//! [`cpu`]; see `ARCHITECTURE.md`.

#![warn(missing_docs)] // every public item has a doc comment (STYLE; the brief)
pub mod bench;
pub mod compliance;
pub mod console;
pub mod contact;
pub mod cpu;
pub mod error;
pub mod gpu;
pub mod haptic_run;
pub mod haptics;
pub mod input;
pub mod interrupt;
pub mod inversion;
pub mod material;
pub mod mesh;
pub mod model;
pub mod output;
pub mod params;
pub mod particles;
pub mod plan;
pub mod rest;
pub mod run;
pub mod scene;
pub mod sim;
pub mod stepper;
pub mod substeps;
pub mod timestep;

pub use error::{PalpateError, Result};
pub use scene::Scene;
pub use sim::{Backend, Simulation};
