//! Passivity of the servo loop, judged by the passivity observer (Hannaford & Ryu):
//! E(n) = Σ_{k<n} [−F_k·(x_{k+1} − x_k) + b|x_{k+1} − x_k|²/Δt_k] must stay ≥ −ε.
//!
//! The hand is a position source (the usual passivity test: whatever the force, the hand
//! follows the script), the tissue a unilateral wall of 5 kN/m (optionally half of it
//! relaxing with a 20 ms first-order lag), published by a fake physics step every tick;
//! everything runs in simulated time, so the results are deterministic and fast.
//!
//! ε = 1e-4 J: the work of 1 N over 0.1 mm, 2.4 % of the energy one 5 mm press stores on
//! the softest device (Touch, k ≈ 336 N/m through the coupling: ½·336·0.005² = 4.2 mJ) and
//! 0.4 % on the omega.3 — far below what a hand can notice. Without the passivity controller
//! the presses, taps and holds stay at E ≥ 0 exactly (the coupling alone is passive); with a
//! model 10 ms late the controller leaves at most its one-tick prediction error, measured
//! ≤ 7.7 µJ (omega.3, 20 Hz presses), 13 times below ε. The sanity cases at the end must
//! fall below −10 ε, so the tests can fail.

#[path = "haptics_common.rs"]
mod common;

use common::{keyframes, presses, simulate, Motion, PhysicsTiming, Wall};
use palpate::haptics::coupling::CouplingParams;
use palpate::haptics::{DeviceSpec, RenderMode, ServoConfig};

const EPS: f64 = 1.0e-4;

/// Keyframes (t s, z m).
type Frames = Vec<(f64, f64)>;
const FREQUENCIES: [f64; 5] = [0.5, 2.0, 5.0, 10.0, 20.0];
const WALL: f64 = 5000.0;

