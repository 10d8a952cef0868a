// sph_stress.wgsl's work for one entry of the stress set S, shared by sph_stress.wgsl's
// `sph_stress` and contact.wgsl's `contact_sph_stress`: per particle p, the displacement
// gradient H_p = [sum_b V (u_b - u_p) (x) grad W(X_b - X_p)] G_p (exact for affine motion,
// see sph_setup), F = I + H, and
//   tlsph: P and Psi from the element stage's material law (shared/material.wgsl);
//   paper: the paper's eq. (1)-(2) stress with strain eps = F^T F - I (no 1/2), which is
//          S = lambda tr(E) I + 2 mu E for E = eps/2 doubled; Psi = mu E:E + lambda/2 tr(E)^2.
// With VISCOUS (the material's strain-rate viscosity, paper eq. 3-4, as fem_forces adds it),
// also Fdot_p = [sum_b V (v_b - v_p) (x) grad W(X_b - X_p)] G_p from the particles'
// velocities (follow gives the embedded ones their host's), Edot = (Fdot^T F + F^T Fdot)/2,
// and tlsph: P += F (phi tr(Edot) I + 2 psi Edot); paper: on its own strain's rate
// nu = 2 Edot, stress += phi tr(nu) I + 2 psi nu. Psi stays elastic.
// Writes A_p = P G_p^T (so that P g_pb = A_p grad W_pb), H_p (for the hourglass penalty) and
// V Psi. Each particle has SPH_STRESS_LANES threads of a 256-thread workgroup that takes 64
// entries: lane j sums the neighbours j, j + SPH_STRESS_LANES, ... and the lanes' sums are
// added in lane order.
// The arrays are declared here (bound by name); the Lame constants and viscosities come as
// arguments.
#import particles
#import material

@group(0) @binding(64) var<uniform> particle_params: ParticleParams;
@group(0) @binding(65) var<storage, read> particle_counts: array<u32>;
@group(0) @binding(66) var<storage, read> stress_list: array<u32>;
@group(0) @binding(67) var<storage, read> particle_rest: array<f32>;
@group(0) @binding(68) var<storage, read> particle_displacements: array<f32>;
@group(0) @binding(69) var<storage, read> neighbour_offsets: array<u32>;
@group(0) @binding(70) var<storage, read> neighbours: array<u32>;
@group(0) @binding(71) var<storage, read> particle_correction: array<f32>;
@group(0) @binding(72) var<storage, read_write> particle_stress: array<f32>;
@group(0) @binding(73) var<storage, read_write> particle_gradient: array<f32>;
@group(0) @binding(74) var<storage, read_write> particle_energy: array<f32>;
@group(0) @binding(75) var<storage, read> particle_velocities: array<f32>;

// Pipeline constants: the material law (as fem_forces' MATERIAL), and whether the viscous
// stress is compiled in (as fem_forces' VISCOUS).
override MATERIAL: u32 = 0u;
override VISCOUS: bool = false;

const SPH_STRESS_LANES: u32 = 4u;
// Entries of S a workgroup takes at a time (its 256 threads / SPH_STRESS_LANES).
const SPH_STRESS_ITEMS: u32 = 64u;

var<workgroup> lane_sums: array<mat3x3<f32>, 256>;

fn sph_rest(p: u32) -> vec3<f32> {
    return vec3<f32>(particle_rest[3u * p], particle_rest[3u * p + 1u], particle_rest[3u * p + 2u]);
}

fn sph_disp(p: u32) -> vec3<f32> {
    return vec3<f32>(particle_displacements[3u * p], particle_displacements[3u * p + 1u], particle_displacements[3u * p + 2u]);
}

fn sph_vel(p: u32) -> vec3<f32> {
    return vec3<f32>(particle_velocities[3u * p], particle_velocities[3u * p + 1u], particle_velocities[3u * p + 2u]);
}

fn sph_kernel_gradient(d: vec3<f32>) -> vec3<f32> {
    return model_kernel_gradient(particle_params.model, d, particle_params.spacing, particle_params.support);
}

fn store9(a: u32, p: u32, m: mat3x3<f32>) {
    for (var c = 0u; c < 3u; c++) {
        let v = m[c];
        if a == 0u {
            particle_stress[9u * p + 3u * c] = v.x;
            particle_stress[9u * p + 3u * c + 1u] = v.y;
            particle_stress[9u * p + 3u * c + 2u] = v.z;
        } else {
            particle_gradient[9u * p + 3u * c] = v.x;
            particle_gradient[9u * p + 3u * c + 1u] = v.y;
            particle_gradient[9u * p + 3u * c + 2u] = v.z;
        }
    }
}

