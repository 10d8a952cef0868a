//! Force shaping: unilateral, the clamp keeps the direction, the start-up ramp, and the fade
//! to zero (and back) when the model is stale, the simulation diverged or the device is not
//! fresh — stage by stage and through the servo's per-tick computation.

#[path = "haptics_common.rs"]
mod common;

use common::Wall;
use glam::{DMat3, DVec3};
use palpate::haptics::model::flags;
use palpate::haptics::shaping::{
    clamp_magnitude, smoothstep, unilateral, FadeCause, ForceShaper, ShapingParams,
};
use palpate::haptics::{DeviceReading, DeviceSpec, LocalModel, ServoConfig, ServoCore};

const T: f64 = 1e-3;

#[test]
fn unilateral_never_pulls() {
    let f0 = DVec3::new(0.0, 0.0, 2.0);
    assert_eq!(
        unilateral(DVec3::new(0.1, 0.0, 1.0), f0),
        DVec3::new(0.1, 0.0, 1.0)
    );
    assert_eq!(
        unilateral(DVec3::new(0.0, 0.0, -0.5), f0),
        DVec3::ZERO,
        "a pull"
    );
    assert_eq!(
        unilateral(DVec3::new(1.0, 0.0, 0.0), f0),
        DVec3::ZERO,
        "no push along n"
    );
    assert_eq!(
        unilateral(DVec3::new(0.0, 0.0, 1.0), DVec3::ZERO),
        DVec3::ZERO,
        "no f0"
    );
}

#[test]
fn clamp_keeps_the_direction() {
    let f = DVec3::new(3.0, -4.0, 12.0); // |f| = 13
    let (c, clamped) = clamp_magnitude(f, 3.3);
    assert!(clamped);
    assert!((c.length() - 3.3).abs() < 1e-12);
    assert!(c.normalize().dot(f.normalize()) > 1.0 - 1e-12);
    assert_eq!(clamp_magnitude(f, 20.0), (f, false));
}

fn params() -> ShapingParams {
    ShapingParams::for_max_force(3.3)
}

#[test]
fn ramp_engages_when_calm_then_rises_over_its_time() {
    let p = params();
    let one = DVec3::new(0.0, 0.0, 1.0);
    // Pressing hard from the start: never engages (CHAI3D's safety rule), and a force above
    // the limit then sends nothing, so it counts as no clamp.
    let mut s = ForceShaper::new(p);
    for _ in 0..2000 {
        assert_eq!(s.shape(T, one, FadeCause::default()).gain, 0.0);
        let r = s.shape(T, one * (10.0 * p.max_force), FadeCause::default());
        assert!(r.force == DVec3::ZERO && !r.clamped);
    }
    // Engaged, a force above the limit is clamped and sent (scaled by the ramp).
    let mut s = ForceShaper::new(p);
    for _ in 0..p.engage_ticks {
        s.shape(T, DVec3::ZERO, FadeCause::default());
    }
    let r = s.shape(T, one * (10.0 * p.max_force), FadeCause::default());
    assert!(r.clamped && r.force != DVec3::ZERO);
    // Calm for engage_ticks, then the gain follows smoothstep(t / ramp_time).
    let mut s = ForceShaper::new(p);
    for _ in 0..p.engage_ticks {
        s.shape(T, DVec3::ZERO, FadeCause::default());
    }
    // (the fade-in of 0.2 s runs alongside from the first tick)
    let mut gains = Vec::new();
    for _ in 0..1200 {
        let r = s.shape(T, one * 0.1, FadeCause::default());
        gains.push(r.gain);
    }
    assert!(gains.windows(2).all(|w| w[1] >= w[0]), "monotone");
    let at = |t: f64| gains[(t / T) as usize - 1];
    let expect = |t: f64| smoothstep((t + 1e-9) / p.ramp_time);
    assert!(
        (at(0.5) - expect(0.5)).abs() < 2e-3,
        "{} vs {}",
        at(0.5),
        expect(0.5)
    );
    assert!(at(0.9) < 1.0);
    assert_eq!(at(1.1), 1.0);
    assert!(
        gains
            .windows(2)
            .all(|w| w[1] - w[0] <= 1.5 * T / p.fade_in + 1e-12),
        "smooth"
    );
}

