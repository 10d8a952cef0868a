//! What the two threads hand each other: the local model (physics → servo) and the tool
//! command (servo → physics).
//!
//! Frame: every position here is in metres in the device frame, relative to the tool's home
//! position; the physics side adds the scene's home (`world = home + x`). Times are seconds
//! on the shared [`LoopClock`].

use glam::{DMat3, DVec3};
use std::time::{Duration, Instant};

/// The clock both threads stamp with: seconds since a common origin (monotonic).
#[derive(Clone, Copy, Debug)]
pub struct LoopClock {
    origin: Instant,
}

impl LoopClock {
    /// A clock whose zero is now.
    pub fn new() -> Self {
        LoopClock {
            origin: Instant::now(),
        }
    }

    /// Seconds since the origin.
    pub fn now(&self) -> f64 {
        self.seconds_at(Instant::now())
    }

    /// The clock reading of `instant` (negative before the origin).
    pub fn seconds_at(&self, instant: Instant) -> f64 {
        match instant.checked_duration_since(self.origin) {
            Some(d) => d.as_secs_f64(),
            None => -(self.origin - instant).as_secs_f64(),
        }
    }

    /// The instant at `seconds` on this clock (clamped at the origin).
    pub fn instant_at(&self, seconds: f64) -> Instant {
        self.origin + Duration::from_secs_f64(seconds.max(0.0))
    }
}

impl Default for LoopClock {
    fn default() -> Self {
        Self::new()
    }
}

/// The linearised contact the physics thread publishes after each batch, so the servo can
/// evaluate the tool force between updates (VRPN's force field, SOFA's local solve):
///
/// F(x) = f0 + K·(x − x0)
///
/// with f0 = [`force`](Self::force), K = [`stiffness`](Self::stiffness),
/// x0 = [`proxy`](Self::proxy). The default value is "no contact, never published".
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LocalModel {
    /// f0, N: the force the tissue exerts on the tool at `proxy`.
    pub force: DVec3,
    /// K = ∂F/∂x, N/m: how the tool force changes with the tool position once the tissue
    /// has settled (the static stiffness); negative along the contact normal for a tissue
    /// that pushes back harder the deeper the tool goes.
    pub stiffness: DMat3,
    /// K_c, N/m: how the tool force changes within one physics batch, before the tissue has
    /// moved (the contact springs with the tissue held). The coupling's proxy solve uses it
    /// (zero: it uses `stiffness`): the servo ↔ physics fixed point converges only when the
    /// solve's stiffness is at least the physics' immediate response (see
    /// [`super::coupling`]), and a contact spring is stiffer than the settled tissue.
    pub contact_stiffness: DMat3,
    /// x0, m: the tool (proxy) position the model was computed at (device frame, relative to
    /// the tool home).
    pub proxy: DVec3,
    /// s on the loop clock: the time the model refers to, i.e. the `stamp` of the
    /// [`ToolCommand`] it was computed from, so that `now − stamp` (the model's age) counts
    /// the whole round trip servo → physics → servo.
    pub stamp: f64,
    /// s: the simulated time at the end of the batch that produced the model.
    pub sim_time: f64,
    /// The simulation diverged: the servo fades the force to zero.
    pub diverged: bool,
    /// The tool touches the tissue. Out of contact the model is ignored (zero force).
    pub in_contact: bool,
    /// m: deepest penetration of the tool into the tissue (logged).
    pub penetration: f64,
    /// Particles of the mesh-free layer active around the tool (logged).
    pub active_particles: u32,
}

impl Default for LocalModel {
    fn default() -> Self {
        LocalModel {
            force: DVec3::ZERO,
            stiffness: DMat3::ZERO,
            contact_stiffness: DMat3::ZERO,
            proxy: DVec3::ZERO,
            stamp: 0.0,
            sim_time: 0.0,
            diverged: false,
            in_contact: false,
            penetration: 0.0,
            active_particles: 0,
        }
    }
}

impl LocalModel {
    /// F(x) = f0 + K·(x − x0), N, without any shaping.
    pub fn force_at(&self, x: DVec3) -> DVec3 {
        self.force + self.stiffness * (x - self.proxy)
    }

    /// The stiffness the coupling's proxy solve uses: `contact_stiffness`, or `stiffness`
    /// when that is zero.
    pub fn solve_stiffness(&self) -> DMat3 {
        if self.contact_stiffness == DMat3::ZERO {
            self.stiffness
        } else {
            self.contact_stiffness
        }
    }

    /// All numbers finite (a non-finite model is treated as diverged).
    pub fn is_finite(&self) -> bool {
        self.force.is_finite()
            && self.stiffness.is_finite()
            && self.contact_stiffness.is_finite()
            && self.proxy.is_finite()
            && self.stamp.is_finite()
    }
}

