//! The pose gate: a device reading that lies farther from the last plausible one than a
//! hand could have moved since is held back, so a glitch (a corrupted or spoofed network
//! packet, an encoder that skips) reaches neither the coupling, the force, the tool nor the
//! passivity observer; and the pose the servo uses never moves faster than a hand.
//!
//! A reading x sampled at time s (the device's sample time: for a network device when its
//! packet arrived, so a pose repeated between packets is not new) is **plausible** when
//!
//! |x − x_a| ≤ v_max·(s − s_a) + δ
//!
//! with (s_a, x_a) the last plausible reading, v_max the fastest a hand moves a stylus and δ
//! a noise floor. The **pose used**, u, follows the last plausible reading, by at most
//! v_max·Δt + δ in a tick of Δt:
//!
//! u ← u + clamp(x_a − u, v_max·Δt + δ)
//!
//! So a one-tick glitch is held (u stays; the tick after, the next good reading is plausible
//! again and, for a hand slower than v_max, u is back on it), and a device that comes back
//! from a pause somewhere else, or a reading that stays off long enough for the bound to
//! reach it, is followed at v_max: the coupling's force rises as for a fast hand, never in
//! one tick.

use glam::DVec3;

/// m/s: the fastest a hand moves a haptic stylus. Fast reaching movements peak at 1–2 m/s;
/// surgical palpation is far slower. At 1 kHz a reading may lie up to 2 mm (plus the noise
/// floor) from the last plausible one.
pub const MAX_HAND_SPEED: f64 = 2.0;

/// m: a reading may always lie this far from the last plausible one, whatever the time
/// between them (encoder quantisation and the jitter of a network device's clock; a
/// Geomagic Touch resolves 0.055 mm).
pub const POSE_NOISE: f64 = 0.2e-3;

/// s: readings implausible for this long in a row make the device count as not fresh (the
/// force fades): a real move is plausible again after |jump|/v_max (25 ms for 50 mm), a
/// device sending nonsense never is.
pub const IMPLAUSIBLE_STALE: f64 = 0.1;

/// What [`PoseGate::filter`] passes on for a tick.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GatedPose {
    /// m: the position to use.
    pub position: DVec3,
    /// m/s: the velocity to use (the reading's when the pose is the reading, else the
    /// pose's own: zero while held in place, its step over the tick while catching up).
    pub velocity: DVec3,
    /// The pose is not the reading: the reading was not plausible, or the pose is still
    /// catching up with it.
    pub held: bool,
    /// The reading itself was not plausible (a subset of `held`).
    pub implausible: bool,
    /// The readings have been implausible for [`IMPLAUSIBLE_STALE`] or longer: treat the
    /// device as not fresh.
    pub stale: bool,
}

/// Holds back readings that jump farther than a hand can move (see the module doc).
#[derive(Clone, Debug)]
pub struct PoseGate {
    max_speed: f64,
    noise: f64,
    /// The last plausible reading: sample time, position, velocity.
    plausible: Option<(f64, DVec3, DVec3)>,
    /// The pose used and the tick time it was used at.
    pose: Option<(f64, DVec3)>,
    implausible: u64,
    catching_up: u64,
    largest_jump: f64,
    implausible_since: Option<f64>,
}

impl PoseGate {
    /// A gate that accepts readings moving at up to `max_speed` (m/s) plus `noise` (m).
    pub fn new(max_speed: f64, noise: f64) -> Self {
        PoseGate {
            max_speed,
            noise,
            plausible: None,
            pose: None,
            implausible: 0,
            catching_up: 0,
            largest_jump: 0.0,
            implausible_since: None,
        }
    }

    /// Forget the readings so far (not the counts): the next reading is taken as it is. For
    /// a device that comes back after it stopped being fresh (the force faded out and fades
    /// back in), or a network device's first packet.
    pub fn reset(&mut self) {
        self.plausible = None;
        self.pose = None;
        self.implausible_since = None;
    }

