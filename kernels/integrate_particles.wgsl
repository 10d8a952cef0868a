// Stage (every particle sub-step; indirect over the dynamic set D): symplectic Euler for the
// dynamic particles with the particle sub-step (paper eq. 12): v <- (v + dt_s f/m)/(1 +
// alpha dt_s), u <- u + dt_s v; status[0] <- min(status[0], n_vertices + p) when a value is
// not finite or |v| is above the speed limit (particles are numbered after the vertices).
// CPU twin: src/cpu/integrate_particles.rs.
#import params
#import index
#import particles

@group(0) @binding(0) var<uniform> params: StepParams;
@group(0) @binding(1) var<uniform> particle_params: ParticleParams;
@group(0) @binding(2) var<storage, read> particle_counts: array<u32>;
@group(0) @binding(3) var<storage, read> dynamic_list: array<u32>;
@group(0) @binding(4) var<storage, read> particle_forces: array<f32>;
@group(0) @binding(5) var<storage, read_write> particle_displacements: array<f32>;
@group(0) @binding(6) var<storage, read_write> particle_velocities: array<f32>;
@group(0) @binding(7) var<storage, read_write> status: array<atomic<u32>>;

const WORKGROUP: u32 = 64u;

@compute @workgroup_size(64)
fn integrate_particles(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let k = linear_index(gid, nwg, WORKGROUP);
    if k >= particle_counts[0] {
        return;
    }
    let p = dynamic_list[k];
    let dt = particle_params.sub_dt;
    let f = vec3<f32>(particle_forces[3u * p], particle_forces[3u * p + 1u], particle_forces[3u * p + 2u]);
    var v = vec3<f32>(particle_velocities[3u * p], particle_velocities[3u * p + 1u], particle_velocities[3u * p + 2u]);
    var u = vec3<f32>(particle_displacements[3u * p], particle_displacements[3u * p + 1u], particle_displacements[3u * p + 2u]);
    v = (v + f * (dt / particle_params.mass)) / (1.0 + params.damping * dt);
    u += v * dt;
    particle_velocities[3u * p] = v.x;
    particle_velocities[3u * p + 1u] = v.y;
    particle_velocities[3u * p + 2u] = v.z;
    particle_displacements[3u * p] = u.x;
    particle_displacements[3u * p + 1u] = u.y;
    particle_displacements[3u * p + 2u] = u.z;
    if !(finite3(u) && finite3(v)) || dot(v, v) > params.speed_limit * params.speed_limit {
        atomicMin(&status[0], params.n_vertices + p);
    }
}
