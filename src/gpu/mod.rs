//! The GPU backend: wgpu context, one struct per kernel file, the simulation buffers and the
//! stepper that records many steps per command buffer.

pub mod buffers;
pub mod context;
pub mod groups;
pub mod kernel;
pub mod preprocess;
pub mod setup;
pub mod stepper;

pub use context::GpuContext;
pub use stepper::GpuStepper;

include!(concat!(env!("OUT_DIR"), "/kernels.rs"));

/// The preprocessed WGSL of kernel file `name` (without extension), as validated at build time.
pub fn kernel_source(name: &str) -> Option<&'static str> {
    KERNELS.iter().find(|(n, _)| *n == name).map(|(_, s)| *s)
}
