// Stage (every particle sub-step; indirect over the force set F): embedded particles that
// take part in the SPH sums follow their host, u_p = sum w_i u_i (+ the fading offset of a
// particle blending back, offset * (1 - t/blend), its timer t first advanced by a sub-step:
// the offset fades step by step, and the activation adds nothing for the interval to a
// particle that was in F). Dynamic particles are left alone.
// CPU twin: src/cpu/follow.rs.
#import index
#import particles

@group(0) @binding(0) var<uniform> particle_params: ParticleParams;
@group(0) @binding(1) var<storage, read> particle_counts: array<u32>;
@group(0) @binding(2) var<storage, read> force_list: array<u32>;
@group(0) @binding(3) var<storage, read> particle_mode: array<u32>;
@group(0) @binding(4) var<storage, read> particle_host: array<u32>;
@group(0) @binding(5) var<storage, read> particle_weights: array<f32>;
@group(0) @binding(6) var<storage, read> tets: array<vec4<u32>>;
@group(0) @binding(7) var<storage, read> displacements: array<f32>;
@group(0) @binding(8) var<storage, read_write> particle_timer: array<f32>;
@group(0) @binding(9) var<storage, read> particle_offset: array<f32>;
@group(0) @binding(10) var<storage, read_write> particle_displacements: array<f32>;

const WORKGROUP: u32 = 64u;

fn node_u(i: u32) -> vec3<f32> {
    return vec3<f32>(displacements[3u * i], displacements[3u * i + 1u], displacements[3u * i + 2u]);
}

@compute @workgroup_size(64)
fn follow(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let k = linear_index(gid, nwg, WORKGROUP);
    if k >= particle_counts[2] {
        return;
    }
    let p = force_list[k];
    let mode = particle_mode[p];
    if (mode & MODE_DYNAMIC) != 0u {
        return;
    }
    let t = tets[particle_host[p]];
    let w = 4u * p;
    var u = node_u(t.x) * particle_weights[w] + node_u(t.y) * particle_weights[w + 1u]
        + node_u(t.z) * particle_weights[w + 2u] + node_u(t.w) * particle_weights[w + 3u];
    if (mode & MODE_BLENDING) != 0u {
        let timer = particle_timer[p] + particle_params.sub_dt;
        particle_timer[p] = timer;
        let b = max(0.0, 1.0 - timer / max(particle_params.blend, 1e-30));
        u += vec3<f32>(particle_offset[3u * p], particle_offset[3u * p + 1u], particle_offset[3u * p + 2u]) * b;
    }
    particle_displacements[3u * p] = u.x;
    particle_displacements[3u * p + 1u] = u.y;
    particle_displacements[3u * p + 2u] = u.z;
}
