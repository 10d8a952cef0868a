// Per-batch parameters shared by every kernel. Mirrors src/params.rs `StepParams`
// (a test checks size and offsets against naga's layout of this struct).
struct StepParams {
    n_vertices: u32,
    n_tets: u32,
    dt: f32,              // s
    damping: f32,         // mass-proportional alpha, 1/s
    gravity: vec3<f32>,   // m/s^2
    lambda: f32,          // Pa
    mu: f32,              // Pa
    phi: f32,             // Pa s
    psi: f32,             // Pa s
    speed_limit: f32,     // m/s; |v| above it counts as diverged (10 x P-wave speed)
}

// Slots of the 8-float stats buffer (src/params.rs `stat`).
const STAT_KINETIC: u32 = 0u;
const STAT_ELASTIC: u32 = 1u;
const STAT_MAX_SPEED: u32 = 2u;
const STAT_RESIDUAL_SQ: u32 = 3u;
const STAT_EXTERNAL_SQ: u32 = 4u;
const STAT_MASS_DISPLACEMENT_SQ: u32 = 5u;
