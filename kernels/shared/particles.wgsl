// The particle layer's uniforms and kernel functions. Mirrors src/particles/params.rs
// (a test checks sizes and offsets against naga's layout of these structs).

// The reference grid the neighbour lists are built on (cells 1.001 x the kernel support).
struct GridParams {
    origin: vec3<f32>,    // m, lower corner
    inv_cell: f32,        // 1/m, 1 / cell edge (the edge is 1.001 R)
    dims: vec3<u32>,      // cells per axis
    n_cells: u32,
    n_particles: u32,
    support: f32,         // m, kernel support radius R
    _pad0: u32,
    _pad1: u32,
}

// Per-run particle constants (src/particles/params.rs `ParticleParams`).
struct ParticleParams {
    n_particles: u32,
    model: u32,           // 0 tlsph, 1 paper
    substeps: u32,        // particle sub-steps per core step
    all_active: u32,      // 1: every (unpinned) particle is dynamic
    volume: f32,          // m^3, every particle
    mass: f32,            // kg, every particle
    spacing: f32,         // m, lattice spacing
    support: f32,         // m, kernel support radius R
    hourglass: f32,       // alpha of the hourglass penalty
    youngs: f32,          // Pa, E in the hourglass penalty
    activation_radius: f32, // m from the tool's surface
    release_radius: f32,  // m, activation radius x hysteresis
    candidate_radius: f32, // m: beyond it a particle cannot be near a dynamic one
    dwell: f32,           // s
    blend: f32,           // s
    interval: f32,        // s between activation updates
    sub_dt: f32,          // s, particle sub-step
    n_surface: u32,       // surface vertices of the tool's contact (0 without a tool)
    _pad1: u32,
    _pad2: u32,
}

// Bits of particle_mode.
const MODE_DYNAMIC: u32 = 1u;        // own position, velocity and mass
const MODE_BLENDING: u32 = 2u;       // released: embedded with a fading offset
const MODE_PINNED: u32 = 4u;         // >= half its weight on core-tet or fixed vertices: never dynamic
const MODE_NEAR: u32 = 8u;           // close enough to the tool to matter this update
const MODE_IN_S: u32 = 16u;          // carries SPH stress (dynamic, or a neighbour of one)
const MODE_IN_F: u32 = 32u;          // receives SPH force (in S, or a neighbour of S)
const MODE_ACTIVATED: u32 = 64u;     // became dynamic at this update
const MODE_RELEASED: u32 = 128u;     // stopped being dynamic at this update

// Bits of node_flags.
const NODE_COUPLED: u32 = 1u;        // hosts an embedded particle that receives force
const NODE_MASSLESS: u32 = 2u;       // no mass left: moves with its dynamic particles

// Wendland C2 kernel in 3-D with support R = 2h (Wendland 1995; Dehnen & Aly 2012):
// W(q) = 21/(16 pi h^3) (1 - q/2)^4 (2q + 1), q = r/h; its gradient with respect to the
// offset vector d (r = |d|) is -105/(16 pi h^5) (1 - q/2)^3 d.
fn wendland_gradient(d: vec3<f32>, support: f32) -> vec3<f32> {
    let h = 0.5 * support;
    let q = length(d) / h;
    if q >= 2.0 {
        return vec3<f32>(0.0);
    }
    let t = 1.0 - 0.5 * q;
    return d * (-105.0 / (16.0 * 3.14159265358979 * h * h * h * h * h) * t * t * t);
}

fn wendland(r: f32, support: f32) -> f32 {
    let h = 0.5 * support;
    let q = r / h;
    if q >= 2.0 {
        return 0.0;
    }
    let t = 1.0 - 0.5 * q;
    return 21.0 / (16.0 * 3.14159265358979 * h * h * h) * t * t * t * t * (2.0 * q + 1.0);
}

// The paper's eq. (8) Lennard-Jones-like function W(s) = (1/s)^3 - 1/s of the distance in
// lattice spacings s = r/dx (epsilon = 1); its gradient with respect to d is
// W'(s)/(dx r) d, W'(s) = -3/s^4 + 1/s^2. Not a normalised kernel: singular at 0, zero at
// s = 1, negative beyond; used only through corrected gradients (see src/particles/).
fn paper_gradient(d: vec3<f32>, spacing: f32, support: f32) -> vec3<f32> {
    let r = length(d);
    if r >= support || r <= 0.0 {
        return vec3<f32>(0.0);
    }
    let s = r / spacing;
    let dw = -3.0 / (s * s * s * s) + 1.0 / (s * s);
    return d * (dw / (spacing * r));
}

// The kernel gradient of particle model `model` (0 tlsph: Wendland C2, 1 paper: eq. 8) at
// offset d (twin: cpu::sph::kernel_gradient).
fn model_kernel_gradient(model: u32, d: vec3<f32>, spacing: f32, support: f32) -> vec3<f32> {
    if model == 1u {
        return paper_gradient(d, spacing, support);
    }
    return wendland_gradient(d, support);
}