/// A shaper running at full gain.
fn engaged() -> ForceShaper {
    let mut s = ForceShaper::new(params());
    for _ in 0..1500 {
        s.shape(T, DVec3::ZERO, FadeCause::default());
    }
    s
}

#[test]
fn fades_out_and_back_for_each_cause() {
    let p = params();
    let f = DVec3::new(0.0, 0.0, 2.0);
    let causes = [
        FadeCause {
            stale: true,
            ..Default::default()
        },
        FadeCause {
            diverged: true,
            ..Default::default()
        },
        FadeCause {
            device_stale: true,
            ..Default::default()
        },
    ];
    for cause in causes {
        let mut s = engaged();
        assert_eq!(s.shape(T, f, FadeCause::default()).gain, 1.0);
        let mut last = 1.0;
        let mut ticks_to_zero = None;
        for k in 1..=100 {
            let r = s.shape(T, f, cause);
            assert!(r.gain <= last, "{cause:?}: not monotone");
            assert!(
                last - r.gain <= 1.5 * T / p.fade_out + 1e-12,
                "{cause:?}: a jump"
            );
            assert!(r.fading);
            last = r.gain;
            if r.gain == 0.0 && ticks_to_zero.is_none() {
                ticks_to_zero = Some(k);
            }
        }
        assert_eq!(
            ticks_to_zero,
            Some((p.fade_out / T).round() as usize),
            "{cause:?}"
        );
        // Back in over fade_in once the cause clears.
        let mut k_full = None;
        for k in 1..=400 {
            let r = s.shape(T, f, FadeCause::default());
            if r.gain == 1.0 && k_full.is_none() {
                k_full = Some(k);
            }
        }
        assert_eq!(k_full, Some((p.fade_in / T).round() as usize), "{cause:?}");
    }
}

/// The servo's per-tick computation, pressing 3 mm into a 5 kN/m wall on a Touch, with the
/// model's age, divergence flag and the device's freshness switched during the run.
#[test]
fn servo_fades_stale_diverged_and_not_fresh() {
    let config = ServoConfig::new(DeviceSpec::TOUCH);
    let stale_after = config.shaping.stale_after;
    enum Fault {
        Stale,
        Diverged,
        NotFinite,
        DeviceStale,
    }
    for fault in [
        Fault::Stale,
        Fault::Diverged,
        Fault::NotFinite,
        Fault::DeviceStale,
    ] {
        let mut core = ServoCore::new(&config);
        let mut wall = Wall::spring(5000.0);
        let mut model = LocalModel::default();
        let mut seq = 0;
        let mut forces = Vec::new();
        for n in 0..2500 {
            let t = n as f64 * T;
            let fault_on = (1.5..2.0).contains(&t);
            let z = if t < 0.1 { 0.002 } else { -0.003 };
            let reading = DeviceReading {
                position: DVec3::new(0.0, 0.0, z),
                fresh: !(fault_on && matches!(fault, Fault::DeviceStale)),
                ..Default::default()
            };
            let out = core.tick(t, &reading, &model, seq);
            let frozen = fault_on && matches!(fault, Fault::Stale);
            if !frozen {
                model = wall.step(T, out.proxy, t);
                if fault_on && matches!(fault, Fault::Diverged) {
                    model.diverged = true;
                    model.force = DVec3::new(0.0, 0.0, 1e6); // garbage, must not be felt
                }
                if fault_on && matches!(fault, Fault::NotFinite) {
                    model.stiffness = DMat3::from_diagonal(DVec3::new(f64::NAN, 0.0, 0.0));
                }
                seq += 1;
            }
            forces.push((out.command.force.z, out.command.flags));
        }
        let f = |t: f64| forces[(t / T).round() as usize];
        let full = f(1.49).0;
        assert!(full > 0.9, "3 mm through the coupling: {full} N");
        assert!(forces
            .iter()
            .all(|x| x.0.abs() <= config.spec.max_force + 1e-12));
        // During the fault: fades (no jump), reaches zero, stays there.
        let start = match fault {
            Fault::Stale => 1.5 + stale_after,
            _ => 1.5,
        };
        let first = f(start + 2.0 * T).0;
        assert!(
            first > 0.8 * full,
            "a fade, not a drop: {first} N after the fault"
        );
        assert_eq!(f(start + config.shaping.fade_out + 2.0 * T).0, 0.0);
        assert_eq!(f(1.99).0, 0.0);
        let flag = match fault {
            Fault::Stale => flags::STALE,
            Fault::Diverged | Fault::NotFinite => flags::DIVERGED,
            Fault::DeviceStale => flags::DEVICE_STALE,
        };
        assert!(f(1.9).1 & flag != 0 && f(1.9).1 & flags::FADING != 0);
        // Back after the fault clears.
        assert!(
            (f(2.49).0 - full).abs() < 0.01 * full,
            "{} vs {full}",
            f(2.49).0
        );
    }
}

