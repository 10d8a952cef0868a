// Stage 1: per tet, element forces (paper eq. 1-6) for the scene's material.
// The state is the displacement u = x - X (finer f32 resolution than positions):
// H = Du Dm^-1, F = I + H; P = first Piola-Kirchhoff stress of the material
// (MATERIAL 0: St. Venant-Kirchhoff, 1: stable Neo-Hookean, 2: corotational; shared with
// the particles in shared/material.wgsl, formulas in src/material.rs), plus the viscous F S_v, S_v = phi tr(Edot) I + 2 psi Edot,
// Edot = (Fdot^T F + F^T Fdot)/2, Fdot = Dv Dm^-1 (eq. 3-4);
// corner forces [f1 f2 f3] = -V P Dm^-T, f0 = -(f1 + f2 + f3); energy V Psi.
// The volume/shape split laws (MATERIAL 3-6) run in fem_forces_split.wgsl instead.
// `fem_forces_follow` does the same per tet and, on the same grid, follow.wgsl's work over
// the particles' force set F (a grid-stride loop: thread t takes list entries t, t + T, …, T
// the grid's threads; the host grows the grid so that it takes at most MAX_RIDER_ROUNDS:
// Domain::CoveringParticles): the two read the vertex displacements and write disjoint arrays, so
// the GPU records this one dispatch in place of the follow and fem_forces passes when the
// plan allows (`StepPlan::gpu_fusions`).
// CPU twin: src/cpu/fem_forces.rs (and src/cpu/follow.rs).
#import params
#import index
#import material
#import follow_particle

@group(0) @binding(0) var<uniform> params: StepParams;
@group(0) @binding(1) var<storage, read> displacements: array<f32>;
@group(0) @binding(2) var<storage, read> velocities: array<f32>;
@group(0) @binding(3) var<storage, read> tets: array<vec4<u32>>;
@group(0) @binding(4) var<storage, read> dm_inv: array<f32>;
@group(0) @binding(5) var<storage, read> rest_volume: array<f32>;
@group(0) @binding(6) var<storage, read_write> corner_forces: array<f32>;
@group(0) @binding(7) var<storage, read_write> tet_energy: array<f32>;
@group(0) @binding(8) var<storage, read> tet_weight: array<f32>;
// fem_forces_follow's list of the force set (the other follow arrays are
// shared/follow_particle.wgsl's).
@group(0) @binding(9) var<storage, read> particle_counts: array<u32>;
@group(0) @binding(10) var<storage, read> force_list: array<u32>;

// Pipeline constants: the material model, and whether the viscous terms are compiled in.
override MATERIAL: u32 = 0u;
override VISCOUS: bool = true;
// With particles, each tet keeps the fraction tet_weight[e] = 1 - phi_e of its energy (the
// rest is carried by the particles in it that bear SPH stress).
override PARTICLES: bool = false;

const WORKGROUP: u32 = 64u;

fn displacement(i: u32) -> vec3<f32> {
    return vec3<f32>(displacements[3u * i], displacements[3u * i + 1u], displacements[3u * i + 2u]);
}

fn velocity(i: u32) -> vec3<f32> {
    return vec3<f32>(velocities[3u * i], velocities[3u * i + 1u], velocities[3u * i + 2u]);
}

fn store_corner(c: u32, f: vec3<f32>) {
    corner_forces[3u * c] = f.x;
    corner_forces[3u * c + 1u] = f.y;
    corner_forces[3u * c + 2u] = f.z;
}

@compute @workgroup_size(64)
fn fem_forces(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let e = linear_index(gid, nwg, WORKGROUP);
    if e < params.n_tets {
        tet_forces(e);
    }
}

@compute @workgroup_size(64)
fn fem_forces_follow(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let e = linear_index(gid, nwg, WORKGROUP);
    if e < params.n_tets {
        tet_forces(e);
    }
    let threads = nwg.x * nwg.y * WORKGROUP;
    let n = particle_counts[2];
    for (var k = e; k < n; k += threads) {
        let p = force_list[k];
        if follow_embedded(p) {
            let h = tets[particle_host[p]];
            follow_particle(p, array<vec3<f32>, 4>(displacement(h.x), displacement(h.y), displacement(h.z), displacement(h.w)));
            if VISCOUS {
                follow_particle_velocity(p, array<vec3<f32>, 4>(velocity(h.x), velocity(h.y), velocity(h.z), velocity(h.w)));
            }
        }
    }
}

// Tet e's corner forces and energy.
fn tet_forces(e: u32) {
    let t = tets[e];
    let u0 = displacement(t.x);
    let du = mat3x3<f32>(displacement(t.y) - u0, displacement(t.z) - u0, displacement(t.w) - u0);
    let b = 9u * e;
    let dmi = mat3x3<f32>(
        vec3<f32>(dm_inv[b], dm_inv[b + 1u], dm_inv[b + 2u]),
        vec3<f32>(dm_inv[b + 3u], dm_inv[b + 4u], dm_inv[b + 5u]),
        vec3<f32>(dm_inv[b + 6u], dm_inv[b + 7u], dm_inv[b + 8u]),
    );
    let volume = rest_volume[e];
    let h = du * dmi;
    let se = material_stress_energy(MATERIAL, h, params.lambda, params.mu);
    var p = se.p;
    if VISCOUS {
        let f = identity3() + h;
        let v0 = velocity(t.x);
        let dv = mat3x3<f32>(velocity(t.y) - v0, velocity(t.z) - v0, velocity(t.w) - v0);
        let f_dot = dv * dmi;
        let rate = (transpose(f_dot) * f + transpose(f) * f_dot) * 0.5;
        p = p + f * (identity3() * (params.phi * trace3(rate)) + rate * (2.0 * params.psi));
    }
    var weight = 1.0;
    if PARTICLES {
        weight = tet_weight[e];
    }
    let g = p * transpose(dmi) * (-volume * weight);
    store_corner(4u * e, -(g[0] + g[1] + g[2]));
    store_corner(4u * e + 1u, g[0]);
    store_corner(4u * e + 2u, g[1]);
    store_corner(4u * e + 3u, g[2]);
    tet_energy[e] = volume * weight * se.psi;
}
