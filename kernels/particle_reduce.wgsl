// Stage (last step of a batch): the particles' diagnostics, a two-level tree reduction like
// reduce.wgsl over the stress list S of the last activation (which holds every particle then
// dynamic; the modes are checked too, though the activation writes both and a checkpoint
// saves both): kinetic energy of dynamic particles, SPH strain energy of particles in S,
// largest dynamic speed, sum |f|^2 over dynamic particles, sum m |u|^2 over dynamic
// particles and the largest stiffening kappa = max(|F|^2, |cof F|^2)/3 of a particle in S or
// dynamic, F = I + H from the last sub-step's sph_stress (src/substeps.rs adapts the particle
// sub-steps to it) -> particle_stats.
// particle_reduce_partial runs indirect over S's arguments (64-thread workgroups, so up to 4x
// the 256-entry blocks needed run; those past the buffer's blocks write nothing);
// particle_reduce_final combines the ceil(|S|/256) blocks. CPU twin: src/cpu/particle_reduce.rs.
#import index
#import particles

@group(0) @binding(0) var<uniform> particle_params: ParticleParams;
@group(0) @binding(1) var<storage, read> particle_mode: array<u32>;
@group(0) @binding(2) var<storage, read> particle_displacements: array<f32>;
@group(0) @binding(3) var<storage, read> particle_velocities: array<f32>;
@group(0) @binding(4) var<storage, read> particle_forces: array<f32>;
@group(0) @binding(5) var<storage, read> particle_energy: array<f32>;
@group(0) @binding(6) var<storage, read_write> particle_partials: array<f32>;
@group(0) @binding(7) var<storage, read_write> particle_stats: array<f32>;
@group(0) @binding(8) var<storage, read> particle_counts: array<u32>;
@group(0) @binding(9) var<storage, read> stress_list: array<u32>;
@group(0) @binding(10) var<storage, read> particle_gradient: array<f32>;

const WORKGROUP: u32 = 256u;
const LANE: u32 = 6u;

var<workgroup> lanes: array<array<f32, 6>, 256>;

// kappa = max(1, I1/3, I2/3) of C = F^T F, F = I + H_p (H_p column-major at 9p): as
// substeps::stiffening.
fn stiffening(p: u32) -> f32 {
    let b = 9u * p;
    let f = mat3x3<f32>(
        vec3<f32>(1.0 + particle_gradient[b], particle_gradient[b + 1u], particle_gradient[b + 2u]),
        vec3<f32>(particle_gradient[b + 3u], 1.0 + particle_gradient[b + 4u], particle_gradient[b + 5u]),
        vec3<f32>(particle_gradient[b + 6u], particle_gradient[b + 7u], 1.0 + particle_gradient[b + 8u]),
    );
    let c = transpose(f) * f;
    let i1 = c[0][0] + c[1][1] + c[2][2];
    let c2 = c * c;
    let i2 = 0.5 * (i1 * i1 - (c2[0][0] + c2[1][1] + c2[2][2]));
    return max(max(i1, i2) / 3.0, 1.0);
}

fn combine(l: u32, o: u32) {
    lanes[l][0] += lanes[o][0];
    lanes[l][1] += lanes[o][1];
    lanes[l][2] = max(lanes[l][2], lanes[o][2]);
    lanes[l][3] += lanes[o][3];
    lanes[l][4] += lanes[o][4];
    lanes[l][5] = max(lanes[l][5], lanes[o][5]);
}

fn tree(l: u32) {
    for (var s = WORKGROUP / 2u; s > 0u; s = s / 2u) {
        workgroupBarrier();
        if l < s {
            combine(l, l + s);
        }
    }
    workgroupBarrier();
}

fn v3(a: u32, p: u32) -> vec3<f32> {
    if a == 0u {
        return vec3<f32>(particle_displacements[3u * p], particle_displacements[3u * p + 1u], particle_displacements[3u * p + 2u]);
    } else if a == 1u {
        return vec3<f32>(particle_velocities[3u * p], particle_velocities[3u * p + 1u], particle_velocities[3u * p + 2u]);
    }
    return vec3<f32>(particle_forces[3u * p], particle_forces[3u * p + 1u], particle_forces[3u * p + 2u]);
}

@compute @workgroup_size(256)
fn particle_reduce_partial(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) l: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
) {
    let s = linear_index(gid, nwg, WORKGROUP);
    var lane = array<f32, 6>(0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    if s < particle_counts[1] {
        let p = stress_list[s];
        let mode = particle_mode[p];
        let m = particle_params.mass;
        if (mode & MODE_DYNAMIC) != 0u {
            let v = v3(1u, p);
            lane[0] = 0.5 * m * dot(v, v);
            lane[2] = length(v);
            let f = v3(2u, p);
            lane[3] = dot(f, f);
            let u = v3(0u, p);
            lane[4] = m * dot(u, u);
        }
        if (mode & MODE_IN_S) != 0u {
            lane[1] = particle_energy[p];
        }
        if (mode & (MODE_DYNAMIC | MODE_IN_S)) != 0u {
            lane[5] = stiffening(p);
        }
    }
    lanes[l] = lane;
    tree(l);
    let block = wid.y * nwg.x + wid.x;
    if l == 0u && block < (particle_params.n_particles + WORKGROUP - 1u) / WORKGROUP {
        for (var k = 0u; k < LANE; k++) {
            particle_partials[LANE * block + k] = lanes[0][k];
        }
    }
}

@compute @workgroup_size(256)
fn particle_reduce_final(@builtin(local_invocation_index) l: u32) {
    let n = (particle_counts[1] + WORKGROUP - 1u) / WORKGROUP;
    var lane = array<f32, 6>(0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for (var k = l; k < n; k += WORKGROUP) {
        let b = LANE * k;
        lane[0] += particle_partials[b];
        lane[1] += particle_partials[b + 1u];
        lane[2] = max(lane[2], particle_partials[b + 2u]);
        lane[3] += particle_partials[b + 3u];
        lane[4] += particle_partials[b + 4u];
        lane[5] = max(lane[5], particle_partials[b + 5u]);
    }
    lanes[l] = lane;
    tree(l);
    if l == 0u {
        for (var k = 0u; k < LANE; k++) {
            particle_stats[k] = lanes[0][k];
        }
    }
}
