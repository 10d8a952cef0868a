//! The virtual coupling: a massless proxy (the simulated tool) joined to the device by a
//! spring k_c and a damper b_c (Colgate, Stanley & Brown 1995; Adams & Hannaford 1999).
//!
//! Each tick the proxy is where the coupling spring balances the tissue's local model
//! F_t(x) = f0 + K·(x − x0) (made unilateral, see [`super::shaping::unilateral`]; K is the
//! model's [`LocalModel::solve_stiffness`], the contact's immediate stiffness):
//!
//! k_c·(x_d − x_p) + F_t(x_p) = 0  ⇒  x_p = (k_c I − K)⁻¹ (k_c x_d + f0 − K x0)
//!
//! and the hand feels F = k_c·(x_p − x_d) + b_c·(v_p − v_d) (= F_t(x_p) plus the damper).
//! The proxy position is what the servo hands the physics thread as the tool position.
//!
//! **Why this is passive.** With K symmetric and negative semi-definite (eigenvalues −κᵢ,
//! κᵢ ≥ 0), the stiffness the hand feels, ∂F/∂x_d = k_c (k_c I − K)⁻¹ K, has eigenvalues
//! −k_c κᵢ/(k_c + κᵢ): the series combination of the coupling spring and the tissue, never
//! stiffer than k_c however stiff the tissue. The rendered field is the gradient of a convex
//! potential whose stiffness is bounded by k_c, and Colgate & Schenkel (1997) show that a
//! virtual stiffness K_v with virtual damping B on a device of physical damping b sampled at
//! period T is passive when b > K_v·T/2 + |B|. Choosing k_c ≤ 2(b − |b_c|)/T (and below the
//! device's own limit) therefore keeps the sampled loop passive whatever the simulation
//! does, which is what the coupling is for: stability is designed on the device side, apart
//! from the simulation. The passivity observer of [`super::observer`] checks it:
//! Σ[−F_k·Δx_k + b|Δx_k|²/T] telescopes to V(x_n) + Σ(b/T − k/2)|Δx_k|² ≥ 0 for a spring k.
//!
//! The servo and the physics thread iterate a fixed point: the physics places its tool at
//! the proxy and answers with a new f0; an error e in the proxy comes back as
//! e·(K_true − K)/(k_c − K), K_true the physics' response over one batch. That factor is
//! below one in magnitude only when K is close to K_true, which over a millisecond is the
//! contact springs' stiffness with the tissue held (the tissue has not moved yet), not the
//! settled static stiffness: with the static one (softer) in the solve, a contact spring
//! stiffer than about 2k_c makes the proxy and the tissue ring (measured: a cantilever at
//! 47 N/m static, 500 N/m contact, k_c = 360 N/m bounced in and out of contact at ≈ 10 Hz).
//! K is not capped for the same reason (a capped K in the proxy solve would make the fixed
//! point between servo and physics diverge for tissue stiffer than k_c + 2·cap); it is only
//! symmetrised and its positive eigenvalues (an active, "negative stiffness" tissue) are
//! clipped to zero, see [`sanitize_stiffness`].
//!
//! The contact dampers respond within a batch too: a tool that crosses Δ in a batch of T
//! meets b A (Δ·n)/T, a spring β = b A/T along the normal, but only into the tissue, and the
//! force f0 the physics reports already holds the last batch's damper push D(Δ₀). The solve
//! therefore takes F(x) = f0 − D(Δ₀) + K·(x − x0) + D(x − x0)
//! ([`LocalModel::damper_force_of`]): with K − β n̂n̂ᵀ for a proxy that moves into the tissue,
//! K alone for one that moves out. Without the damper term a damper stiffer than the springs
//! over a batch (β > (k_c + kA)/2) made the fixed point diverge (the proxy ran away to the
//! device's force clamp); with D(Δ₀) kept in f0 as well, a steady press felt the damper twice.

