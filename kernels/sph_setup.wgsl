// Setup stage (once, after the neighbour lists): each particle's kernel-gradient correction
// G_p = M_p^-1, M_p = sum_b V (X_b - X_p) (x) grad W(X_b - X_p) (Bonet & Lok 1999; the
// L_a of TrixiParticles' total-Lagrangian SPH), so that F_p = [sum_b V (x_b - x_p) (x)
// grad W] G_p is exactly the deformation gradient of any affine motion. A particle whose M
// is singular (too few neighbours) gets G = 0 and no stress. CPU twin: src/cpu/sph_setup.rs.
#import index
#import particles

@group(0) @binding(0) var<uniform> particle_params: ParticleParams;
@group(0) @binding(1) var<storage, read> particle_rest: array<f32>;
@group(0) @binding(2) var<storage, read> neighbour_offsets: array<u32>;
@group(0) @binding(3) var<storage, read> neighbours: array<u32>;
@group(0) @binding(4) var<storage, read_write> particle_correction: array<f32>;

const WORKGROUP: u32 = 64u;

fn rest(p: u32) -> vec3<f32> {
    return vec3<f32>(particle_rest[3u * p], particle_rest[3u * p + 1u], particle_rest[3u * p + 2u]);
}

fn kernel_gradient(d: vec3<f32>) -> vec3<f32> {
    return model_kernel_gradient(particle_params.model, d, particle_params.spacing, particle_params.support);
}

@compute @workgroup_size(64)
fn sph_setup(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let p = linear_index(gid, nwg, WORKGROUP);
    if p >= particle_params.n_particles {
        return;
    }
    let x = rest(p);
    var m = mat3x3<f32>(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0));
    for (var k = neighbour_offsets[p]; k < neighbour_offsets[p + 1u]; k++) {
        let d = rest(neighbours[k]) - x;
        let w = kernel_gradient(d) * particle_params.volume;
        m += mat3x3<f32>(d * w.x, d * w.y, d * w.z);
    }
    let det = determinant(m);
    var g = mat3x3<f32>(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0));
    let scale = abs(m[0].x) + abs(m[1].y) + abs(m[2].z);
    if abs(det) > 1e-6 * scale * scale * scale {
        // Inverse by the adjugate: rows of m^-1 are the cross products of m's columns.
        let r0 = cross(m[1], m[2]);
        let r1 = cross(m[2], m[0]);
        let r2 = cross(m[0], m[1]);
        g = transpose(mat3x3<f32>(r0, r1, r2)) * (1.0 / det);
    }
    for (var c = 0u; c < 3u; c++) {
        particle_correction[9u * p + 3u * c] = g[c].x;
        particle_correction[9u * p + 3u * c + 1u] = g[c].y;
        particle_correction[9u * p + 3u * c + 2u] = g[c].z;
    }
}
