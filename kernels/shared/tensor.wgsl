// 3x3 tensor helpers shared by the element kernels (fem_forces, fem_forces_split), and the
// rotation extraction of Mueller et al. 2016. CPU twins: src/material.rs (trace, ddot,
// cofactor, outer, extract_rotation).

const ROTATION_ITERATIONS: u32 = 24u;

fn trace3(m: mat3x3<f32>) -> f32 {
    return m[0].x + m[1].y + m[2].z;
}

fn ddot(a: mat3x3<f32>, b: mat3x3<f32>) -> f32 {
    return dot(a[0], b[0]) + dot(a[1], b[1]) + dot(a[2], b[2]);
}

// Columns c0 = a1 x a2, c1 = a2 x a0, c2 = a0 x a1: det(A) A^-T = d det / dA.
fn cofactor(a: mat3x3<f32>) -> mat3x3<f32> {
    return mat3x3<f32>(cross(a[1], a[2]), cross(a[2], a[0]), cross(a[0], a[1]));
}

fn identity3() -> mat3x3<f32> {
    return mat3x3<f32>(vec3<f32>(1.0, 0.0, 0.0), vec3<f32>(0.0, 1.0, 0.0), vec3<f32>(0.0, 0.0, 1.0));
}

// a (x) b: column j is a * b_j.
fn outer(a: vec3<f32>, b: vec3<f32>) -> mat3x3<f32> {
    return mat3x3<f32>(a * b.x, a * b.y, a * b.z);
}

// Green strain from the displacement gradient: E = (H + H^T + H^T H) / 2.
fn green_strain(h: mat3x3<f32>) -> mat3x3<f32> {
    return (h + transpose(h) + transpose(h) * h) * 0.5;
}

fn quat_to_mat(q: vec4<f32>) -> mat3x3<f32> {
    let x = q.x;
    let y = q.y;
    let z = q.z;
    let w = q.w;
    return mat3x3<f32>(
        vec3<f32>(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)),
        vec3<f32>(2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x)),
        vec3<f32>(2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)),
    );
}

fn quat_mul(a: vec4<f32>, b: vec4<f32>) -> vec4<f32> {
    return vec4<f32>(a.w * b.xyz + b.w * a.xyz + cross(a.xyz, b.xyz), a.w * b.w - dot(a.xyz, b.xyz));
}

// The rotation nearest F (Mueller et al. 2016), from the identity.
fn extract_rotation(f: mat3x3<f32>) -> mat3x3<f32> {
    var q = vec4<f32>(0.0, 0.0, 0.0, 1.0);
    for (var k = 0u; k < ROTATION_ITERATIONS; k++) {
        let r = quat_to_mat(q);
        let num = cross(r[0], f[0]) + cross(r[1], f[1]) + cross(r[2], f[2]);
        let den = abs(dot(r[0], f[0]) + dot(r[1], f[1]) + dot(r[2], f[2])) + 1e-9;
        let omega = num / den;
        let w = length(omega);
        if w < 1e-9 {
            break;
        }
        let axis = omega / w;
        let dq = vec4<f32>(axis * sin(0.5 * w), cos(0.5 * w));
        q = normalize(quat_mul(dq, q));
    }
    return quat_to_mat(q);
}
