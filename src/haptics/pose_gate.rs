//! The pose gate: a device reading that lies farther from the last accepted pose than a hand
//! could have moved since is held back for the tick, so a glitch (a corrupted or spoofed
//! network packet, an encoder that skips) does not reach the coupling, the force or the
//! passivity observer.
//!
//! A reading x at time t is accepted when
//!
//! |x − x_a| ≤ v_max·(t − t_a) + δ
//!
//! with (t_a, x_a) the last accepted reading, v_max the fastest a hand moves a stylus and δ
//! a noise floor. Otherwise the servo uses x_a for the tick (and the velocity read with it).
//! The bound grows while readings are held, so a hand that really moved, or a device that
//! came back from a pause somewhere else, is accepted after |x − x_a|/v_max: the tool then
//! follows no faster than a hand can, and the coupling's force rises as it would for a fast
//! hand, not in one tick. A one-tick glitch of 10 mm at 1 kHz is held and the next good
//! reading accepted.

use glam::DVec3;

/// m/s: the fastest a hand moves a haptic stylus. Fast reaching movements peak at 1–2 m/s;
/// surgical palpation is far slower. At 1 kHz a reading may lie up to 2 mm (plus the noise
/// floor) from the last accepted one.
pub const MAX_HAND_SPEED: f64 = 2.0;

/// m: a reading may always lie this far from the last accepted one, whatever the time
/// between them (encoder quantisation and the jitter of a network device's clock; a
/// Geomagic Touch resolves 0.055 mm).
pub const POSE_NOISE: f64 = 0.2e-3;

/// What [`PoseGate::filter`] passes on for a tick.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GatedPose {
    /// m: the position to use (the reading's, or the last accepted one's when held).
    pub position: DVec3,
    /// m/s: the velocity to use (the reading's, or the last accepted one's when held).
    pub velocity: DVec3,
    /// The reading was held back.
    pub held: bool,
}

/// Holds back readings that jump farther than a hand can move (see the module doc).
#[derive(Clone, Debug)]
pub struct PoseGate {
    max_speed: f64,
    noise: f64,
    accepted: Option<(f64, DVec3, DVec3)>,
    held: u64,
    largest_jump: f64,
}

impl PoseGate {
    /// A gate that accepts readings moving at up to `max_speed` (m/s) plus `noise` (m).
    pub fn new(max_speed: f64, noise: f64) -> Self {
        PoseGate {
            max_speed,
            noise,
            accepted: None,
            held: 0,
            largest_jump: 0.0,
        }
    }

    /// The pose to use for the reading `position`, `velocity` taken at time `t` (s).
    pub fn filter(&mut self, t: f64, position: DVec3, velocity: DVec3) -> GatedPose {
        if let Some((t_a, x_a, v_a)) = self.accepted {
            let jump = (position - x_a).length();
            let reach = self.max_speed * (t - t_a).max(0.0) + self.noise;
            if jump.is_nan() || jump > reach {
                self.held += 1;
                if jump.is_finite() {
                    self.largest_jump = self.largest_jump.max(jump);
                }
                return GatedPose {
                    position: x_a,
                    velocity: v_a,
                    held: true,
                };
            }
        } else if !position.is_finite() {
            // Nothing accepted yet: a non-finite first reading is held at the origin.
            self.held += 1;
            return GatedPose {
                position: DVec3::ZERO,
                velocity: DVec3::ZERO,
                held: true,
            };
        }
        let velocity = if velocity.is_finite() {
            velocity
        } else {
            DVec3::ZERO
        };
        self.accepted = Some((t, position, velocity));
        GatedPose {
            position,
            velocity,
            held: false,
        }
    }

    /// Readings held back so far.
    pub fn held(&self) -> u64 {
        self.held
    }

    /// m: the largest (finite) distance of a held reading from the last accepted pose.
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
    fn a_one_tick_glitch_is_held_and_the_next_good_reading_accepted() {
        let mut g = PoseGate::new(MAX_HAND_SPEED, POSE_NOISE);
        // A hand moving at 0.5 m/s, with a 10 mm glitch at tick 5.
        for n in 0..10 {
            let t = n as f64 * T;
            let x = z(-0.5 * t) + if n == 5 { z(-0.010) } else { DVec3::ZERO };
            let p = g.filter(t, x, z(-0.5));
            assert_eq!(p.held, n == 5, "tick {n}");
            let expected = if n == 5 { z(-0.5 * 4.0 * T) } else { x };
            assert_eq!(p.position, expected, "tick {n}");
        }
        assert_eq!(g.held(), 1);
        assert!((g.largest_jump() - 0.0105).abs() < 1e-12);
    }

    #[test]
    fn a_real_move_is_followed_no_faster_than_a_hand() {
        // The device comes back from a pause 10 mm away: held until v_max·Δt + δ reaches it.
        let mut g = PoseGate::new(MAX_HAND_SPEED, POSE_NOISE);
        g.filter(0.0, DVec3::ZERO, DVec3::ZERO);
        let away = DVec3::new(0.010, 0.0, 0.0);
        let first = (1..20)
            .find(|&n| !g.filter(n as f64 * T, away, DVec3::ZERO).held)
            .expect("accepted");
        // 2 m/s × n ms + 0.2 mm: 8.2 mm at tick 4, 10.2 mm ≥ 10 mm at tick 5.
        assert_eq!(first, 5);
        assert_eq!(g.held(), 4);
    }

    #[test]
    fn noise_and_slow_motion_pass_and_non_finite_readings_are_held() {
        let mut g = PoseGate::new(MAX_HAND_SPEED, POSE_NOISE);
        assert!(g.filter(0.0, DVec3::NAN, DVec3::ZERO).held);
        assert!(!g.filter(0.0, z(0.001), DVec3::ZERO).held);
        // Two readings at the same time stamp, 0.15 mm apart: within the noise floor.
        assert!(!g.filter(0.0, z(0.00115), DVec3::ZERO).held);
        assert!(g.filter(T, DVec3::INFINITY, DVec3::ZERO).held);
        let p = g.filter(2.0 * T, z(0.001), DVec3::NAN);
        assert!(!p.held && p.velocity == DVec3::ZERO);
        assert_eq!(g.held(), 2);
    }
}