#[test]
fn no_force_out_of_contact_or_before_the_first_model() {
    let config = ServoConfig::new(DeviceSpec::OMEGA3);
    let mut core = ServoCore::new(&config);
    let reading = DeviceReading {
        position: DVec3::new(0.0, 0.0, -0.003),
        fresh: true,
        ..Default::default()
    };
    // No model yet (sequence 0): nothing, and the proxy sits on the device.
    for n in 0..1500 {
        let out = core.tick(n as f64 * T, &reading, &LocalModel::default(), 0);
        assert_eq!(out.command.force, DVec3::ZERO);
        assert_eq!(out.proxy, reading.position);
    }
    // A model that is not in contact renders nothing, whatever its numbers.
    let model = LocalModel {
        force: DVec3::new(0.0, 0.0, 5.0),
        stiffness: DMat3::from_diagonal(DVec3::splat(-1000.0)),
        in_contact: false,
        stamp: 1.5,
        ..Default::default()
    };
    let out = core.tick(1.5, &reading, &model, 1);
    assert_eq!(out.command.force, DVec3::ZERO);
}

/// A network device's first pose 50 mm from home (before it, the device reads the origin and
/// is not fresh): taken where it is — no tick held, no catch-up from the origin, no damping
/// credit in the observer for the jump — and the same after the device is lost and comes
/// back elsewhere.
#[test]
fn a_device_fresh_again_is_taken_where_it_is() {
    let config = ServoConfig::new(DeviceSpec::TOUCH);
    let mut core = ServoCore::new(&config);
    let far = DVec3::new(0.05, 0.0, 0.02);
    let mut t = 0.0;
    let mut tick = |core: &mut ServoCore, position: DVec3, fresh: bool| {
        let reading = DeviceReading {
            position,
            fresh,
            sampled: fresh.then_some(t),
            ..Default::default()
        };
        let out = core.tick(t, &reading, &LocalModel::default(), 0);
        t += T;
        out
    };
    for _ in 0..50 {
        tick(&mut core, DVec3::ZERO, false);
    }
    for _ in 0..50 {
        let out = tick(&mut core, far, true);
        assert_eq!(out.pose.position, far);
        assert_eq!(out.command.flags & flags::POSE_HELD, 0);
    }
    // Lost for 0.2 s, back 30 mm away.
    for _ in 0..200 {
        tick(&mut core, far, false);
    }
    let back = far + DVec3::new(0.0, 0.03, 0.0);
    let out = tick(&mut core, back, true);
    assert_eq!(out.pose.position, back);
    assert_eq!(core.counters().ticks, 301);
    assert!(
        core.observer().energy().abs() < 1e-12,
        "the observer credited {} J for the jumps",
        core.observer().energy()
    );
    // Without the restart a 30 mm jump in a tick is held back (the sanity case).
    let out = tick(&mut core, back + DVec3::new(0.0, 0.03, 0.0), true);
    assert!(out.pose.implausible && out.pose.position == back);
}
