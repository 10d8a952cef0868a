//! CPU twin of `kernels/neighbours.wgsl`: the particles' reference neighbour lists on a
//! uniform grid, in the same fixed order (cells z, y, x ascending, then particles
//! ascending), so the CPU and GPU lists are identical.

use super::load3;
use crate::particles::params::GridParams;
use glam::{IVec3, UVec3, Vec3};

fn cell_coords(g: &GridParams, x: Vec3) -> IVec3 {
    let c = ((x - Vec3::from_array(g.origin)) * g.inv_cell)
        .floor()
        .as_ivec3();
    c.clamp(
        IVec3::ZERO,
        UVec3::from_array(g.dims).as_ivec3() - IVec3::ONE,
    )
}

fn cell_id(g: &GridParams, c: IVec3) -> u32 {
    (c.z as u32 * g.dims[1] + c.y as u32) * g.dims[0] + c.x as u32
}

fn in_grid(g: &GridParams, c: IVec3) -> bool {
    c.cmpge(IVec3::ZERO).all() && c.cmplt(UVec3::from_array(g.dims).as_ivec3()).all()
}

/// The grid, the cell of each particle, and the CSR lists: (cell_offsets (n_cells + 1),
/// cell_particles, neighbour_offsets (n + 1), neighbours).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NeighbourLists {
    /// Per cell, the start of its particles in `cell_particles` (n_cells + 1 entries).
    pub cell_offsets: Vec<u32>,
    /// Particles grouped by cell, ascending within a cell.
    pub cell_particles: Vec<u32>,
    /// Per particle, the start of its neighbours (n + 1 entries).
    pub neighbour_offsets: Vec<u32>,
    /// Neighbour lists.
    pub neighbours: Vec<u32>,
}

/// `neighbours_bin`, scan, `neighbours_place`, `neighbours_sort`, `neighbours_count`,
/// scan, `neighbours_fill`, in that order, on the particles' rest positions.
pub fn build(g: &GridParams, particle_rest: &[f32]) -> NeighbourLists {
    let n = g.n_particles as usize;
    let nc = g.n_cells as usize;
    let r2 = g.support * g.support;
    // bin
    let cells: Vec<u32> = (0..n)
        .map(|p| cell_id(g, cell_coords(g, load3(particle_rest, p))))
        .collect();
    let mut cell_offsets = vec![0u32; nc + 1];
    for &c in &cells {
        cell_offsets[c as usize] += 1;
    }
    super::scan::exclusive_scan(nc + 1, &mut cell_offsets);
    // place (in any order) then sort each cell: ascending particle index
    let mut fill = vec![0u32; nc];
    let mut cell_particles = vec![0u32; n];
    for (p, &c) in cells.iter().enumerate() {
        cell_particles[(cell_offsets[c as usize] + fill[c as usize]) as usize] = p as u32;
        fill[c as usize] += 1;
    }
    for c in 0..nc {
        cell_particles[cell_offsets[c] as usize..cell_offsets[c + 1] as usize].sort_unstable();
    }
    let visit = |p: usize, out: &mut dyn FnMut(u32)| {
        let x = load3(particle_rest, p);
        let c0 = cell_coords(g, x);
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let c = c0 + IVec3::new(dx, dy, dz);
                    if !in_grid(g, c) {
                        continue;
                    }
                    let id = cell_id(g, c) as usize;
                    for s in cell_offsets[id]..cell_offsets[id + 1] {
                        let b = cell_particles[s as usize];
                        let d = load3(particle_rest, b as usize) - x;
                        if b as usize != p && d.dot(d) < r2 {
                            out(b);
                        }
                    }
                }
            }
        }
    };
    let mut neighbour_offsets = vec![0u32; n + 1];
    for (p, count) in neighbour_offsets.iter_mut().take(n).enumerate() {
        visit(p, &mut |_| *count += 1);
    }
    let total = super::scan::exclusive_scan(n + 1, &mut neighbour_offsets);
    let mut neighbours = Vec::with_capacity(total as usize);
    for p in 0..n {
        visit(p, &mut |b| neighbours.push(b));
    }
    NeighbourLists {
        cell_offsets,
        cell_particles,
        neighbour_offsets,
        neighbours,
    }
}
