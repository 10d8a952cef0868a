//! The particle layer's uniforms, mirrored field for field in `kernels/shared/particles.wgsl`
//! (a test compares sizes and offsets with naga's layout of the WGSL structs).

use bytemuck::{Pod, Zeroable};

/// The reference grid the neighbour lists are built on (WGSL `GridParams`), 48 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GridParams {
    /// Lower corner, m.
    pub origin: [f32; 3],
    /// Cell edge (the support radius), m.
    pub cell: f32,
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

impl GridParams {
    /// The grid over `rest` (packed xyz) with cells of the support radius, one cell of
    /// margin on every side.
    pub fn over(rest: &[f32], support: f32) -> GridParams {
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
        let origin = [lo[0] - support, lo[1] - support, lo[2] - support];
        let dims = [0, 1, 2].map(|k| ((hi[k] - origin[k]) / support).floor() as u32 + 2);
        GridParams {
            origin,
            cell: support,
            dims,
            n_cells: dims[0] * dims[1] * dims[2],
            n_particles: n as u32,
            support,
            _pad: [0; 2],
        }
    }
}