use super::device::DeviceSpec;
use super::model::LocalModel;
use super::shaping::unilateral;
use glam::{DMat3, DVec3};

/// Largest tissue stiffness kept in a local model, N/m (numerical sanity only).
pub const MAX_TISSUE_STIFFNESS: f64 = 1.0e9;

/// Fraction of the passive limit the default coupling spring uses: the 10 % margin keeps
/// Colgate's condition for ticks up to 11 % late (a tick held longer leaks more energy).
pub const PASSIVE_FRACTION: f64 = 0.9;

/// Coupling spring and damper.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CouplingParams {
    /// k_c, N/m.
    pub stiffness: f64,
    /// b_c, N·s/m, on the proxy–device relative velocity.
    pub damping: f64,
}

impl CouplingParams {
    /// The default for a device and loop period T (s): b_c = 0 and
    /// k_c = 0.9 · min(2b/T, spec.max_stiffness), b = [`DeviceSpec::physical_damping`].
    /// Virtual damping would consume the same budget (b > k_c T/2 + |b_c|), and the
    /// device's own damping already damps the hand–device mode, so none is added.
    pub fn passive(spec: &DeviceSpec, period: f64) -> Self {
        CouplingParams {
            stiffness: PASSIVE_FRACTION * spec.max_passive_stiffness(period, 0.0),
            damping: 0.0,
        }
    }
}

/// Eigen-decomposition of a symmetric 3×3 matrix by cyclic Jacobi rotations:
/// returns (λ, V) with M = V·diag(λ)·Vᵀ, V orthonormal (eigenvectors in columns).
pub fn symmetric_eigen(m: DMat3) -> (DVec3, DMat3) {
    let mut a = m;
    let mut v = DMat3::IDENTITY;
    let scale = a.x_axis.length_squared() + a.y_axis.length_squared() + a.z_axis.length_squared();
    for _sweep in 0..32 {
        let off = a.col(1).x.powi(2) + a.col(2).x.powi(2) + a.col(2).y.powi(2);
        if off <= 1e-30 * scale || off == 0.0 {
            break;
        }
        for (p, q) in [(0usize, 1usize), (0, 2), (1, 2)] {
            let apq = a.col(q)[p];
            if apq == 0.0 {
                continue;
            }
            let theta = (a.col(q)[q] - a.col(p)[p]) / (2.0 * apq);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            let mut j = DMat3::IDENTITY;
            j.col_mut(p)[p] = c;
            j.col_mut(q)[q] = c;
            j.col_mut(q)[p] = s;
            j.col_mut(p)[q] = -s;
            a = j.transpose() * a * j;
            v *= j;
        }
    }
    (DVec3::new(a.x_axis.x, a.y_axis.y, a.z_axis.z), v)
}

/// V·diag(d)·Vᵀ.
fn compose(v: DMat3, d: DVec3) -> DMat3 {
    v * DMat3::from_diagonal(d) * v.transpose()
}

/// A tissue stiffness fit for rendering: symmetrised, (K + Kᵀ)/2 (an antisymmetric part is a
/// curl that pumps energy round a loop), with its eigenvalues clipped to
/// [−[`MAX_TISSUE_STIFFNESS`], 0] (a positive eigenvalue is an active, negative-stiffness
/// tissue). Returns the eigen-decomposition (λ, V) of the result.
pub fn sanitize_stiffness(k: DMat3) -> (DVec3, DMat3) {
    let sym = (k + k.transpose()) * 0.5;
    let (lambda, v) = symmetric_eigen(sym);
    let clip = |l: f64| l.clamp(-MAX_TISSUE_STIFFNESS, 0.0);
    (
        DVec3::new(clip(lambda.x), clip(lambda.y), clip(lambda.z)),
        v,
    )
}

