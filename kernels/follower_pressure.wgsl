// Follower pressure (a load on the deformed surface, as in the Land et al. 2015 benchmark):
// per loaded face (a, b, c), oriented with its normal out of the body, at the current
// positions x = X + u: each corner gets f = -s p_face (x_b - x_a) x (x_c - x_a) / 6, i.e.
// -s p A n / 3 (s = load_factor, the ramp). Written to per-face-corner slots face*3 + corner;
// follower_pressure_gather.wgsl sums them per vertex (no float atomics).
// CPU twin: src/cpu/follower_pressure.rs.
#import index

// Mirrors src/cpu/follower_pressure.rs `FollowerLoad` (a test checks the layout).
struct FollowerLoad {
    n_faces: u32,
    load_factor: f32,   // ramp in [0, 1], set per batch: min(t / t_ramp, 1)
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> follower_load: FollowerLoad;
@group(0) @binding(1) var<storage, read> rest_positions: array<f32>;
@group(0) @binding(2) var<storage, read> displacements: array<f32>;
@group(0) @binding(3) var<storage, read> follower_faces: array<u32>;
@group(0) @binding(4) var<storage, read> follower_face_pressure: array<f32>;
@group(0) @binding(5) var<storage, read_write> follower_corner_forces: array<f32>;

const WORKGROUP: u32 = 64u;

fn rest_position(i: u32) -> vec3<f32> {
    return vec3<f32>(rest_positions[3u * i], rest_positions[3u * i + 1u], rest_positions[3u * i + 2u]);
}

fn displacement(i: u32) -> vec3<f32> {
    return vec3<f32>(displacements[3u * i], displacements[3u * i + 1u], displacements[3u * i + 2u]);
}

fn store_corner(c: u32, f: vec3<f32>) {
    follower_corner_forces[3u * c] = f.x;
    follower_corner_forces[3u * c + 1u] = f.y;
    follower_corner_forces[3u * c + 2u] = f.z;
}

@compute @workgroup_size(64)
fn follower_pressure(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_index(gid, nwg, WORKGROUP);
    if i >= follower_load.n_faces {
        return;
    }
    let a = follower_faces[3u * i];
    let b = follower_faces[3u * i + 1u];
    let c = follower_faces[3u * i + 2u];
    let xa = rest_position(a);
    let ua = displacement(a);
    let e1 = (rest_position(b) - xa) + (displacement(b) - ua);
    let e2 = (rest_position(c) - xa) + (displacement(c) - ua);
    let p = follower_load.load_factor * follower_face_pressure[i];
    let f = cross(e1, e2) * (-p / 6.0);
    store_corner(3u * i, f);
    store_corner(3u * i + 1u, f);
    store_corner(3u * i + 2u, f);
}