// The sum over the lanes of the slot `slot` in `lane_sums`.
fn sph_lane_total(slot: u32) -> mat3x3<f32> {
    var s = lane_sums[slot];
    for (var j = 1u; j < SPH_STRESS_LANES; j++) {
        s += lane_sums[slot + j * SPH_STRESS_ITEMS];
    }
    return s;
}

// The stress of entry k of S (nothing where k is past its end) for Lame constants lambda and
// mu (and viscosities phi and psi with VISCOUS), by the thread `local` of the workgroup (lane local / 64 of slot local % 64). Every thread of the workgroup calls it, for
// the same 64 entries (it has workgroup barriers); a caller that calls it again must put a
// workgroup barrier between the calls (lane 0 reads `lane_sums` after the last).
fn sph_stress_entry(k: u32, local: u32, lambda: f32, mu: f32, phi: f32, psi: f32) {
    let slot = local % SPH_STRESS_ITEMS;
    let lane = local / SPH_STRESS_ITEMS;
    let live = k < particle_counts[1];
    var p = 0u;
    var mine = mat3x3<f32>(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0));
    var mine_rate = mat3x3<f32>(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0));
    if live {
        p = stress_list[k];
        let x = sph_rest(p);
        let up = sph_disp(p);
        var vp = vec3<f32>(0.0);
        if VISCOUS {
            vp = sph_vel(p);
        }
        for (var n = neighbour_offsets[p] + lane; n < neighbour_offsets[p + 1u]; n += SPH_STRESS_LANES) {
            let b = neighbours[n];
            let w = sph_kernel_gradient(sph_rest(b) - x) * particle_params.volume;
            let du = sph_disp(b) - up;
            mine += mat3x3<f32>(du * w.x, du * w.y, du * w.z);
            if VISCOUS {
                let dv = sph_vel(b) - vp;
                mine_rate += mat3x3<f32>(dv * w.x, dv * w.y, dv * w.z);
            }
        }
    }
    lane_sums[local] = mine;
    workgroupBarrier();
    var s = mat3x3<f32>(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0));
    if live && lane == 0u {
        s = sph_lane_total(slot);
    }
    var s_rate = mat3x3<f32>(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0));
    if VISCOUS {
        // The same array for the velocity sums, once lane 0 has read the displacements'.
        workgroupBarrier();
        lane_sums[local] = mine_rate;
        workgroupBarrier();
        if live && lane == 0u {
            s_rate = sph_lane_total(slot);
        }
    }
    if live && lane == 0u {
        let c = 9u * p;
        let g = mat3x3<f32>(
            vec3<f32>(particle_correction[c], particle_correction[c + 1u], particle_correction[c + 2u]),
            vec3<f32>(particle_correction[c + 3u], particle_correction[c + 4u], particle_correction[c + 5u]),
            vec3<f32>(particle_correction[c + 6u], particle_correction[c + 7u], particle_correction[c + 8u]),
        );
        let h = s * g;
        var se: StressEnergy;
        if particle_params.model == 1u {
            let f = identity3() + h;
            let eps = transpose(f) * f - identity3();
            let tr = trace3(eps);
            se = StressEnergy(
                identity3() * (lambda * tr) + eps * (2.0 * mu),
                0.25 * mu * ddot(eps, eps) + 0.125 * lambda * tr * tr,
            );
        } else {
            se = material_stress_energy(MATERIAL, h, lambda, mu);
        }
        var stress = se.p;
        if VISCOUS {
            let f = identity3() + h;
            let f_dot = s_rate * g;
            if particle_params.model == 1u {
                // The paper's eq. (3)-(4) on its own strain eps = F^T F - I, as its elastic
                // stress above: nu = d eps/dt, no F.
                let nu = transpose(f_dot) * f + transpose(f) * f_dot;
                stress = stress + identity3() * (phi * trace3(nu)) + nu * (2.0 * psi);
            } else {
                let rate = (transpose(f_dot) * f + transpose(f) * f_dot) * 0.5;
                stress = stress + f * (identity3() * (phi * trace3(rate)) + rate * (2.0 * psi));
            }
        }
        store9(0u, p, stress * transpose(g));
        store9(1u, p, h);
        particle_energy[p] = particle_params.volume * se.psi;
    }
}
