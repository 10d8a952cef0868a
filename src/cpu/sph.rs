//! CPU twins of the kernel functions in `kernels/shared/particles.wgsl`: the Wendland C2
//! kernel and the paper's eq. (8) function, and their gradients.

use glam::Vec3;

const PI: f32 = std::f32::consts::PI;

/// ∇W of the Wendland C2 kernel (support R = 2h) at offset d:
/// −105/(16π h⁵) (1 − q/2)³ d, q = |d|/h; zero beyond the support.
pub fn wendland_gradient(d: Vec3, support: f32) -> Vec3 {
    let h = 0.5 * support;
    let q = d.length() / h;
    if q >= 2.0 {
        return Vec3::ZERO;
    }
    let t = 1.0 - 0.5 * q;
    d * (-105.0 / (16.0 * PI * h * h * h * h * h) * t * t * t)
}

/// W of the Wendland C2 kernel: 21/(16π h³) (1 − q/2)⁴ (2q + 1).
pub fn wendland(r: f32, support: f32) -> f32 {
    let h = 0.5 * support;
    let q = r / h;
    if q >= 2.0 {
        return 0.0;
    }
    let t = 1.0 - 0.5 * q;
    21.0 / (16.0 * PI * h * h * h) * t * t * t * t * (2.0 * q + 1.0)
}

/// Gradient of the paper's eq. (8) W(s) = s⁻³ − s⁻¹, s = r/Δx (ε = 1): W′(s)/(Δx r) d,
/// W′(s) = −3/s⁴ + 1/s²; zero beyond the support or at r = 0.
pub fn paper_gradient(d: Vec3, spacing: f32, support: f32) -> Vec3 {
    let r = d.length();
    if r >= support || r <= 0.0 {
        return Vec3::ZERO;
    }
    let s = r / spacing;
    let dw = -3.0 / (s * s * s * s) + 1.0 / (s * s);
    d * (dw / (spacing * r))
}

/// The kernel gradient of particle model `model` (0 tlsph, 1 paper).
pub fn kernel_gradient(model: u32, d: Vec3, spacing: f32, support: f32) -> Vec3 {
    if model == 1 {
        paper_gradient(d, spacing, support)
    } else {
        wendland_gradient(d, support)
    }
}