    /// The pose to use at tick time `now` (s) for the reading `position`, `velocity` sampled
    /// at time `sampled` (s; `now` for a device read at the tick).
    pub fn filter(
        &mut self,
        now: f64,
        sampled: f64,
        position: DVec3,
        velocity: DVec3,
    ) -> GatedPose {
        let velocity = if velocity.is_finite() {
            velocity
        } else {
            DVec3::ZERO
        };
        let implausible = match self.plausible {
            _ if !position.is_finite() => true,
            None => false,
            Some((s_a, x_a, _)) => {
                let jump = (position - x_a).length();
                let implausible = jump > self.max_speed * (sampled - s_a).max(0.0) + self.noise;
                if implausible {
                    self.largest_jump = self.largest_jump.max(jump);
                }
                implausible
            }
        };
        if implausible {
            self.implausible += 1;
            self.implausible_since.get_or_insert(now);
        } else {
            self.implausible_since = None;
        }
        let stale = self
            .implausible_since
            .is_some_and(|t0| now - t0 >= IMPLAUSIBLE_STALE);
        if !implausible {
            self.plausible = Some((sampled, position, velocity));
        }
        let Some((target, target_velocity)) = self.plausible.map(|(_, x, v)| (x, v)) else {
            // Nothing plausible yet (a non-finite first reading): the origin, held.
            return GatedPose {
                position: DVec3::ZERO,
                velocity: DVec3::ZERO,
                held: true,
                implausible: true,
                stale,
            };
        };
        let (position_used, velocity_used) = match self.pose {
            None => (target, target_velocity),
            Some((t_u, u)) => {
                let dt = (now - t_u).max(0.0);
                let step = self.max_speed * dt + self.noise;
                let gap = target - u;
                if gap.length() <= step {
                    // On the target: held in place (still) while the reading is off.
                    let v = if implausible {
                        DVec3::ZERO
                    } else {
                        target_velocity
                    };
                    (target, v)
                } else {
                    let moved = gap * (step / gap.length());
                    let v = if dt > 0.0 { moved / dt } else { DVec3::ZERO };
                    (u + moved, v)
                }
            }
        };
        self.pose = Some((now, position_used));
        let held = implausible || position_used != position;
        if held && !implausible {
            self.catching_up += 1;
        }
        GatedPose {
            position: position_used,
            velocity: velocity_used,
            held,
            implausible,
            stale,
        }
    }

    /// Readings that were not plausible (held back) so far.
    pub fn implausible(&self) -> u64 {
        self.implausible
    }

    /// Ticks with a plausible reading that the pose was still catching up with, so far.
    pub fn catching_up(&self) -> u64 {
        self.catching_up
    }

    /// m: the largest (finite) distance of an implausible reading from the last plausible
    /// one.
    pub fn largest_jump(&self) -> f64 {
        self.largest_jump
    }

