// Setup stage: the particles' reference neighbour lists, built once on a uniform grid of
// cells a hair wider than the kernel support (1.001 R), in CSR form and in a fixed order (cells z, y, x
// ascending, then particles ascending), so every device builds the same lists.
//   neighbours_bin    per particle: its cell, and an (integer) atomic count per cell, in
//                     cell_offsets (counts until the scan turns them into offsets)
//   [scan over cell_offsets (n_cells + 1 entries): exclusive offsets]
//   neighbours_place  per particle: its slot in its cell (atomic cursor; order fixed below)
//   neighbours_sort   per cell: insertion sort of its particles by index
//   neighbours_count  per particle: neighbours b != p with |X_b - X_p| < R in the 27 cells
//   [scan over neighbour_offsets (n + 1 entries, counts until then); the total sizes
//    `neighbours`]
//   neighbours_fill   per particle: its list, in the fixed order
// CPU twin: src/cpu/neighbours.rs.
#import index
#import particles

@group(0) @binding(0) var<uniform> grid_params: GridParams;
@group(0) @binding(1) var<storage, read> particle_rest: array<f32>;
@group(0) @binding(2) var<storage, read_write> particle_cell: array<u32>;
@group(0) @binding(3) var<storage, read_write> cell_offsets: array<atomic<u32>>;
@group(0) @binding(4) var<storage, read_write> cell_fill: array<atomic<u32>>;
@group(0) @binding(5) var<storage, read_write> cell_particles: array<u32>;
@group(0) @binding(6) var<storage, read_write> neighbour_offsets: array<u32>;
@group(0) @binding(7) var<storage, read_write> neighbours: array<u32>;

const WORKGROUP: u32 = 64u;

fn rest(p: u32) -> vec3<f32> {
    return vec3<f32>(particle_rest[3u * p], particle_rest[3u * p + 1u], particle_rest[3u * p + 2u]);
}

fn cell_coords(x: vec3<f32>) -> vec3<i32> {
    // A product, not a quotient: WGSL rounds it exactly, so every device bins alike.
    let c = vec3<i32>(floor((x - grid_params.origin) * grid_params.inv_cell));
    return clamp(c, vec3<i32>(0), vec3<i32>(grid_params.dims) - vec3<i32>(1));
}

fn cell_id(c: vec3<i32>) -> u32 {
    let d = grid_params.dims;
    return (u32(c.z) * d.y + u32(c.y)) * d.x + u32(c.x);
}

fn in_grid(c: vec3<i32>) -> bool {
    return all(c >= vec3<i32>(0)) && all(c < vec3<i32>(grid_params.dims));
}

// The start of cell c's particles (after the scan; read through the atomic view).
fn cell_start(c: u32) -> u32 {
    return atomicLoad(&cell_offsets[c]);
}

@compute @workgroup_size(64)
fn neighbours_bin(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let p = linear_index(gid, nwg, WORKGROUP);
    if p >= grid_params.n_particles {
        return;
    }
    let c = cell_id(cell_coords(rest(p)));
    particle_cell[p] = c;
    atomicAdd(&cell_offsets[c], 1u);
}

@compute @workgroup_size(64)
fn neighbours_place(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let p = linear_index(gid, nwg, WORKGROUP);
    if p >= grid_params.n_particles {
        return;
    }
    let c = particle_cell[p];
    cell_particles[cell_start(c) + atomicAdd(&cell_fill[c], 1u)] = p;
}

@compute @workgroup_size(64)
fn neighbours_sort(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let c = linear_index(gid, nwg, WORKGROUP);
    if c >= grid_params.n_cells {
        return;
    }
    let start = cell_start(c);
    let end = cell_start(c + 1u);
    for (var i = start + 1u; i < end; i++) {
        let v = cell_particles[i];
        var j = i;
        while j > start && cell_particles[j - 1u] > v {
            cell_particles[j] = cell_particles[j - 1u];
            j -= 1u;
        }
        cell_particles[j] = v;
    }
}

// Count the neighbours of p (the same loop as fill_neighbours, which cannot share it: a
// function that writes `neighbours` would make every entry point that calls it bind it, and
// the list is only sized after counting).
fn count_neighbours(p: u32) -> u32 {
    let x = rest(p);
    let c0 = cell_coords(x);
    let r2 = grid_params.support * grid_params.support;
    var k = 0u;
    for (var dz = -1; dz <= 1; dz++) {
        for (var dy = -1; dy <= 1; dy++) {
            for (var dx = -1; dx <= 1; dx++) {
                let c = c0 + vec3<i32>(dx, dy, dz);
                if !in_grid(c) {
                    continue;
                }
                let id = cell_id(c);
                for (var s = cell_start(id); s < cell_start(id + 1u); s++) {
                    let b = cell_particles[s];
                    let d = rest(b) - x;
                    if b != p && dot(d, d) < r2 {
                        k += 1u;
                    }
                }
            }
        }
    }
    return k;
}

// Write the neighbours of p from `base` in the fixed order (cells z, y, x, then particles).
fn fill_neighbours(p: u32, base: u32) {
    let x = rest(p);
    let c0 = cell_coords(x);
    let r2 = grid_params.support * grid_params.support;
    var k = base;
    for (var dz = -1; dz <= 1; dz++) {
        for (var dy = -1; dy <= 1; dy++) {
            for (var dx = -1; dx <= 1; dx++) {
                let c = c0 + vec3<i32>(dx, dy, dz);
                if !in_grid(c) {
                    continue;
                }
                let id = cell_id(c);
                for (var s = cell_start(id); s < cell_start(id + 1u); s++) {
                    let b = cell_particles[s];
                    let d = rest(b) - x;
                    if b != p && dot(d, d) < r2 {
                        neighbours[k] = b;
                        k += 1u;
                    }
                }
            }
        }
    }
}

@compute @workgroup_size(64)
fn neighbours_count(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let p = linear_index(gid, nwg, WORKGROUP);
    if p >= grid_params.n_particles {
        return;
    }
    neighbour_offsets[p] = count_neighbours(p);
}

@compute @workgroup_size(64)
fn neighbours_fill(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let p = linear_index(gid, nwg, WORKGROUP);
    if p >= grid_params.n_particles {
        return;
    }
    fill_neighbours(p, neighbour_offsets[p]);
}