fn tissues() -> [(&'static str, Wall); 2] {
    [
        ("spring", Wall::spring(WALL)),
        ("lagged", Wall::viscoelastic(WALL, 0.5, 0.02)),
    ]
}

/// Presses from 2 mm above the surface to 5 mm into it, after the 1 s start-up ramp, for
/// at least 3 cycles and 3 s.
fn press(freq: f64) -> (Motion, f64) {
    (
        presses(freq, 0.002, 0.005, 1.2),
        1.2 + (3.0 / freq).max(3.0),
    )
}

fn without_controller(spec: DeviceSpec) -> ServoConfig {
    let mut c = ServoConfig::new(spec);
    c.passivity_control = false;
    c
}

#[test]
fn coupling_alone_keeps_presses_passive() {
    let mut worst = 0.0f64;
    for spec in DeviceSpec::ALL {
        let config = without_controller(spec);
        for freq in FREQUENCIES {
            for (name, wall) in tissues() {
                let (motion, seconds) = press(freq);
                let o = simulate(&config, wall, &motion, PhysicsTiming::default(), seconds);
                println!(
                    "{:8} {freq:4} Hz {name:6}: min E {:+.2e} J, final {:.2e} J, max |F| {:.2} N, clamps {}",
                    spec.name, o.min_energy, o.final_energy, o.max_force, o.clamps
                );
                assert!(
                    o.min_energy >= -EPS,
                    "{} {freq} Hz {name}: E dipped to {:e} J",
                    spec.name,
                    o.min_energy
                );
                assert!(o.max_force > 0.5, "the press must be felt");
                assert!(o.max_force <= spec.max_force + 1e-9);
                worst = worst.min(o.min_energy);
            }
        }
    }
    println!("worst minimum over presses without the controller: {worst:+.3e} J");
}

#[test]
fn contact_make_and_break_and_holding_still_are_passive() {
    // Fast taps: in and out of the tissue at 0.6 m/s, 10 times.
    let mut taps = vec![(0.0, 0.002), (1.2, 0.002)];
    for i in 0..10 {
        let t = 1.2 + i as f64 * 0.12;
        taps.extend([(t + 0.01, -0.004), (t + 0.06, -0.004), (t + 0.07, 0.002)]);
    }
    let taps_end = taps.last().map_or(0.0, |k| k.0) + 0.2;
    // Press 4 mm in, hold 3 s (the lagged tissue relaxes meanwhile), release.
    let hold = vec![
        (0.0, 0.002),
        (1.2, 0.002),
        (1.7, -0.004),
        (4.7, -0.004),
        (5.2, 0.002),
    ];
    let cases: [(&str, Frames, f64); 2] = [("taps", taps, taps_end), ("hold", hold, 5.6)];
    for spec in DeviceSpec::ALL {
        for pc in [false, true] {
            let mut config = ServoConfig::new(spec);
            config.passivity_control = pc;
            for (case, frames, seconds) in &cases {
                for (name, wall) in tissues() {
                    let motion = keyframes(frames.clone());
                    let o = simulate(&config, wall, &motion, PhysicsTiming::default(), *seconds);
                    println!(
                        "{:8} controller {pc:5} {case:4} {name:6}: min E {:+.2e} J, max |F| {:.2} N",
                        spec.name, o.min_energy, o.max_force
                    );
                    assert!(
                        o.min_energy >= -EPS,
                        "{} {case} {name}: {:e}",
                        spec.name,
                        o.min_energy
                    );
                    assert!(o.max_force > 0.5);
                }
            }
        }
    }
}

#[test]
fn late_models_stay_passive() {
    let mut worst = 0.0f64;
    for spec in DeviceSpec::ALL {
        let config = ServoConfig::new(spec);
        for late in [0.010, 0.050, 0.100] {
            let timings = [
                (
                    "delayed",
                    PhysicsTiming {
                        delay: late,
                        ..Default::default()
                    },
                ),
                (
                    "sparse",
                    PhysicsTiming {
                        every: late,
                        ..Default::default()
                    },
                ),
                (
                    "stalled",
                    PhysicsTiming {
                        stall: Some((1.5, late)),
                        ..Default::default()
                    },
                ),
            ];
            for (kind, timing) in timings {
                for freq in FREQUENCIES {
                    let (motion, seconds) = press(freq);
                    let o = simulate(&config, Wall::spring(WALL), &motion, timing, seconds);
                    println!(
                        "{:8} {kind:7} {:3.0} ms {freq:4} Hz: min E {:+.2e} J, max |F| {:.2} N, controller ticks {}, fading ticks {}",
                        spec.name, late * 1e3, o.min_energy, o.max_force, o.pc_ticks, o.fading_ticks
                    );
                    assert!(
                        o.min_energy >= -EPS,
                        "{} {kind} {late} s {freq} Hz: E dipped to {:e} J",
                        spec.name,
                        o.min_energy
                    );
                    worst = worst.min(o.min_energy);
                    if kind == "delayed" && late > 0.02 {
                        // Always older than the 20 ms threshold: faded out, never felt.
                        assert!(o.max_force < 1e-9, "{}: {}", spec.name, o.max_force);
                    }
                }
            }
        }
    }
    println!("worst minimum over late models with the controller: {worst:+.3e} J");
}

#[test]
fn start_up_ramp_while_pressing_is_passive() {
    // Pressing from t = 0.3 s, while the start-up ramp raises the gain.
    for spec in DeviceSpec::ALL {
        let config = ServoConfig::new(spec);
        for freq in [2.0, 10.0] {
            let motion = presses(freq, 0.002, 0.005, 0.3);
            let o = simulate(
                &config,
                Wall::spring(WALL),
                &motion,
                PhysicsTiming::default(),
                2.0,
            );
            println!(
                "{:8} ramp {freq:4} Hz: min E {:+.2e} J, controller ticks {}",
                spec.name, o.min_energy, o.pc_ticks
            );
            assert!(o.min_energy >= -EPS, "{}: {:e}", spec.name, o.min_energy);
        }
    }
}

/// The tests above can fail: without the coupling and the cap the same observer sees the
/// loop give energy away.
#[test]
fn observer_catches_an_unshaped_too_stiff_spring() {
    let mut config = ServoConfig::new(DeviceSpec::TOUCH);
    config.mode = RenderMode::Raw;
    let (motion, seconds) = press(2.0);
    let o = simulate(
        &config,
        Wall::spring(WALL),
        &motion,
        PhysicsTiming::default(),
        seconds,
    );
    println!("raw 5 kN/m on a Touch: min E {:+.3e} J", o.min_energy);
    assert!(o.min_energy < -10.0 * EPS, "{:e}", o.min_energy);
}

#[test]
fn observer_catches_a_coupling_above_the_passive_limit() {
    let spec = DeviceSpec::TOUCH;
    let mut config = without_controller(spec);
    // Four times 2b/T (validate() refuses this; ServoCore does what it is told).
    config.coupling = CouplingParams {
        stiffness: 4.0 * spec.max_passive_stiffness(1e-3, 0.0),
        damping: 0.0,
    };
    assert!(config.validate().is_err());
    let (motion, seconds) = press(5.0);
    let o = simulate(
        &config,
        Wall::spring(WALL),
        &motion,
        PhysicsTiming::default(),
        seconds,
    );
    println!(
        "coupling 4 × 2b/T on a Touch: min E {:+.3e} J",
        o.min_energy
    );
    assert!(o.min_energy < -10.0 * EPS, "{:e}", o.min_energy);
}

/// Why the controller exists: a model 10 ms late at contact make gives energy.
#[test]
fn late_model_without_controller_is_active() {
    let config = without_controller(DeviceSpec::OMEGA3);
    let (motion, seconds) = press(10.0);
    let timing = PhysicsTiming {
        delay: 0.010,
        ..Default::default()
    };
    let o = simulate(&config, Wall::spring(WALL), &motion, timing, seconds);
    println!(
        "omega3, 10 ms late, no controller: min E {:+.3e} J",
        o.min_energy
    );
    assert!(o.min_energy < -10.0 * EPS, "{:e}", o.min_energy);
}

/// A hand pressing on slowly 3 mm deep (2 mm/s) whose device reports 10 mm deeper for
/// `glitch_ticks` ticks at t = 1.5 s (a corrupted packet, a skipping encoder), against the
/// same hand with no glitch: with the pose gate (the tick uses the last good pose, at most 6
/// µm behind) the force never differs by more than 5 mN and the observer's energy by less
/// than ε; with the gate opened up (no speed bound) the glitch puts newtons
/// into the hand and the observer credits the device's damping for the teleport.
#[test]
fn a_pose_glitch_reaches_neither_the_hand_nor_the_observer() {
    let run = |glitch_ticks: usize, gated: bool| {
        let mut config = ServoConfig::new(DeviceSpec::TOUCH).with_duration(2.0);
        if !gated {
            config.max_hand_speed = 1.0e9;
        }
        let hand = keyframes(vec![
            (0.0, 0.002),
            (0.5, 0.002),
            (1.0, -0.003),
            (2.0, -0.005),
        ]);
        let motion: Motion = Box::new(move |t| {
            let (x, v) = hand(t);
            let tick = (t * 1e3).round() as usize;
            let glitched = (1500..1500 + glitch_ticks).contains(&tick);
            let x = if glitched {
                x - glam::DVec3::new(0.0, 0.0, 0.010)
            } else {
                x
            };
            (x, v)
        });
        simulate(
            &config,
            Wall::spring(WALL),
            &motion,
            PhysicsTiming::default(),
            2.0,
        )
    };
    let clean = run(0, true);
    let held_flag = palpate::haptics::model::flags::POSE_HELD;
    assert!(clean.trace.iter().all(|r| r.4 & held_flag == 0));
    let held_force = clean.trace[1499].3;
    assert!(held_force > 0.5, "the hand is pressed in: {held_force} N");
    for ticks in [1, 3] {
        let gated = run(ticks, true);
        let max_df = (clean.trace.iter().zip(&gated.trace))
            .map(|(a, b)| (a.3 - b.3).abs())
            .fold(0.0, f64::max);
        let held = gated.trace.iter().filter(|r| r.4 & held_flag != 0).count();
        let de = (gated.final_energy - clean.final_energy).abs();
        println!("{ticks}-tick glitch, gated: {held} ticks held, force differs by up to {max_df:.2e} N, observer energy by {de:.2e} J");
        assert_eq!(held, ticks, "every glitched reading is held, no other");
        assert!(max_df < 5e-3, "the glitch reached the hand: {max_df} N");
        assert!(de < EPS, "the observer saw the glitch: {de} J");
        assert!(gated.min_energy >= -EPS);

        let open = run(ticks, false);
        let max_df = (clean.trace.iter().zip(&open.trace))
            .map(|(a, b)| (a.3 - b.3).abs())
            .fold(0.0, f64::max);
        let de = (open.final_energy - clean.final_energy).abs();
        println!("{ticks}-tick glitch, not gated: force differs by up to {max_df:.2} N, observer energy by {de:.2e} J");
        assert!(max_df > 1.0, "sanity: the ungated glitch kicks: {max_df} N");
        assert!(de > 10.0 * EPS, "sanity: the observer credits it: {de} J");
    }
    // A reading that stays 10 mm off for 0.2 s (an encoder that slipped, a device re-homed
    // while held): the pose follows it at 2.2 mm a tick, so the force rises over ticks, not
    // in one; without the gate it jumps by newtons at once.
    let steepest = |o: &common::Outcome| {
        o.trace
            .windows(2)
            .map(|w| (w[1].3 - w[0].3).abs())
            .fold(0.0, f64::max)
    };
    let (gated, open) = (run(200, true), run(200, false));
    let (clean_step, gated_step, open_step) = (steepest(&clean), steepest(&gated), steepest(&open));
    println!("a 10 mm offset held 0.2 s: largest force change in a tick {gated_step:.3} N gated, {open_step:.3} N not (no offset: {clean_step:.4} N)");
    assert!(gated_step < 0.8, "{gated_step} N in one tick");
    assert!(open_step > 1.5, "sanity: {open_step} N");
}