    /// m/s: the speed bound v_max.
    pub fn max_speed(&self) -> f64 {
        self.max_speed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const T: f64 = 1e-3;

    fn z(v: f64) -> DVec3 {
        DVec3::new(0.0, 0.0, v)
    }

    #[test]
    fn a_one_tick_glitch_is_held_and_the_next_good_reading_used() {
        let mut g = PoseGate::new(MAX_HAND_SPEED, POSE_NOISE);
        // A hand moving at 0.5 m/s, with a 10 mm glitch at tick 5.
        for n in 0..10 {
            let t = n as f64 * T;
            let x = z(-0.5 * t) + if n == 5 { z(-0.010) } else { DVec3::ZERO };
            let p = g.filter(t, t, x, z(-0.5));
            assert_eq!((p.held, p.implausible), (n == 5, n == 5), "tick {n}");
            let expected = if n == 5 { z(-0.5 * 4.0 * T) } else { x };
            assert_eq!(p.position, expected, "tick {n}");
            let v = if n == 5 { DVec3::ZERO } else { z(-0.5) };
            assert_eq!(p.velocity, v, "tick {n}");
        }
        assert_eq!((g.implausible(), g.catching_up()), (1, 0));
        assert!((g.largest_jump() - 0.0105).abs() < 1e-12);
    }

    #[test]
    fn a_real_move_is_followed_no_faster_than_a_hand() {
        // The device comes back from a pause 10 mm away: held while the jump is implausible
        // (2 m/s × n ms + 0.2 mm: 8.2 mm at tick 4, 10.2 mm at tick 5), then followed at
        // 2.2 mm a tick, never in one tick.
        let mut g = PoseGate::new(MAX_HAND_SPEED, POSE_NOISE);
        g.filter(0.0, 0.0, DVec3::ZERO, DVec3::ZERO);
        let away = DVec3::new(0.010, 0.0, 0.0);
        let mut last = 0.0;
        for n in 1..20 {
            let t = n as f64 * T;
            let p = g.filter(t, t, away, DVec3::ZERO);
            assert_eq!(p.implausible, n < 5, "tick {n}");
            let expected = if n < 5 {
                0.0
            } else {
                (last + 2.2e-3_f64).min(0.010)
            };
            assert!((p.position.x - expected).abs() < 1e-12, "tick {n}: {p:?}");
            assert_eq!(p.held, p.position != away, "tick {n}");
            last = p.position.x;
        }
        assert_eq!(last, 0.010);
        // Ticks 1–4 held, 5–8 catching up (2.2, 4.4, 6.6, 8.8 mm), 9 on it.
        assert_eq!((g.implausible(), g.catching_up()), (4, 4));
    }

    #[test]
    fn a_pose_repeated_between_packets_does_not_make_the_next_one_a_jump() {
        // A network device whose packets pause 20 ms (the pose read in between is the last
        // packet's, sampled then) while the hand moves on at 0.25 m/s: the packet after the
        // pause is plausible by its own sample time, and the pose catches up with it at
        // 2.2 mm a tick (5 mm behind at tick 30: 2.8, then 0.85, then on it at tick 32).
        let mut g = PoseGate::new(MAX_HAND_SPEED, POSE_NOISE);
        for n in 0..=40 {
            let t = n as f64 * T;
            let sampled = if (10..30).contains(&n) { 10.0 * T } else { t };
            let x = z(-0.25 * sampled);
            let p = g.filter(t, sampled, x, z(-0.25));
            assert!(!p.implausible, "tick {n}");
            assert_eq!(p.held, n == 30 || n == 31, "tick {n}");
            if !p.held {
                assert_eq!(p.position, x, "tick {n}");
            }
        }
        assert_eq!((g.implausible(), g.catching_up()), (0, 2));
    }

    #[test]
    fn nonsense_goes_stale_and_a_reset_takes_the_next_reading_as_it_is() {
        let mut g = PoseGate::new(MAX_HAND_SPEED, POSE_NOISE);
        g.filter(0.0, 0.0, DVec3::ZERO, DVec3::ZERO);
        let far = z(0.5);
        for n in 1..=120 {
            let t = n as f64 * T;
            let p = g.filter(t, t, if n % 2 == 0 { DVec3::NAN } else { far }, DVec3::ZERO);
            assert!(p.implausible && p.position == DVec3::ZERO, "tick {n}");
            assert_eq!(p.stale, t >= 1e-3 + IMPLAUSIBLE_STALE - 1e-12, "tick {n}");
        }
        g.reset();
        let p = g.filter(0.121, 0.121, far, DVec3::ZERO);
        assert!(!p.held && !p.stale && p.position == far);
    }

    #[test]
    fn noise_and_slow_motion_pass_and_non_finite_readings_are_held() {
        let mut g = PoseGate::new(MAX_HAND_SPEED, POSE_NOISE);
        assert!(g.filter(0.0, 0.0, DVec3::NAN, DVec3::ZERO).held);
        assert!(!g.filter(0.0, 0.0, z(0.001), DVec3::ZERO).held);
        // Two readings at the same time stamp, 0.15 mm apart: within the noise floor.
        assert!(!g.filter(0.0, 0.0, z(0.00115), DVec3::ZERO).held);
        let p = g.filter(T, T, DVec3::INFINITY, DVec3::ZERO);
        assert!(p.held && p.implausible && p.position == z(0.00115));
        let p = g.filter(2.0 * T, 2.0 * T, z(0.001), DVec3::NAN);
        assert!(!p.held && p.velocity == DVec3::ZERO);
        assert_eq!((g.implausible(), g.catching_up()), (2, 0));
    }
}
