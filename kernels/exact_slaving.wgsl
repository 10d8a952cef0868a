// Design 8's slaved vertices (`particles.coupling = "exact"`): a vertex that carries no core
// mass is placed on the affine fit of its dynamic particles, x_V = sum_q s_q x_q, and passes
// its force to them as s_q f_V (sum s = 1 and x_V = sum s_q x_q keep sum f and sum x cross f).
// The slaving is uploaded as two CSRs (the model's under activation = "all", fixed for the run;
// under the tool, the CPU twin's after each activation that changes it, into lists sized for
// every vertex-particle slot): vertex -> (particle, s) (exact_fit_*) and
// particle -> (vertex, s) (exact_slave_*, vertices ascending). Entry points:
//   exact_slaving_transfer  per dynamic particle (indirect over the dynamic list):
//                           f_q += sum s f_V over the slaved vertices that fit it (before
//                           the step);
//   exact_slaving_place     per vertex, after the step: every vertex's offset clock advances
//                           by dt; a slaved vertex takes u_V = sum s_q u_q + (1 - t/b) c_V,
//                           v_V = sum s_q v_q - c_V / b while its offset c_V fades (t < b, the
//                           blend time b; c_V is set where an activation slaves a vertex off
//                           its fit, on the CPU) and its force is zeroed (it went to its
//                           particles);
//   exact_slaving_relump    per vertex, closing an activation: the slaving's lumped masses
//                           and inverse masses (-1 on slaved vertices: integrate moves them
//                           kinematically until they are placed), and the slaved vertices
//                           placed on their fit.
// CPU twins: Slaving::transfer_forces and Slaving::place (src/cpu/exact_coupling.rs) as the
// CPU stepper's ExactIntegrate and ActivateExact call them.
#import params
#import index
#import particles

@group(0) @binding(0) var<uniform> params: StepParams;
@group(0) @binding(1) var<storage, read> particle_counts: array<u32>;
@group(0) @binding(2) var<storage, read> dynamic_list: array<u32>;
@group(0) @binding(3) var<storage, read_write> forces: array<f32>;
@group(0) @binding(4) var<storage, read_write> particle_forces: array<f32>;
@group(0) @binding(5) var<storage, read_write> displacements: array<f32>;
@group(0) @binding(6) var<storage, read_write> velocities: array<f32>;
@group(0) @binding(7) var<storage, read> particle_displacements: array<f32>;
@group(0) @binding(8) var<storage, read> particle_velocities: array<f32>;
@group(0) @binding(9) var<storage, read> exact_fit_offsets: array<u32>;
@group(0) @binding(10) var<storage, read> exact_fit_particles: array<u32>;
@group(0) @binding(11) var<storage, read> exact_fit_weights: array<f32>;
@group(0) @binding(12) var<storage, read> exact_slave_offsets: array<u32>;
@group(0) @binding(13) var<storage, read> exact_slave_vertices: array<u32>;
@group(0) @binding(14) var<storage, read> exact_slave_weights: array<f32>;
@group(0) @binding(15) var<storage, read> exact_mass: array<f32>;
@group(0) @binding(16) var<storage, read> exact_inv_mass: array<f32>;
@group(0) @binding(17) var<storage, read_write> mass: array<f32>;
@group(0) @binding(18) var<storage, read_write> inv_mass: array<f32>;
@group(0) @binding(19) var<storage, read> exact_vertex_offset: array<f32>;
@group(0) @binding(20) var<storage, read_write> exact_vertex_timer: array<f32>;
@group(0) @binding(21) var<uniform> particle_params: ParticleParams;

const WORKGROUP: u32 = 64u;

fn store(which: u32, i: u32, v: vec3<f32>) {
    if which == 0u {
        displacements[3u * i] = v.x;
        displacements[3u * i + 1u] = v.y;
        displacements[3u * i + 2u] = v.z;
    } else if which == 1u {
        velocities[3u * i] = v.x;
        velocities[3u * i + 1u] = v.y;
        velocities[3u * i + 2u] = v.z;
    } else {
        forces[3u * i] = v.x;
        forces[3u * i + 1u] = v.y;
        forces[3u * i + 2u] = v.z;
    }
}

// Place slaved vertex i (one with a fit) on its particles, u and v, plus what is left of its
// offset after t seconds of fading (the twin's place_slaved, SlaveOffsets::left and rate).
fn place(i: u32, t: f32) {
    var u = vec3<f32>(0.0);
    var v = vec3<f32>(0.0);
    for (var k = exact_fit_offsets[i]; k < exact_fit_offsets[i + 1u]; k++) {
        let q = exact_fit_particles[k];
        let s = exact_fit_weights[k];
        u += vec3<f32>(particle_displacements[3u * q], particle_displacements[3u * q + 1u], particle_displacements[3u * q + 2u]) * s;
        v += vec3<f32>(particle_velocities[3u * q], particle_velocities[3u * q + 1u], particle_velocities[3u * q + 2u]) * s;
    }
    let b = particle_params.blend;
    let c = vec3<f32>(exact_vertex_offset[3u * i], exact_vertex_offset[3u * i + 1u], exact_vertex_offset[3u * i + 2u]);
    var fade = 0.0;
    if b > 0.0 {
        fade = max(1.0 - t / b, 0.0);
    }
    let left = c * fade;
    if any(left != vec3<f32>(0.0)) {
        u = u + left;
        if t < b {
            v = v + (-c / b);
        }
    }
    store(0u, i, u);
    store(1u, i, v);
}

@compute @workgroup_size(64)
fn exact_slaving_transfer(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let k = linear_index(gid, nwg, WORKGROUP);
    if k >= particle_counts[0] {
        return;
    }
    let q = dynamic_list[k];
    var f = vec3<f32>(particle_forces[3u * q], particle_forces[3u * q + 1u], particle_forces[3u * q + 2u]);
    for (var j = exact_slave_offsets[q]; j < exact_slave_offsets[q + 1u]; j++) {
        let v = exact_slave_vertices[j];
        f += vec3<f32>(forces[3u * v], forces[3u * v + 1u], forces[3u * v + 2u]) * exact_slave_weights[j];
    }
    particle_forces[3u * q] = f.x;
    particle_forces[3u * q + 1u] = f.y;
    particle_forces[3u * q + 2u] = f.z;
}

@compute @workgroup_size(64)
fn exact_slaving_place(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_index(gid, nwg, WORKGROUP);
    if i >= params.n_vertices {
        return;
    }
    let t = exact_vertex_timer[i] + params.dt;
    exact_vertex_timer[i] = t;
    if exact_fit_offsets[i + 1u] == exact_fit_offsets[i] {
        return;
    }
    place(i, t);
    store(2u, i, vec3<f32>(0.0));
}

@compute @workgroup_size(64)
fn exact_slaving_relump(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_index(gid, nwg, WORKGROUP);
    if i >= params.n_vertices {
        return;
    }
    mass[i] = exact_mass[i];
    inv_mass[i] = exact_inv_mass[i];
    if exact_fit_offsets[i + 1u] != exact_fit_offsets[i] {
        place(i, exact_vertex_timer[i]);
    }
}
