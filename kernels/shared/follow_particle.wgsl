// follow.wgsl's work for one particle, shared by follow.wgsl's `follow` and fem_forces.wgsl's
// `fem_forces_follow`: particle p of the force set F, when embedded (not dynamic), takes
// u_p = sum w_i u_i of its host tet's vertices (their displacements u_host, which the caller
// loads: `follow_embedded(p)` says whether to), plus the fading offset of a particle
// blending back, offset * (1 - t/blend) (its timer t first advanced by a sub-step). The
// arrays it reads and writes are declared here (bound by name, like every kernel's).
#import particles

@group(0) @binding(48) var<uniform> particle_params: ParticleParams;
@group(0) @binding(49) var<storage, read> particle_mode: array<u32>;
@group(0) @binding(50) var<storage, read> particle_host: array<u32>;
@group(0) @binding(51) var<storage, read> particle_weights: array<f32>;
@group(0) @binding(52) var<storage, read_write> particle_timer: array<f32>;
@group(0) @binding(53) var<storage, read> particle_offset: array<f32>;
@group(0) @binding(54) var<storage, read_write> particle_displacements: array<f32>;
@group(0) @binding(55) var<storage, read_write> particle_velocities: array<f32>;

// True when particle p is embedded (it follows its host tet, particle_host[p]).
fn follow_embedded(p: u32) -> bool {
    return (particle_mode[p] & MODE_DYNAMIC) == 0u;
}

// Place embedded particle p from its host's corner displacements u_host.
fn follow_particle(p: u32, u_host: array<vec3<f32>, 4>) {
    let w = 4u * p;
    var u = u_host[0] * particle_weights[w] + u_host[1] * particle_weights[w + 1u]
        + u_host[2] * particle_weights[w + 2u] + u_host[3] * particle_weights[w + 3u];
    if (particle_mode[p] & MODE_BLENDING) != 0u {
        let timer = particle_timer[p] + particle_params.sub_dt;
        particle_timer[p] = timer;
        let b = max(0.0, 1.0 - timer / max(particle_params.blend, 1e-30));
        u += vec3<f32>(particle_offset[3u * p], particle_offset[3u * p + 1u], particle_offset[3u * p + 2u]) * b;
    }
    particle_displacements[3u * p] = u.x;
    particle_displacements[3u * p + 1u] = u.y;
    particle_displacements[3u * p + 2u] = u.z;
}

// Give embedded particle p its host's velocity from the corner velocities v_host,
// v_p = sum w_i v_i, plus the rate of a blending particle's fading offset, -offset/blend
// while it fades (call after follow_particle, which advances the timer). For the viscous
// stress (sph_stress with VISCOUS): callers call it only then.
fn follow_particle_velocity(p: u32, v_host: array<vec3<f32>, 4>) {
    let w = 4u * p;
    var v = v_host[0] * particle_weights[w] + v_host[1] * particle_weights[w + 1u]
        + v_host[2] * particle_weights[w + 2u] + v_host[3] * particle_weights[w + 3u];
    if (particle_mode[p] & MODE_BLENDING) != 0u {
        let b = 1.0 - particle_timer[p] / max(particle_params.blend, 1e-30);
        if b > 0.0 {
            v -= vec3<f32>(particle_offset[3u * p], particle_offset[3u * p + 1u], particle_offset[3u * p + 2u]) / max(particle_params.blend, 1e-30);
        }
    }
    particle_velocities[3u * p] = v.x;
    particle_velocities[3u * p + 1u] = v.y;
    particle_velocities[3u * p + 2u] = v.z;
}
