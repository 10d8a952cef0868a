// Stage (every particle sub-step; indirect over the dynamic set D): symplectic Euler for the
// dynamic particles with the particle sub-step (paper eq. 12), the per-particle work of
// shared/integrate_particle.wgsl, which gather.wgsl's `gather_coupled_integrate` also runs
// (the GPU records that one dispatch in place of this pass and gather_coupled's where the
// plan allows). CPU twin: src/cpu/integrate_particles.rs.
#import params
#import index
#import particles
#import integrate_particle

@group(0) @binding(0) var<uniform> params: StepParams;
@group(0) @binding(1) var<storage, read> particle_counts: array<u32>;
@group(0) @binding(2) var<storage, read> dynamic_list: array<u32>;

const WORKGROUP: u32 = 64u;

@compute @workgroup_size(64)
fn integrate_particles(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let k = linear_index(gid, nwg, WORKGROUP);
    if k >= particle_counts[0] {
        return;
    }
    integrate_particle(dynamic_list[k], params.damping, params.speed_limit, params.n_vertices);
}
