// The particle layer's uniforms and kernel functions. Mirrors src/particles/params.rs
// (a test checks sizes and offsets against naga's layout of these structs).

// The reference grid the neighbour lists are built on (cells of the kernel support).
struct GridParams {
    origin: vec3<f32>,    // m, lower corner
    cell: f32,            // m, cell edge (= the support radius)
    dims: vec3<u32>,      // cells per axis
    n_cells: u32,
    n_particles: u32,
    support: f32,         // m, kernel support radius R
    _pad0: u32,
    _pad1: u32,
}

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
