// Stage (every particle sub-step; indirect over the force set F): embedded particles that
// take part in the SPH sums follow their host, u_p = sum w_i u_i (+ the fading offset of a
// particle blending back, offset * (1 - t/blend), its timer t first advanced by a sub-step:
// the offset fades step by step, and the activation adds nothing for the interval to a
// particle that was in F); with VISCOUS also v_p = sum w_i v_i (+ the offset's rate), which
// sph_stress's viscous stress reads. Dynamic particles are left alone. The per-particle work is
// shared/follow_particle.wgsl, which fem_forces.wgsl's `fem_forces_follow` also runs (the GPU
// records that one dispatch in place of this pass and fem_forces' where the plan allows).
// CPU twin: src/cpu/follow.rs.
#import index
#import particles
#import follow_particle

@group(0) @binding(0) var<storage, read> particle_counts: array<u32>;
@group(0) @binding(1) var<storage, read> force_list: array<u32>;
@group(0) @binding(2) var<storage, read> tets: array<vec4<u32>>;
@group(0) @binding(3) var<storage, read> displacements: array<f32>;
@group(0) @binding(4) var<storage, read> velocities: array<f32>;

// Pipeline constant: the material is viscous, so sph_stress reads the embedded particles'
// velocities too (follow_particle_velocity).
override VISCOUS: bool = false;

const WORKGROUP: u32 = 64u;

fn node_u(i: u32) -> vec3<f32> {
    return vec3<f32>(displacements[3u * i], displacements[3u * i + 1u], displacements[3u * i + 2u]);
}

fn node_v(i: u32) -> vec3<f32> {
    return vec3<f32>(velocities[3u * i], velocities[3u * i + 1u], velocities[3u * i + 2u]);
}

@compute @workgroup_size(64)
fn follow(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let k = linear_index(gid, nwg, WORKGROUP);
    if k >= particle_counts[2] {
        return;
    }
    let p = force_list[k];
    if follow_embedded(p) {
        let t = tets[particle_host[p]];
        follow_particle(p, array<vec3<f32>, 4>(node_u(t.x), node_u(t.y), node_u(t.z), node_u(t.w)));
        if VISCOUS {
            follow_particle_velocity(p, array<vec3<f32>, 4>(node_v(t.x), node_v(t.y), node_v(t.z), node_v(t.w)));
        }
    }
}
