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
    /// [`super::coupling`]), and a contact spring is stiffer than the settled tissue (the
    /// dampers' immediate response is `damper_rate`'s).
    pub contact_stiffness: DMat3,
    /// β = b A_c / T, N/m: how the contact dampers resist a tool move within one physics batch
    /// of T s (the tool crosses Δx at Δx/T; b the damping per unit area, A_c the contact's
    /// area), along `damper_normal` and only into the tissue (the damper is unilateral).
    /// Zero: no damper term (see [`LocalModel::damper_force_of`]).
    pub damper_rate: f64,
    /// n̂: the direction of the tool force (out of the tissue), the contact's mean normal.
    pub damper_normal: DVec3,
    /// N: the part of `force` the dampers gave the last batch's own tool move Δ₀,
    /// [`LocalModel::damper_force_of`]\(Δ₀): the next batch's move replaces it.
    pub damper_force: DVec3,
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
            damper_rate: 0.0,
            damper_normal: DVec3::ZERO,
            damper_force: DVec3::ZERO,
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

    /// D(Δ) = β max(0, −n̂·Δ) n̂, N: the contact dampers' push on the tool after a batch
    /// that moved it by Δ (the tissue held): zero for a move out of the tissue. The batch
    /// that moves the tool from x0 to x reports, to first order,
    ///
    /// F(x) = f0 − D(Δ₀) + K_c·(x − x0) + D(x − x0)
    ///
    /// (`damper_force` = D(Δ₀), Δ₀ the last batch's move; K_c the contact springs): the
    /// model the coupling's proxy solve uses ([`super::coupling`]).
    pub fn damper_force_of(&self, delta: DVec3) -> DVec3 {
        self.damper_normal * (self.damper_rate * (-self.damper_normal.dot(delta)).max(0.0))
    }

    /// This model with its contact damper term for a batch of `batch_seconds` s that moved
    /// the tool by `tool_move` m, from the tool's damping per unit area `damping` (Pa·s/m)
    /// and the contact's area `contact_area` (m²), along the tool force's direction.
    pub fn with_batch_damper(
        mut self,
        damping: f64,
        contact_area: f64,
        batch_seconds: f64,
        tool_move: DVec3,
    ) -> Self {
        let normal = self.force.normalize_or_zero();
        if damping > 0.0 && contact_area > 0.0 && batch_seconds > 0.0 && normal != DVec3::ZERO {
            self.damper_rate = damping * contact_area / batch_seconds;
            self.damper_normal = normal;
            self.damper_force = self.damper_force_of(tool_move);
        }
        self
    }

    /// This model with no damper term, and with the part of the dampers' push D(Δ₀) that a
    /// move into the tissue beyond `cap` (m) made taken out of f0 (at most f0's component
    /// along n̂, so f0 never turns to pull): for a tool that does not follow the proxy (held
    /// back, its batches moving it no farther in than `cap`), whose arrival at the tissue
    /// at the hand's speed put the dampers' push at that speed in f0 (0.2 N on lv_touch at
    /// 2 m/s, in the hand for one batch). A move within `cap` keeps its push: the tissue
    /// follows a tool that slow, so the estimate β·(−n̂·Δ₀), which takes the tissue as
    /// still, would overstate it.
    pub fn without_damper(mut self, cap: f64) -> Self {
        if self.damper_rate > 0.0 {
            let into = self.damper_force.length() / self.damper_rate;
            let excess = self.damper_rate * (into - cap.max(0.0)).max(0.0);
            let along = self.force.dot(self.damper_normal).max(0.0);
            self.force -= self.damper_normal * excess.min(along);
        }
        self.damper_rate = 0.0;
        self.damper_normal = DVec3::ZERO;
        self.damper_force = DVec3::ZERO;
        self
    }

    /// All numbers finite (a non-finite model is treated as diverged).
    pub fn is_finite(&self) -> bool {
        self.force.is_finite()
            && self.stiffness.is_finite()
            && self.contact_stiffness.is_finite()
            && self.damper_rate.is_finite()
            && self.damper_normal.is_finite()
            && self.damper_force.is_finite()
            && self.proxy.is_finite()
            && self.stamp.is_finite()
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
    /// The pose used is not the device's reading: the reading jumped farther than a hand
    /// moves (held back), or the pose is catching up with it at that speed
    /// ([`crate::haptics::pose_gate`]).
    pub const POSE_HELD: u32 = 1 << 8;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_damper_term_pushes_back_on_moves_into_the_tissue_only() {
        // Force out of the tissue along +z, b = 1e4 Pa·s/m on 3e-5 m² over a 1 ms batch.
        let m = LocalModel {
            force: DVec3::new(0.0, 0.0, 0.5),
            ..Default::default()
        }
        .with_batch_damper(1.0e4, 3.0e-5, 1.0e-3, DVec3::new(0.0, 1e-4, -2e-4));
        let beta = 1.0e4 * 3.0e-5 / 1.0e-3;
        assert!((m.damper_rate - beta).abs() < 1e-12 && m.damper_normal == DVec3::Z);
        // The last move went 0.2 mm into the tissue: its damper force, along the normal only.
        assert!((m.damper_force - DVec3::new(0.0, 0.0, beta * 2e-4)).length() < 1e-12);
        // A move out of the tissue meets no damper.
        assert_eq!(m.damper_force_of(DVec3::new(0.0, 0.0, 1e-4)), DVec3::ZERO);
        // No damping, no area or no force: no term.
        let plain = LocalModel {
            force: DVec3::new(0.0, 0.0, 0.5),
            ..Default::default()
        };
        for (b, a) in [(0.0, 3e-5), (1e4, 0.0)] {
            let m = plain.with_batch_damper(b, a, 1e-3, DVec3::NEG_Z);
            assert_eq!((m.damper_rate, m.damper_force), (0.0, DVec3::ZERO));
        }
        let m = LocalModel::default().with_batch_damper(1e4, 3e-5, 1e-3, DVec3::NEG_Z);
        assert_eq!(m.damper_rate, 0.0);
    }
    #[test]
    fn without_the_damper_only_the_push_of_a_move_beyond_the_cap_leaves_f0() {
        // β = 300 N/m; the batch moved the tool 0.2 mm in: push 0.06 N in f0 = 0.5 N.
        let m = LocalModel {
            force: DVec3::new(0.0, 0.0, 0.5),
            ..Default::default()
        }
        .with_batch_damper(1.0e4, 3.0e-5, 1.0e-3, DVec3::new(0.0, 0.0, -2e-4));
        // Held back at 0.05 mm a batch: the push of the other 0.15 mm goes, 0.045 N.
        let held = m.without_damper(5e-5);
        assert!(
            (held.force.z - (0.5 - 300.0 * 1.5e-4)).abs() < 1e-12,
            "{held:?}"
        );
        assert_eq!((held.damper_rate, held.damper_force), (0.0, DVec3::ZERO));
        // A move within the cap keeps its push.
        assert_eq!(m.without_damper(3e-4).force, m.force);
        // Never below zero along the normal: f0 = 0.01 N against a 0.06 N push.
        let weak = LocalModel {
            force: DVec3::new(0.002, 0.0, 0.01),
            ..Default::default()
        }
        .with_batch_damper(1.0e4, 3.0e-5, 1.0e-3, DVec3::new(0.0, 0.0, -2e-4));
        let w = weak.without_damper(0.0);
        assert!(w.force.dot(weak.damper_normal).abs() < 1e-12, "{w:?}");
    }
}
