//! Helpers shared by the haptics tests (included with `#[path]`): a fake tissue that
//! publishes a local model, prescribed hand motions, and a driver that runs the servo's
//! per-tick computation against them in simulated time (deterministic, fast).
#![allow(dead_code)]

use glam::{DMat3, DVec3};
use palpate::haptics::{DeviceReading, LocalModel, ServoConfig, ServoCore, ToolCommand};
use std::collections::VecDeque;

/// A tissue filling z < 0 (surface z = 0, normal +z) that pushes the tool out with a
/// unilateral spring k1 in parallel with a Maxwell branch (spring k2, relaxation time tau:
/// a first-order lag of part of the force). Physically passive.
#[derive(Clone, Debug)]
pub struct Wall {
    /// N/m.
    pub k1: f64,
    /// N/m (0: a pure spring).
    pub k2: f64,
    /// s.
    pub tau: f64,
    maxwell: f64,
    last_pen: f64,
}

impl Wall {
    pub fn spring(k: f64) -> Self {
        Wall {
            k1: k,
            k2: 0.0,
            tau: 1.0,
            maxwell: 0.0,
            last_pen: 0.0,
        }
    }

    /// k1 + k2 = k, with a fraction `lag` of it relaxing with time constant `tau`.
    pub fn viscoelastic(k: f64, lag: f64, tau: f64) -> Self {
        Wall {
            k1: k * (1.0 - lag),
            k2: k * lag,
            tau,
            maxwell: 0.0,
            last_pen: 0.0,
        }
    }

    /// Advance the tissue `dt` with the tool at `x`; return the model there.
    pub fn step(&mut self, dt: f64, x: DVec3, stamp: f64) -> LocalModel {
        let pen = -x.z;
        if pen > 0.0 {
            let dpen = pen - self.last_pen.max(0.0);
            self.maxwell = (self.maxwell + self.k2 * dpen) * (-dt / self.tau).exp();
        } else {
            self.maxwell = 0.0;
        }
        self.last_pen = pen;
        let f = (self.k1 * pen.max(0.0) + self.maxwell).max(0.0);
        let in_contact = pen > 0.0 && f > 0.0;
        let k = if in_contact { self.k1 + self.k2 } else { 0.0 };
        LocalModel {
            force: DVec3::new(0.0, 0.0, f),
            stiffness: DMat3::from_diagonal(DVec3::new(0.0, 0.0, -k)),
            contact_stiffness: DMat3::ZERO,
            proxy: x,
            stamp,
            sim_time: stamp,
            diverged: false,
            in_contact,
            penetration: pen.max(0.0),
            active_particles: 0,
            ..Default::default()
        }
    }
}

/// A prescribed hand motion: position and velocity at t.
pub type Motion = Box<dyn Fn(f64) -> (DVec3, DVec3)>;

/// Presses at `freq` Hz from `top` (m above the surface) down to `depth` (m below it),
/// starting at `start` s (held at `top` before).
pub fn presses(freq: f64, top: f64, depth: f64, start: f64) -> Motion {
    let a = top + depth;
    let w = 2.0 * std::f64::consts::PI * freq;
    Box::new(move |t| {
        if t < start {
            return (DVec3::new(0.0, 0.0, top), DVec3::ZERO);
        }
        let s = t - start;
        let z = top - a * (1.0 - (w * s).cos()) / 2.0;
        let vz = -a * w * (w * s).sin() / 2.0;
        (DVec3::new(0.0, 0.0, z), DVec3::new(0.0, 0.0, vz))
    })
}

/// Piecewise-linear keyframes (t, z), x and y = 0.
pub fn keyframes(frames: Vec<(f64, f64)>) -> Motion {
    Box::new(move |t| {
        let n = frames.len();
        if t <= frames[0].0 {
            return (DVec3::new(0.0, 0.0, frames[0].1), DVec3::ZERO);
        }
        for i in 1..n {
            let (t0, z0) = frames[i - 1];
            let (t1, z1) = frames[i];
            if t <= t1 {
                let v = (z1 - z0) / (t1 - t0);
                return (
                    DVec3::new(0.0, 0.0, z0 + v * (t - t0)),
                    DVec3::new(0.0, 0.0, v),
                );
            }
        }
        (DVec3::new(0.0, 0.0, frames[n - 1].1), DVec3::ZERO)
    })
}

