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

/// Rest-state quantities of every neighbour pair, computed once (the CPU path's cache; the
/// WGSL kernels compute them on the fly with the same arithmetic, so results are equal):
/// for slot k of particle c's neighbour list (neighbour b), ∇W(X_b − X_c), r0 = |X_c − X_b|
/// and the hourglass weight h·W(r0)/r0² (h = ½ α E V²).
#[derive(Clone, Debug, Default)]
pub struct PairTable {
    /// ∇W(X_b − X_c) per slot.
    pub gradient: Vec<Vec3>,
    /// r0 per slot.
    pub rest_distance: Vec<f32>,
    /// h·W(r0)/r0² per slot (0 where r0 = 0).
    pub hourglass: Vec<f32>,
}

impl PairTable {
    /// The table over neighbour lists `neighbour_offsets`/`neighbours` of `rest`.
    pub fn new(
        pp: &crate::particles::params::ParticleParams,
        rest: &[f32],
        neighbour_offsets: &[u32],
        neighbours: &[u32],
    ) -> PairTable {
        let n_slots = neighbours.len();
        let mut t = PairTable {
            gradient: Vec::with_capacity(n_slots),
            rest_distance: Vec::with_capacity(n_slots),
            hourglass: Vec::with_capacity(n_slots),
        };
        let hg = 0.5 * pp.hourglass * pp.youngs * (pp.volume * pp.volume);
        for c in 0..neighbour_offsets.len().saturating_sub(1) {
            let x0c = super::load3(rest, c);
            for k in neighbour_offsets[c]..neighbour_offsets[c + 1] {
                let x0b = super::load3(rest, neighbours[k as usize] as usize);
                t.gradient
                    .push(kernel_gradient(pp.model, x0b - x0c, pp.spacing, pp.support));
                let r0 = (x0c - x0b).length();
                t.rest_distance.push(r0);
                t.hourglass.push(if r0 > 0.0 {
                    hg * wendland(r0, pp.support) / (r0 * r0)
                } else {
                    0.0
                });
            }
        }
        t
    }
}