/// One coupling solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CouplingOutput {
    /// x_p, m: the proxy (simulated tool) position.
    pub proxy: DVec3,
    /// N: the force on the hand, spring + damper.
    pub force: DVec3,
    /// N: the spring part, k_c (x_p − x_d) = F_t(x_p).
    pub spring_force: DVec3,
    /// N/m: ∂(spring force)/∂x_d = k_c (k_c I − K)⁻¹ K (zero out of contact).
    pub stiffness: DMat3,
    /// The unilateral local model pushes on the proxy.
    pub contact: bool,
    /// N/m: the tissue's largest stiffness κ_max (of −K, sanitised), what the hand would
    /// feel without the coupling.
    pub tissue_stiffness: f64,
}

/// The coupling's state (the proxy's last position, for the damper).
#[derive(Clone, Debug)]
pub struct VirtualCoupling {
    params: CouplingParams,
    last_proxy: Option<DVec3>,
}

impl VirtualCoupling {
    /// A coupling with `params`.
    pub fn new(params: CouplingParams) -> Self {
        VirtualCoupling {
            params,
            last_proxy: None,
        }
    }

    /// The coupling's parameters.
    pub fn params(&self) -> CouplingParams {
        self.params
    }

    /// Solve for the proxy given the device position `x_d` and velocity `v_d`, `dt` (s)
    /// after the last solve. `model` is `None` when there is no usable model (none yet, not
    /// finite): the proxy then sits on the device and no force is rendered.
    pub fn update(
        &mut self,
        model: Option<&LocalModel>,
        x_d: DVec3,
        v_d: DVec3,
        dt: f64,
    ) -> CouplingOutput {
        let k_c = self.params.stiffness;
        let mut out = CouplingOutput {
            proxy: x_d,
            force: DVec3::ZERO,
            spring_force: DVec3::ZERO,
            stiffness: DMat3::ZERO,
            contact: false,
            tissue_stiffness: 0.0,
        };
        if let Some(m) = model.filter(|m| m.in_contact && k_c > 0.0) {
            // F(x) = f0 − D(Δ₀) + K·(x − x0) + D(x − x0) (LocalModel::damper_force_of): the
            // last batch's damper force is replaced by the next move's. D is linear on each
            // side of the surface: a move into the tissue meets K − β n̂n̂ᵀ, one out of it K.
            let f0 = m.force - m.damper_force;
            let springs = m.solve_stiffness();
            let solve = |(lambda, v): (DVec3, DMat3)| {
                let inv_a = compose(v, DVec3::ONE / (DVec3::splat(k_c) - lambda));
                let k = compose(v, lambda);
                (inv_a * (k_c * x_d + f0 - k * m.proxy), k, lambda, v)
            };
            let n = m.damper_normal;
            let into = (m.damper_rate > 0.0)
                .then(|| {
                    let nn = DMat3::from_cols(n * n.x, n * n.y, n * n.z);
                    solve(sanitize_stiffness(springs - nn * m.damper_rate))
                })
                .filter(|(x_p, ..)| (*x_p - m.proxy).dot(n) <= 0.0);
            // The springs' decomposition: the tissue's stiffness, and the solve out of it.
            let springs = sanitize_stiffness(springs);
            out.tissue_stiffness = -springs.0.min_element();
            let (x_p, k, lambda, v) = into.unwrap_or_else(|| solve(springs));
            let f_t = unilateral(f0 + k * (x_p - m.proxy), m.force);
            if f_t != DVec3::ZERO {
                out.proxy = x_p;
                out.spring_force = k_c * (x_p - x_d);
                out.stiffness = compose(v, k_c * lambda / (DVec3::splat(k_c) - lambda));
                out.contact = true;
            }
        }
        out.force = out.spring_force;
        if self.params.damping != 0.0 && dt > 0.0 {
            if let Some(last) = self.last_proxy {
                let v_p = (out.proxy - last) / dt;
                out.force += self.params.damping * (v_p - v_d);
            }
        }
        self.last_proxy = Some(out.proxy);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eigen_reconstructs() {
        let m = DMat3::from_cols(
            DVec3::new(4.0, 1.0, -2.0),
            DVec3::new(1.0, -3.0, 0.5),
            DVec3::new(-2.0, 0.5, 1.0),
        );
        let (l, v) = symmetric_eigen(m);
        let r = compose(v, l);
        assert!((r - m).to_cols_array().iter().all(|e| e.abs() < 1e-12));
        assert!((v.transpose() * v - DMat3::IDENTITY)
            .to_cols_array()
            .iter()
            .all(|e| e.abs() < 1e-12));
    }

    /// A wall z < 0 with contact springs a and dampers β over a batch, the tool at
    /// penetration p after a batch that moved it c deeper (so f0 holds β c of damper push):
    /// the proxy solves the batch's own piecewise model, k_c (x_d − x_p) + F(x_p) = 0 with
    /// F(x) = a (p − (x − x0)) + β max(0, −(x − x0)): into the tissue with a + β, out of it
    /// with a alone, and the last batch's damper push is not counted again.
    #[test]
    fn the_proxy_solves_the_batchs_piecewise_damper_model() {
        let (k_c, a, beta, p, c) = (400.0, 2000.0, 5000.0, 0.002, 1e-4);
        let n = DVec3::Z;
        let x0 = -p * n;
        let model = LocalModel {
            force: n * (a * p + beta * c),
            contact_stiffness: -a * DMat3::from_cols(n * n.x, n * n.y, n * n.z),
            proxy: x0,
            in_contact: true,
            ..Default::default()
        }
        .with_batch_damper(beta * 1e-3 / 3e-5, 3e-5, 1e-3, -c * n);
        assert!((model.damper_rate - beta).abs() < 1e-9);
        let force = |x: f64| a * (p - (x - x0.z)) + beta * (-(x - x0.z)).max(0.0);
        for x_d in [-0.0030, -0.0022, -0.0021, -0.0019, -0.0010] {
            let mut coupling = VirtualCoupling::new(CouplingParams {
                stiffness: k_c,
                damping: 0.0,
            });
            let out = coupling.update(Some(&model), DVec3::new(0.0, 0.0, x_d), DVec3::ZERO, 1e-3);
            let x_p = out.proxy.z;
            let balance = k_c * (x_d - x_p) + force(x_p);
            assert!(out.contact, "x_d {x_d}");
            assert!(
                balance.abs() < 1e-9,
                "x_d {x_d}: proxy {x_p}, residual {balance} N"
            );
            // Felt: the springs and, pressing deeper, the dampers in series with k_c.
            let k = if x_p < x0.z { a + beta } else { a };
            assert!((out.stiffness.z_axis.z + k_c * k / (k_c + k)).abs() < 1e-9);
        }
    }

    #[test]
    fn series_stiffness_on_a_wall() {
        // Wall z < 0, stiffness 5000 N/m, model computed at the surface x0 = 0, f0 = 0+.
        let kw = 5000.0;
        let n = DVec3::Z;
        let mut c = VirtualCoupling::new(CouplingParams {
            stiffness: 400.0,
            damping: 0.0,
        });
        let model = LocalModel {
            force: n * 1e-3,
            stiffness: -kw * DMat3::from_cols(n * n.x, n * n.y, n * n.z),
            proxy: DVec3::ZERO,
            in_contact: true,
            ..Default::default()
        };
        let x_d = DVec3::new(0.0, 0.0, -0.002);
        let out = c.update(Some(&model), x_d, DVec3::ZERO, 1e-3);
        let ks = 400.0 * kw / (400.0 + kw);
        assert!(out.contact);
        assert!((out.force.z - (1e-3 * 400.0 / (400.0 + kw) + ks * 0.002)).abs() < 1e-9);
        assert!((out.stiffness.z_axis.z + ks).abs() < 1e-9);
        // Out of the wall: no pull, proxy on the device.
        let out = c.update(Some(&model), DVec3::new(0.0, 0.0, 0.001), DVec3::ZERO, 1e-3);
        assert!(!out.contact && out.force == DVec3::ZERO);
    }
}