/// The contact's stiffness within one physics batch of `batch_seconds` (s), N/m, for
/// [`LocalModel::contact_stiffness`]: the contact springs' `springs` (ToolForce's
/// k Σ A [(R/r)(I − n nᵀ) − I], normal part −k Σ A n nᵀ) plus the dampers',
/// −(b A_c / T) f̂ f̂ᵀ, b the tool's damping per unit area, A_c the contact's area, T the
/// batch's duration and f̂ the direction of the tool force `force` (the contact's mean
/// normal; exact for one contact point).
///
/// Within a batch the tool moves from where it was to the proxy at Δx/T, so the contact
/// dampers push back b A (Δx·n)/T: a spring b A/T along each contact normal. Without it a
/// damper much stiffer than the springs over one batch (b/k ≫ T) makes the servo ↔ physics
/// fixed point diverge (the proxy runs away until the device's force clamp holds it; see
/// [`super::coupling`]); overestimating this stiffness only slows the proxy, and where it
/// settles (f0 balanced by the coupling spring) does not depend on it.
pub fn batch_contact_stiffness(
    springs: DMat3,
    force: DVec3,
    damping: f64,
    contact_area: f64,
    batch_seconds: f64,
) -> DMat3 {
    let normal = force.normalize_or_zero();
    if damping > 0.0 && contact_area > 0.0 && batch_seconds > 0.0 && normal != DVec3::ZERO {
        springs
            - DMat3::from_cols(normal * normal.x, normal * normal.y, normal * normal.z)
                * (damping * contact_area / batch_seconds)
    } else {
        springs
    }
}

/// What the servo hands the physics thread each tick: where the simulated tool must be.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ToolCommand {
    /// m: the proxy (simulated tool) position the virtual coupling computed; the physics side
    /// places its tool at `home + position`.
    pub position: DVec3,
    /// m/s: the device velocity (estimated from its position history where the device gives
    /// none); the proxy follows the device, so this is also the proxy's mean velocity.
    pub velocity: DVec3,
    /// m: the device position this tick (for logging on the physics side).
    pub device_position: DVec3,
    /// s on the loop clock: when the servo read the device; copy it into
    /// [`LocalModel::stamp`] of the model computed from this command.
    pub stamp: f64,
    /// Device buttons, bit i = button i.
    pub buttons: u32,
    /// Servo tick number.
    pub tick: u64,
}

/// The force the servo sends to a device, with the hand-side local model so a device (or a
/// network driver) can extrapolate between packets:
///
/// F(x) = model_force + stiffness·(x − at), clamped to the device's force, zero where it
/// would reverse `model_force`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ForceCommand {
    /// N: the force the device applies to the hand.
    pub force: DVec3,
    /// N: the position-dependent part of `force` (without the passivity controller's
    /// damping): the f0 of the hand-side model F(x) = f0 + K·(x − at).
    pub model_force: DVec3,
    /// N/m: ∂force/∂(device position) at `at`, shaping gains included (the stiffness the hand
    /// feels through the virtual coupling).
    pub stiffness: DMat3,
    /// m: the device position the force was computed for.
    pub at: DVec3,
    /// s: age of the physics model the force comes from (infinite before the first one).
    pub model_age: f64,
    /// [`flags`] bits.
    pub flags: u32,
}

impl Default for ForceCommand {
    fn default() -> Self {
        ForceCommand {
            force: DVec3::ZERO,
            model_force: DVec3::ZERO,
            stiffness: DMat3::ZERO,
            at: DVec3::ZERO,
            model_age: f64::INFINITY,
            flags: 0,
        }
    }
}

/// Bits of [`ForceCommand::flags`] (and of the UDP force packet's flags).
pub mod flags {
    /// The physics model reports contact.
    pub const IN_CONTACT: u32 = 1 << 0;
    /// The simulation diverged (or the model is not finite).
    pub const DIVERGED: u32 = 1 << 1;
    /// The force is fading out or in (gain below 1 because of staleness, divergence or the
    /// device's keep-alive).
    pub const FADING: u32 = 1 << 2;
    /// The force magnitude was clamped to the device's limit this tick.
    pub const CLAMPED: u32 = 1 << 3;
    /// The model is older than the staleness threshold (or there is none yet).
    pub const STALE: u32 = 1 << 4;
    /// The start-up ramp is not finished.
    pub const RAMPING: u32 = 1 << 5;
    /// The device input is not fresh (keep-alive expired).
    pub const DEVICE_STALE: u32 = 1 << 6;
    /// The passivity controller added damping this tick.
    pub const PASSIVITY_CONTROL: u32 = 1 << 7;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_batch_contact_stiffness_adds_the_dampers_along_the_normal() {
        // One contact along z with area A: springs −k A n nᵀ (R/r = 1), force along +z.
        let (k, b, t, area) = (2.0e6, 1.0e4, 1.0e-3, 3.0e-5);
        let springs = DMat3::from_diagonal(DVec3::new(0.0, 0.0, -k * area));
        let f = DVec3::new(0.0, 0.0, 0.5);
        let kc = batch_contact_stiffness(springs, f, b, area, t);
        assert!((kc.z_axis.z - (-(k + b / t) * area)).abs() <= 1e-9 * k * area);
        assert_eq!(kc.x_axis, DVec3::ZERO);
        assert_eq!(kc.y_axis, DVec3::ZERO);
        // No damper, no batch or no force: the springs alone.
        assert_eq!(batch_contact_stiffness(springs, f, 0.0, area, t), springs);
        assert_eq!(batch_contact_stiffness(springs, f, b, area, 0.0), springs);
        assert_eq!(
            batch_contact_stiffness(springs, DVec3::ZERO, b, area, t),
            springs
        );
    }
}
