// Stage: symplectic Euler (paper eq. 12): v <- (v + dt f/m) / (1 + alpha dt), u <- u + dt v
// (the state is the displacement u = x - X).
// Fixed vertices have inverse mass 0 and keep v = 0. A negative inverse mass marks a vertex
// left without mass by dynamic particles: it moves kinematically, u <- u + dt v, with the
// velocity activate_relump gave it.
// status[0] <- min(status[0], i) when u or v is not finite or |v| exceeds the speed limit
// (an instability caught long before it overflows to Inf/NaN).
// CPU twin: src/cpu/integrate.rs.
#import params
#import index

@group(0) @binding(0) var<uniform> params: StepParams;
@group(0) @binding(1) var<storage, read> forces: array<f32>;
@group(0) @binding(2) var<storage, read> inv_mass: array<f32>;
@group(0) @binding(3) var<storage, read_write> displacements: array<f32>;
@group(0) @binding(4) var<storage, read_write> velocities: array<f32>;
@group(0) @binding(5) var<storage, read_write> status: array<atomic<u32>>;

const WORKGROUP: u32 = 64u;

@compute @workgroup_size(64)
fn integrate(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_index(gid, nwg, WORKGROUP);
    if i >= params.n_vertices {
        return;
    }
    let w = inv_mass[i];
    var v = vec3<f32>(velocities[3u * i], velocities[3u * i + 1u], velocities[3u * i + 2u]);
    var x = vec3<f32>(displacements[3u * i], displacements[3u * i + 1u], displacements[3u * i + 2u]);
    if w > 0.0 {
        let f = vec3<f32>(forces[3u * i], forces[3u * i + 1u], forces[3u * i + 2u]);
        v = (v + f * (params.dt * w)) / (1.0 + params.damping * params.dt);
        x += v * params.dt;
    } else if w < 0.0 {
        x += v * params.dt;
    } else {
        v = vec3<f32>(0.0);
    }
    velocities[3u * i] = v.x;
    velocities[3u * i + 1u] = v.y;
    velocities[3u * i + 2u] = v.z;
    displacements[3u * i] = x.x;
    displacements[3u * i + 1u] = x.y;
    displacements[3u * i + 2u] = x.z;
    if !(finite3(x) && finite3(v)) || dot(v, v) > params.speed_limit * params.speed_limit {
        atomicMin(&status[0], i);
    }
}