/// How the fake physics thread delivers its models.
#[derive(Clone, Copy, Debug, Default)]
pub struct PhysicsTiming {
    /// s between published models (0: every tick).
    pub every: f64,
    /// s: each model is computed from the tool command this old (a slow pipeline).
    pub delay: f64,
    /// (start, length) s: no model is published in this window (a stalled physics thread).
    pub stall: Option<(f64, f64)>,
}

/// What a simulated run produced.
#[derive(Clone, Debug)]
pub struct Outcome {
    pub min_energy: f64,
    pub final_energy: f64,
    pub max_force: f64,
    pub clamps: u64,
    pub pc_ticks: u64,
    pub fading_ticks: u64,
    pub max_penetration: f64,
    /// Per tick: (t, device z, proxy z, force z, gain-carrying flags).
    pub trace: Vec<(f64, f64, f64, f64, u32)>,
}

/// Run `seconds` of the servo core at its rate against `tissue` with the hand following
/// `motion` (a position source, the usual passivity test), in simulated time.
pub fn simulate(
    config: &ServoConfig,
    mut tissue: Wall,
    motion: &Motion,
    timing: PhysicsTiming,
    seconds: f64,
) -> Outcome {
    let mut core = ServoCore::new(config);
    let period = config.period();
    let ticks = (seconds / period).round() as usize;
    let mut model = LocalModel::default();
    let mut sequence = 0u64;
    let mut commands: VecDeque<ToolCommand> = VecDeque::new();
    let mut last_physics = f64::NEG_INFINITY;
    let mut max_pen: f64 = 0.0;
    let mut trace = Vec::with_capacity(ticks);
    for n in 0..ticks {
        let t = n as f64 * period;
        let (x, v) = motion(t);
        let reading = DeviceReading {
            position: x,
            velocity: v,
            buttons: 0,
            fresh: true,
            sampled: None,
        };
        let out = core.tick(t, &reading, &model, sequence);
        trace.push((t, x.z, out.proxy.z, out.command.force.z, out.command.flags));
        commands.push_back(ToolCommand {
            position: out.proxy,
            velocity: v,
            device_position: x,
            stamp: t,
            buttons: 0,
            tick: n as u64,
        });
        // The physics step after the servo tick: its model is seen from the next tick on.
        let stalled = timing.stall.is_some_and(|(s, len)| t >= s && t < s + len);
        if t - last_physics + 1e-12 >= timing.every && !stalled {
            while commands.len() > 1 && commands[1].stamp <= t - timing.delay + 1e-12 {
                commands.pop_front();
            }
            let cmd = commands[0];
            if cmd.stamp <= t - timing.delay + 1e-12 {
                let dt = if last_physics.is_finite() {
                    t - last_physics
                } else {
                    period
                };
                model = tissue.step(dt, cmd.position, cmd.stamp);
                max_pen = max_pen.max(model.penetration);
                sequence += 1;
                last_physics = t;
            }
        }
    }
    let c = core.counters();
    Outcome {
        min_energy: core.observer().min_energy(),
        final_energy: core.observer().energy(),
        max_force: c.max_force,
        clamps: c.force_clamps,
        pc_ticks: c.passivity_control_ticks,
        fading_ticks: c.fading_ticks,
        max_penetration: max_pen,
        trace,
    }
}

/// A fake physics thread: every ~1 ms (sleep), reads the tool command, steps `tissue` with
/// the tool there and publishes the model stamped with the command's time. Stops when
/// `stop` is set; returns the number of models published.
pub fn spawn_fake_physics(
    mut physics: palpate::haptics::PhysicsLink,
    mut tissue: Wall,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
) -> std::thread::JoinHandle<u64> {
    std::thread::spawn(move || {
        let mut published = 0u64;
        let mut last = physics.clock().now();
        while !stop.load(std::sync::atomic::Ordering::Relaxed) {
            let (tool, _) = physics.tool();
            let now = physics.clock().now();
            let model = tissue.step((now - last).max(1e-4), tool.position, tool.stamp);
            last = now;
            physics.publish(model);
            published += 1;
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        published
    })
}

/// A unique temporary file path for a test.
pub fn temp_path(name: &str) -> std::path::PathBuf {
    std::env::temp_dir().join(format!("palpate-haptics-{}-{name}", std::process::id()))
}
