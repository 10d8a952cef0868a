// Stage 6: symplectic Euler (paper eq. 12): v <- (v + dt f/m) / (1 + alpha dt), x <- x + dt v.
// Fixed vertices have inverse mass 0 and keep v = 0. Kinetic damping zeroes v after a
// kinetic-energy peak. status[0] <- min(status[0], i) when x or v is not finite.
// CPU twin: src/cpu/integrate.rs.
#import params
#import index

@group(0) @binding(0) var<uniform> params: StepParams;
@group(0) @binding(1) var<storage, read> forces: array<f32>;
@group(0) @binding(2) var<storage, read> inv_mass: array<f32>;
@group(0) @binding(3) var<storage, read_write> positions: array<f32>;
@group(0) @binding(4) var<storage, read_write> velocities: array<f32>;
@group(0) @binding(5) var<storage, read> stats: array<f32>;
@group(0) @binding(6) var<storage, read_write> status: array<atomic<u32>>;

const WORKGROUP: u32 = 64u;

@compute @workgroup_size(64)
fn integrate(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_index(gid, nwg, WORKGROUP);
    if i >= params.n_vertices {
        return;
    }
    let reset = params.kinetic_damping != 0u && stats[STAT_RESET_VELOCITY] > 0.5;
    let w = inv_mass[i];
    var v = vec3<f32>(velocities[3u * i], velocities[3u * i + 1u], velocities[3u * i + 2u]);
    if reset {
        v = vec3<f32>(0.0);
    }
    var x = vec3<f32>(positions[3u * i], positions[3u * i + 1u], positions[3u * i + 2u]);
    if w > 0.0 {
        let f = vec3<f32>(forces[3u * i], forces[3u * i + 1u], forces[3u * i + 2u]);
        v = (v + f * (params.dt * w)) / (1.0 + params.damping * params.dt);
        x += v * params.dt;
    } else {
        v = vec3<f32>(0.0);
    }
    velocities[3u * i] = v.x;
    velocities[3u * i + 1u] = v.y;
    velocities[3u * i + 2u] = v.z;
    positions[3u * i] = x.x;
    positions[3u * i + 1u] = x.y;
    positions[3u * i + 2u] = x.z;
    if !(finite3(x) && finite3(v)) {
        atomicMin(&status[0], i);
    }
}
