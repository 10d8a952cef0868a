//! The per-batch uniform shared by every kernel and its CPU twin.
//!
//! Mirrors `kernels/shared/params.wgsl` field for field; a test compares this struct's
//! size and offsets with naga's layout of the WGSL struct.

use bytemuck::{Pod, Zeroable};

/// Index of each quantity in the 8-float `stats` buffer written by `reduce`.
pub mod stat {
    /// Σ ½ m |v|², J.
    pub const KINETIC: usize = 0;
    /// Σ V Ψ(E), J.
    pub const ELASTIC: usize = 1;
    /// max |v|, m/s.
    pub const MAX_SPEED: usize = 2;
    /// Σ |f|² over free vertices, N².
    pub const RESIDUAL_SQ: usize = 3;
    /// Σ |m g + f_ext|² over free vertices, N².
    pub const EXTERNAL_SQ: usize = 4;
    /// Σ m |x − X|², kg·m² (with the elastic energy, a Rayleigh-quotient estimate of the
    /// dominant frequency: ω² ≈ 2·elastic / Σ m|u|²).
    pub const MASS_DISPLACEMENT_SQ: usize = 5;
    /// Number of floats in the stats buffer.
    pub const LEN: usize = 8;
}

/// Step parameters (WGSL `StepParams`), 48 bytes, std140-compatible.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct StepParams {
    /// Number of vertices.
    pub n_vertices: u32,
    /// Number of tets.
    pub n_tets: u32,
    /// Time step, s.
    pub dt: f32,
    /// Mass-proportional damping α, 1/s: v ← v / (1 + α dt).
    pub damping: f32,
    /// Gravity, m/s².
    pub gravity: [f32; 3],
    /// First Lamé parameter λ, Pa.
    pub lambda: f32,
    /// Shear modulus μ, Pa.
    pub mu: f32,
    /// Bulk viscosity φ, Pa·s.
    pub phi: f32,
    /// Shear viscosity ψ, Pa·s.
    pub psi: f32,
    /// Speed above which a vertex counts as diverged, m/s
    /// ([`crate::model::SPEED_LIMIT_WAVE_SPEEDS`] × the P-wave speed).
    pub speed_limit: f32,
}
