// integrate_particles.wgsl's work for one dynamic particle p, shared by
// integrate_particles.wgsl's `integrate_particles` and gather.wgsl's
// `gather_coupled_integrate`: symplectic Euler with the particle sub-step (paper eq. 12),
// v <- (v + dt_s f/m)/(1 + alpha dt_s), u <- u + dt_s v; status[0] <- min(status[0],
// n_vertices + p) when a value is not finite or |v| is above the speed limit (particles are
// numbered after the vertices). The caller passes the step's alpha, speed limit and vertex
// count (its StepParams); the arrays are declared here (bound by name, like every kernel's).
#import index
#import particles

@group(0) @binding(56) var<uniform> particle_params: ParticleParams;
@group(0) @binding(57) var<storage, read> particle_forces: array<f32>;
@group(0) @binding(58) var<storage, read_write> particle_displacements: array<f32>;
@group(0) @binding(59) var<storage, read_write> particle_velocities: array<f32>;
@group(0) @binding(60) var<storage, read_write> status: array<atomic<u32>>;

fn integrate_particle(p: u32, damping: f32, speed_limit: f32, n_vertices: u32) {
    let dt = particle_params.sub_dt;
    let f = vec3<f32>(particle_forces[3u * p], particle_forces[3u * p + 1u], particle_forces[3u * p + 2u]);
    var v = vec3<f32>(particle_velocities[3u * p], particle_velocities[3u * p + 1u], particle_velocities[3u * p + 2u]);
    var u = vec3<f32>(particle_displacements[3u * p], particle_displacements[3u * p + 1u], particle_displacements[3u * p + 2u]);
    v = (v + f * (dt / particle_params.mass)) / (1.0 + damping * dt);
    u += v * dt;
    particle_velocities[3u * p] = v.x;
    particle_velocities[3u * p + 1u] = v.y;
    particle_velocities[3u * p + 2u] = v.z;
    particle_displacements[3u * p] = u.x;
    particle_displacements[3u * p + 1u] = u.y;
    particle_displacements[3u * p + 2u] = u.z;
    if !(finite3(u) && finite3(v)) || dot(v, v) > speed_limit * speed_limit {
        atomicMin(&status[0], n_vertices + p);
    }
}
