//! The particle layer's uniforms, mirrored field for field in `kernels/shared/particles.wgsl`
//! (a test compares sizes and offsets with naga's layout of the WGSL structs).

use bytemuck::{Pod, Zeroable};

/// The reference grid the neighbour lists are built on (WGSL `GridParams`), 48 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GridParams {
    /// Lower corner, m.
    pub origin: [f32; 3],
    /// 1 / cell edge, 1/m. A particle's cell is ⌊(x − origin)·inv_cell⌋: a product, which
    /// WGSL rounds exactly, where a quotient may be off by 2.5 ulp on a GPU, so every device
    /// bins a particle on a cell boundary alike (the lists' order depends on the bins).
    pub inv_cell: f32,
    /// Cells per axis.
    pub dims: [u32; 3],
    /// Number of cells.
    pub n_cells: u32,
    /// Number of particles.
    pub n_particles: u32,
    /// Kernel support radius R, m.
    pub support: f32,
    /// Padding.
    pub _pad: [u32; 2],
}

/// The cell edge over the support radius: a hair wider than the support, so two particles
/// closer than R always fall in the same or adjacent cells, whatever the rounding of their
/// cell coordinates.
pub const CELL_OVER_SUPPORT: f32 = 1.001;

/// The most cells a neighbour grid may have (its offsets take 4 bytes a cell, on both
/// backends): 2²⁷, 512 MiB.
pub const MAX_GRID_CELLS: u64 = 1 << 27;

impl GridParams {
    /// The grid over `rest` (packed xyz) with cells of [`CELL_OVER_SUPPORT`]·R, a support R of
    /// margin below the particles and at least one cell above them, and its number of cells
    /// (unbounded: [`GridParams::over`] needs it ≤ [`MAX_GRID_CELLS`], which sampling checks).
    pub fn layout(rest: &[f32], support: f32) -> (GridParams, u64) {
        let n = rest.len() / 3;
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for p in rest.chunks(3) {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        if n == 0 {
            lo = [0.0; 3];
            hi = [0.0; 3];
        }
        let inv_cell = 1.0 / (CELL_OVER_SUPPORT * support);
        let origin = [lo[0] - support, lo[1] - support, lo[2] - support];
        let dims = [0, 1, 2].map(|k| ((hi[k] - origin[k]) * inv_cell).floor() as u64 + 2);
        let n_cells = dims[0].saturating_mul(dims[1]).saturating_mul(dims[2]);
        let grid = GridParams {
            origin,
            inv_cell,
            dims: dims.map(|d| d.min(u32::MAX as u64) as u32),
            n_cells: n_cells.min(u32::MAX as u64) as u32,
            n_particles: n as u32,
            support,
            _pad: [0; 2],
        };
        (grid, n_cells)
    }

    /// The grid over `rest` (see [`GridParams::layout`]); `rest` has passed sampling, which
    /// bounds the cell count by [`MAX_GRID_CELLS`].
    pub fn over(rest: &[f32], support: f32) -> GridParams {
        Self::layout(rest, support).0
    }
}

/// Bits of `particle_mode` (WGSL `MODE_*`).
pub mod mode {
    /// Own position, velocity and mass.
    pub const DYNAMIC: u32 = 1;
    /// Released: embedded with a fading offset.
    pub const BLENDING: u32 = 2;
    /// At least half its barycentric weight on vertices of core tets (outside the particle
    /// region) or fixed ones (it lies on the core side of its host): never dynamic.
    pub const PINNED: u32 = 4;
    /// Close enough to the tool to matter this update.
    pub const NEAR: u32 = 8;
    /// Carries SPH stress (dynamic, or a neighbour of a dynamic particle).
    pub const IN_S: u32 = 16;
    /// Receives SPH force (in S, or a neighbour of a particle in S).
    pub const IN_F: u32 = 32;
    /// Became dynamic at this update.
    pub const ACTIVATED: u32 = 64;
    /// Stopped being dynamic at this update.
    pub const RELEASED: u32 = 128;
}

/// Bit of `node_flags`: the vertex hosts an embedded particle that receives force.
pub const NODE_COUPLED: u32 = 1;

/// Bit of `node_flags`: the vertex has no mass left and moves with its dynamic particles
/// (its velocity is their fit, set at each activation).
pub const NODE_MASSLESS: u32 = 2;

/// Per-run particle constants (WGSL `ParticleParams`), 80 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct ParticleParams {
    /// Number of particles.
    pub n_particles: u32,
    /// 0: tlsph, 1: paper.
    pub model: u32,
    /// Particle sub-steps per core step.
    pub substeps: u32,
    /// 1: every unpinned particle is dynamic.
    pub all_active: u32,
    /// Volume of every particle, m³.
    pub volume: f32,
    /// Mass of every particle, kg.
    pub mass: f32,
    /// Lattice spacing, m.
    pub spacing: f32,
    /// Kernel support radius R, m.
    pub support: f32,
    /// Hourglass coefficient α.
    pub hourglass: f32,
    /// Young's modulus in the hourglass penalty, Pa.
    pub youngs: f32,
    /// Activation radius from the tool's surface, m.
    pub activation_radius: f32,
    /// Release radius (activation × hysteresis), m.
    pub release_radius: f32,
    /// Beyond this distance from the tool's surface a particle cannot neighbour a dynamic
    /// one, m (release radius + two supports).
    pub candidate_radius: f32,
    /// Dwell time, s.
    pub dwell: f32,
    /// Blend-back time, s.
    pub blend: f32,
    /// Time between activation updates, s.
    pub interval: f32,
    /// Particle sub-step, s.
    pub sub_dt: f32,
    /// Surface vertices the tool's contact runs over (0 without a tool): the fused
    /// contact + sph_stress dispatch covers them and the stress set (`compact_args`).
    pub n_surface: u32,
    /// Padding.
    pub _pad: [u32; 2],
}

impl ParticleParams {
    /// These parameters for core step `dt`, keeping the sub-step count: the activation
    /// interval N_act·dt and the sub-step dt/substeps, formed in f64 and rounded once, so
    /// every backend gets the same values for the same dt (`Model::particle_params` builds
    /// them the same way; the steppers call this when dt changes).
    pub fn at_core_dt(mut self, dt: f32, activation_interval: u32) -> ParticleParams {
        let dt = dt as f64;
        self.interval = (activation_interval as f64 * dt) as f32;
        self.sub_dt = (dt / self.substeps.max(1) as f64) as f32;
        self
    }
}
