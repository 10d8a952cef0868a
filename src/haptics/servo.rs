//! The servo loop: 1 kHz on absolute deadlines, device → coupling → shaping → device.
//!
//! [`ServoCore`] is one tick's computation, free of clocks and threads (the loop drives it;
//! tests drive it in simulated time). [`run_servo`] is the loop; [`spawn_servo`] runs it on
//! its own thread and returns a [`ServoHandle`] to stop it and collect the [`ServoReport`].
//!
//! Per tick: read the device → gate the pose ([`super::pose_gate`]: a reading farther from
//! the last plausible one than a hand could have moved is held back, and the pose used moves
//! no faster than a hand) → observe passivity → read the local model → coupling (proxy) →
//! publish the tool command → shape → passivity control → send → log. Inside the loop
//! nothing allocates, no lock is taken (the slots are lock-free, the device calls are
//! non-blocking), wgpu is never touched.
//!
//! Timing: deadlines are absolute (`start + n·T` on the monotonic clock); the loop sleeps
//! until `spin` (150 µs) before a deadline, then spins, which removes the timer slack from
//! the median. When a tick overruns, the loop skips to the next deadline still in the future
//! and counts the ones it skipped (no burst of catch-up ticks).

use super::coupling::{CouplingParams, VirtualCoupling};
use super::device::{DeviceReading, DeviceSpec, DeviceStats, HapticDevice};
use super::link::ServoLink;
use super::log::{TickLog, TickRecord};
use super::model::{flags, ForceCommand, LocalModel, ToolCommand};
use super::observer::{passivity_control, PassivityObserver};
use super::pose_gate::{GatedPose, PoseGate, MAX_HAND_SPEED, POSE_NOISE};
use super::shaping::{clamp_magnitude, FadeCause, ForceShaper, ShapingParams};
use crate::error::{PalpateError, Result};
use glam::{DMat3, DVec3};
use serde::Serialize;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How the force is computed from the local model.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RenderMode {
    /// Virtual coupling and every shaping stage (the default).
    Coupled,
    /// Diagnostics only: F = f0 + K·(x_d − x0) at the device position when the model is in
    /// contact, nothing else (no coupling, cap, clamp, ramp, fade or passivity control).
    Raw,
}

/// The most ticks a session's log holds: one hour at 1 kHz (80 B a tick: about 290 MB,
/// preallocated; `haptic.csv` is streamed to disk, about 0.6 GB for an hour).
/// A longer session logs its first hour and counts the rest in `unlogged_ticks`.
pub const MAX_LOG_TICKS: usize = 3_600_000;

/// Servo loop parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ServoConfig {
    /// The device's specification.
    pub spec: DeviceSpec,
    /// Hz, tick rate (default 1000).
    pub rate_hz: f64,
    /// s, run length; `None` runs until stopped.
    pub duration: Option<f64>,
    /// s, the loop sleeps until this long before a deadline, then spins (default 150 µs,
    /// above Linux's 50 µs timer slack plus the wake-up latency of a loaded machine).
    pub spin: f64,
    /// The virtual coupling (default [`CouplingParams::passive`]).
    pub coupling: CouplingParams,
    /// Force shaping (default [`ShapingParams::for_max_force`] of the spec).
    pub shaping: ShapingParams,
    /// N·s/m, the device's physical damping b credited by the passivity observer (default
    /// [`DeviceSpec::physical_damping`]).
    pub physical_damping: f64,
    /// Add the passivity controller's damping when the observer's energy is negative
    /// (default on).
    pub passivity_control: bool,
    /// Coupled (default) or raw rendering.
    pub mode: RenderMode,
    /// m/s: the fastest the pose gate lets the device's position move (default
    /// [`MAX_HAND_SPEED`]); a reading beyond it is held back for the tick.
    pub max_hand_speed: f64,
    /// Ticks the log holds when `duration` is `None` (default 600 000: 10 min at 1 kHz,
    /// ≈ 48 MB); with a duration the log holds the whole run up to [`MAX_LOG_TICKS`].
    pub log_capacity: usize,
}

impl ServoConfig {
    /// The defaults for `spec` at 1 kHz.
    pub fn new(spec: DeviceSpec) -> Self {
        let rate_hz = 1000.0;
        ServoConfig {
            spec,
            rate_hz,
            duration: None,
            spin: 150e-6,
            coupling: CouplingParams::passive(&spec, 1.0 / rate_hz),
            shaping: ShapingParams::for_max_force(spec.max_force),
            physical_damping: spec.physical_damping(),
            passivity_control: true,
            mode: RenderMode::Coupled,
            max_hand_speed: MAX_HAND_SPEED,
            log_capacity: 600_000,
        }
    }

    /// The same with a run length, s.
    pub fn with_duration(mut self, seconds: f64) -> Self {
        self.duration = Some(seconds);
        self
    }

    /// T = 1/rate, s.
    pub fn period(&self) -> f64 {
        1.0 / self.rate_hz
    }

    /// N/m, k_max = min(2(b − |b_c|)/T, spec.max_stiffness): the stiffness the loop keeps
    /// passive.
    pub fn max_passive_stiffness(&self) -> f64 {
        let colgate = 2.0 * (self.physical_damping - self.coupling.damping.abs()) * self.rate_hz;
        colgate.min(self.spec.max_stiffness).max(0.0)
    }

    /// Ticks the log is allocated for: the whole run, at most [`MAX_LOG_TICKS`] (later
    /// ticks are counted in `unlogged_ticks`, not logged).
    pub fn log_ticks(&self) -> usize {
        match self.duration {
            Some(d) => ((d * self.rate_hz).ceil() as usize + 16).min(MAX_LOG_TICKS),
            None => self.log_capacity,
        }
    }

    /// Check the parameters; errors are one line.
    pub fn validate(&self) -> Result<()> {
        let bad = |what: String| Err(PalpateError::Usage(format!("haptic servo: {what}")));
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0 && self.rate_hz <= 100_000.0) {
            return bad(format!("rate {} Hz is not in (0, 100000]", self.rate_hz));
        }
        if let Some(d) = self.duration {
            if !(0.0..=1.0e6).contains(&d) {
                return bad(format!("duration {d} s is not in [0, 1e6]"));
            }
        }
        if !(self.spin >= 0.0 && self.spin < 1.0) {
            return bad(format!("spin {} s is not in [0, 1)", self.spin));
        }
        let k = self.coupling.stiffness;
        if !(k.is_finite() && k > 0.0) {
            return bad(format!("coupling stiffness {k} N/m must be > 0"));
        }
        if !(self.coupling.damping.is_finite() && self.coupling.damping >= 0.0) {
            return bad(format!(
                "coupling damping {} N·s/m must be ≥ 0",
                self.coupling.damping
            ));
        }
        if k > self.max_passive_stiffness() * (1.0 + 1e-9) && self.mode == RenderMode::Coupled {
            return bad(format!(
                "coupling stiffness {k} N/m is above the passive limit {:.1} N/m (2(b − b_c)/T and the device's {} N/m)",
                self.max_passive_stiffness(),
                self.spec.max_stiffness
            ));
        }
        if !(self.max_hand_speed.is_finite() && self.max_hand_speed > 0.0) {
            return bad(format!(
                "max hand speed {} m/s must be > 0",
                self.max_hand_speed
            ));
        }
        if !(self.shaping.max_force.is_finite() && self.shaping.max_force > 0.0) {
            return bad(format!(
                "max force {} N must be > 0",
                self.shaping.max_force
            ));
        }
        Ok(())
    }
}

/// Counters a [`ServoCore`] keeps.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Counters {
    /// Ticks computed.
    pub ticks: u64,
    /// New models seen.
    pub model_updates: u64,
    /// Ticks before the first model.
    pub ticks_without_model: u64,
    /// Ticks whose model was stale (or absent).
    pub stale_ticks: u64,
    /// Ticks with a fade gain below 1.
    pub fading_ticks: u64,
    /// Ticks whose force magnitude was clamped.
    pub force_clamps: u64,
    /// Ticks in which the tissue was stiffer than the passive limit, so the coupling did
    /// the capping.
    pub stiffness_limited_ticks: u64,
    /// Ticks the passivity controller acted.
    pub passivity_control_ticks: u64,
    /// N, largest force magnitude sent.
    pub max_force: f64,
}

/// What one tick produced.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TickOutput {
    /// m: the proxy position to hand the physics thread.
    pub proxy: DVec3,
    /// The force to send.
    pub command: ForceCommand,
    /// The log row (lateness and work time filled in by the loop).
    pub record: TickRecord,
    /// The device pose the tick used (the reading; held in place or catching up with it
    /// when the pose gate did not take it).
    pub pose: GatedPose,
}

/// One tick's computation: coupling, shaping, passivity observer and controller.
#[derive(Clone, Debug)]
pub struct ServoCore {
    config: ServoConfig,
    coupling: VirtualCoupling,
    shaper: ForceShaper,
    observer: PassivityObserver,
    gate: PoseGate,
    device_was_fresh: bool,
    k_max: f64,
    last_time: Option<f64>,
    last_sequence: u64,
    last_good: Option<LocalModel>,
    counters: Counters,
}

impl ServoCore {
    /// A core for `config` (validate it first with [`ServoConfig::validate`]).
    pub fn new(config: &ServoConfig) -> Self {
        ServoCore {
            config: *config,
            coupling: VirtualCoupling::new(config.coupling),
            shaper: ForceShaper::new(config.shaping),
            observer: PassivityObserver::new(config.physical_damping),
            gate: PoseGate::new(config.max_hand_speed, POSE_NOISE),
            device_was_fresh: false,
            k_max: config.max_passive_stiffness(),
            last_time: None,
            last_sequence: 0,
            last_good: None,
            counters: Counters::default(),
        }
    }

    /// One tick at loop time `now` (s) with the device `reading` and the newest `model`
    /// from the slot with its sequence number (0 = none published yet).
    pub fn tick(
        &mut self,
        now: f64,
        reading: &DeviceReading,
        model: &LocalModel,
        sequence: u64,
    ) -> TickOutput {
        let cfg = &self.config;
        let dt = self.last_time.map_or(cfg.period(), |t| (now - t).max(0.0));
        self.last_time = Some(now);
        let c = &mut self.counters;
        c.ticks += 1;

        // A device fresh again (back after its keep-alive expired, or a network device's
        // first packet) is taken where it is: the force faded out meanwhile and fades back
        // in, and the observer does not count the jump as motion.
        let back = reading.fresh && !self.device_was_fresh;
        self.device_was_fresh = reading.fresh;
        if back {
            self.gate.reset();
        }
        // The observer, like everything after it, sees the pose used: a held reading moves
        // nothing, a catch-up moves no faster than a hand.
        let pose = self.gate.filter(
            now,
            reading.sampled.unwrap_or(now),
            reading.position,
            reading.velocity,
        );
        let energy = if back {
            self.observer.restart(now, pose.position);
            self.observer.energy()
        } else {
            self.observer.observe(now, pose.position)
        };

        let has_model = sequence > 0;
        if sequence > self.last_sequence {
            self.last_sequence = sequence;
            c.model_updates += 1;
        }
        if !has_model {
            c.ticks_without_model += 1;
        }
        let age = if has_model {
            now - model.stamp
        } else {
            f64::INFINITY
        };
        let usable = has_model && model.is_finite() && !model.diverged;
        if usable {
            self.last_good = Some(*model);
        }
        // A diverged model fades out from the last good one rather than dropping at once.
        let render = if usable { Some(*model) } else { self.last_good };
        // (NaN ages compare false: stale.)
        let fresh_model = has_model && age <= cfg.shaping.stale_after;
        let cause = FadeCause {
            stale: !fresh_model,
            diverged: has_model && !usable,
            device_stale: !reading.fresh || pose.stale,
        };
        if cause.stale {
            c.stale_ticks += 1;
        }

        let x_d = pose.position;
        let mut flag_bits = if pose.held { flags::POSE_HELD } else { 0 };
        let (proxy, mut force, model_force, stiffness, gain) = match cfg.mode {
            RenderMode::Coupled => {
                let out = self
                    .coupling
                    .update(render.as_ref(), x_d, pose.velocity, dt);
                if out.tissue_stiffness > self.k_max {
                    c.stiffness_limited_ticks += 1;
                }
                let s = self.shaper.shape(dt, out.force, cause);
                let unclamped = out.force.length();
                let clamp_ratio = if s.clamped && unclamped > 0.0 {
                    cfg.shaping.max_force / unclamped
                } else {
                    1.0
                };
                if s.clamped {
                    c.force_clamps += 1;
                    flag_bits |= flags::CLAMPED;
                }
                if s.fading {
                    c.fading_ticks += 1;
                    flag_bits |= flags::FADING;
                }
                if s.ramping {
                    flag_bits |= flags::RAMPING;
                }
                let k_hand = out.stiffness * (s.gain * clamp_ratio);
                (out.proxy, s.force, s.force, k_hand, s.gain)
            }
            RenderMode::Raw => {
                let f = match render {
                    Some(m) if m.in_contact => m.force_at(x_d),
                    _ => DVec3::ZERO,
                };
                let k = render.map_or(DMat3::ZERO, |m| m.stiffness);
                (x_d, f, f, k, 1.0)
            }
        };

        if cfg.passivity_control && cfg.mode == RenderMode::Coupled && reading.fresh {
            let (_, dt_v) = self.observer.last_velocity();
            let (f_pc, alpha) = passivity_control(
                energy,
                force,
                self.observer.predicted_velocities(),
                dt_v,
                cfg.physical_damping,
                cfg.spec.max_damping,
            );
            if alpha > 0.0 {
                let (f, clamped) = clamp_magnitude(force + f_pc, cfg.shaping.max_force);
                force = f;
                if clamped && flag_bits & flags::CLAMPED == 0 {
                    c.force_clamps += 1;
                    flag_bits |= flags::CLAMPED;
                }
                c.passivity_control_ticks += 1;
                flag_bits |= flags::PASSIVITY_CONTROL;
            }
        }
        self.observer.set_force(force);
        c.max_force = c.max_force.max(force.length());

        let (in_contact, penetration, active) = render.map_or((false, 0.0, 0), |m| {
            (m.in_contact, m.penetration, m.active_particles)
        });
        if in_contact {
            flag_bits |= flags::IN_CONTACT;
        }
        if cause.diverged {
            flag_bits |= flags::DIVERGED;
        }
        if cause.stale {
            flag_bits |= flags::STALE;
        }
        if cause.device_stale {
            flag_bits |= flags::DEVICE_STALE;
        }
        let f32x3 = |v: DVec3| [v.x as f32, v.y as f32, v.z as f32];
        TickOutput {
            proxy,
            command: ForceCommand {
                force,
                model_force,
                stiffness,
                at: x_d,
                model_age: age,
                flags: flag_bits,
            },
            record: TickRecord {
                time: now,
                lateness_us: 0.0,
                work_us: 0.0,
                // What the device read (the pose used is the last accepted one when held).
                device: f32x3(reading.position),
                proxy: f32x3(proxy),
                force: f32x3(force),
                penetration: penetration as f32,
                active_particles: active,
                model_age_ms: if has_model {
                    (age * 1e3) as f32
                } else {
                    f32::NAN
                },
                gain: gain as f32,
                energy: self.observer.energy() as f32,
                flags: flag_bits,
            },
            pose,
        }
    }

    /// The passivity observer.
    pub fn observer(&self) -> &PassivityObserver {
        &self.observer
    }

    /// The counters so far.
    pub fn counters(&self) -> &Counters {
        &self.counters
    }

    /// The configuration.
    pub fn config(&self) -> &ServoConfig {
        &self.config
    }

    /// N/m: the coupling stiffness in use.
    pub fn coupling_stiffness(&self) -> f64 {
        self.coupling.params().stiffness
    }
}

/// p50, p99, p99.9 and max of a sample (nearest rank); NaN (JSON null) when empty.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Percentiles {
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// 99.9th percentile.
    pub p99_9: f64,
    /// Largest.
    pub max: f64,
}

impl Percentiles {
    /// The percentiles of `values` (sorted in place; NaNs ignored).
    pub fn of(values: &mut Vec<f32>) -> Percentiles {
        values.retain(|v| !v.is_nan());
        if values.is_empty() {
            return Percentiles {
                p50: f64::NAN,
                p99: f64::NAN,
                p99_9: f64::NAN,
                max: f64::NAN,
            };
        }
        values.sort_unstable_by(f32::total_cmp);
        let n = values.len();
        let rank = |p: f64| values[((p * n as f64).ceil() as usize).clamp(1, n) - 1] as f64;
        Percentiles {
            p50: rank(0.50),
            p99: rank(0.99),
            p99_9: rank(0.999),
            max: values[n - 1] as f64,
        }
    }
}

/// The loop statistics `palpate haptic` writes into summary.json.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ServoStats {
    /// Ticks run.
    pub ticks: u64,
    /// s, wall time from the first deadline to the end of the last tick.
    pub wall_seconds: f64,
    /// Hz, achieved rate: ticks / wall_seconds.
    pub rate_hz: f64,
    /// Hz, the rate asked for.
    pub target_rate_hz: f64,
    /// µs, how late each tick started after its deadline.
    pub lateness_us: Percentiles,
    /// µs, the work of a tick (read → send).
    pub work_us: Percentiles,
    /// Deadlines skipped after overruns.
    pub missed_deadlines: u64,
    /// ms, age of the model used, over ticks that had one.
    pub model_age_ms: Percentiles,
    /// New models received.
    pub model_updates: u64,
    /// Ticks before the first model.
    pub ticks_without_model: u64,
    /// Ticks with a stale (or no) model.
    pub stale_ticks: u64,
    /// Ticks with the fade gain below 1.
    pub fading_ticks: u64,
    /// Ticks whose force was clamped to the device's limit.
    pub force_clamps: u64,
    /// Ticks where the tissue was stiffer than the passive limit (the coupling capped it).
    pub stiffness_limited_ticks: u64,
    /// N, the largest force sent.
    pub max_force_n: f64,
    /// J, the passivity observer's minimum E(n) (≥ 0: the loop never gave energy).
    pub passivity_min_energy_j: f64,
    /// J, E at the end.
    pub passivity_final_energy_j: f64,
    /// N·s/m, the physical damping b the observer credits.
    pub passivity_damping: f64,
    /// Ticks the passivity controller acted.
    pub passivity_control_ticks: u64,
    /// N/m, the coupling spring k_c.
    pub coupling_stiffness: f64,
    /// N/m, k_max = min(2b/T, device max stiffness).
    pub max_passive_stiffness: f64,
    /// Ticks run but not logged (log full).
    pub unlogged_ticks: u64,
    /// Ticks whose device reading the pose gate held back: it lay farther from the last
    /// plausible one than `max_hand_speed` allows since (a glitching device or network; a
    /// network device slower than the loop repeats a bad pose over several ticks).
    pub held_poses: u64,
    /// m, the largest distance of a held reading from the last plausible one (0 if none).
    pub largest_pose_jump_m: f64,
    /// Ticks whose pose was catching up, at `max_hand_speed`, with a plausible reading it
    /// had fallen behind (after held readings, or a network device's late packet).
    pub pose_catch_up_ticks: u64,
    /// m/s, the pose gate's speed bound.
    pub max_hand_speed: f64,
}

impl ServoStats {
    /// Statistics of a run of `core` logged in `log`.
    pub fn from_run(
        core: &ServoCore,
        log: &TickLog,
        wall_seconds: f64,
        missed_deadlines: u64,
    ) -> Self {
        let c = core.counters();
        let records = log.records();
        let mut v: Vec<f32> = records.iter().map(|r| r.lateness_us).collect();
        let lateness_us = Percentiles::of(&mut v);
        v.clear();
        v.extend(records.iter().map(|r| r.work_us));
        let work_us = Percentiles::of(&mut v);
        v.clear();
        v.extend(records.iter().map(|r| r.model_age_ms));
        let model_age_ms = Percentiles::of(&mut v);
        ServoStats {
            ticks: c.ticks,
            wall_seconds,
            rate_hz: if wall_seconds > 0.0 {
                c.ticks as f64 / wall_seconds
            } else {
                0.0
            },
            target_rate_hz: core.config().rate_hz,
            lateness_us,
            work_us,
            missed_deadlines,
            model_age_ms,
            model_updates: c.model_updates,
            ticks_without_model: c.ticks_without_model,
            stale_ticks: c.stale_ticks,
            fading_ticks: c.fading_ticks,
            force_clamps: c.force_clamps,
            stiffness_limited_ticks: c.stiffness_limited_ticks,
            max_force_n: c.max_force,
            passivity_min_energy_j: core.observer().min_energy(),
            passivity_final_energy_j: core.observer().energy(),
            passivity_damping: core.observer().damping(),
            passivity_control_ticks: c.passivity_control_ticks,
            coupling_stiffness: core.coupling_stiffness(),
            max_passive_stiffness: core.config().max_passive_stiffness(),
            unlogged_ticks: log.overflow(),
            held_poses: core.gate.implausible(),
            pose_catch_up_ticks: core.gate.catching_up(),
            largest_pose_jump_m: core.gate.largest_jump(),
            max_hand_speed: core.gate.max_speed(),
        }
    }
}

/// Everything a servo run leaves behind.
#[derive(Clone, Debug)]
pub struct ServoReport {
    /// Loop statistics (for summary.json).
    pub stats: ServoStats,
    /// The per-tick log (for haptic.csv: [`TickLog::write_csv`]).
    pub log: TickLog,
    /// The device's counters (packets, drops).
    pub device: DeviceStats,
    /// The device, as [`HapticDevice::describe`] names it.
    pub device_name: String,
}

/// Sleep until `spin` before `deadline`, then spin until it.
fn wait_until(deadline: Instant, spin: Duration) {
    let now = Instant::now();
    if deadline <= now {
        return;
    }
    let remaining = deadline - now;
    if remaining > spin {
        std::thread::sleep(remaining - spin);
    }
    while Instant::now() < deadline {
        std::hint::spin_loop();
    }
}

/// Run the servo loop on the calling thread until `stop` is set or `config.duration` has
/// passed. Allocates its log before the first tick and its statistics after the last,
/// nothing in between.
pub fn run_servo(
    device: &mut dyn HapticDevice,
    link: &mut ServoLink,
    config: &ServoConfig,
    stop: &AtomicBool,
) -> Result<ServoReport> {
    config.validate()?;
    let device_name = device.describe();
    let mut log = TickLog::with_capacity(config.log_ticks());
    let mut core = ServoCore::new(config);
    let period = Duration::from_secs_f64(config.period());
    let spin = Duration::from_secs_f64(config.spin);
    let clock = link.clock;

    let start = Instant::now();
    let end = config.duration.map(|d| start + Duration::from_secs_f64(d));
    let mut deadline = start;
    let mut missed = 0u64;
    let mut last_done = start;
    let mut tick = 0u64;
    while !stop.load(Ordering::Relaxed) && end.is_none_or(|e| deadline < e) {
        wait_until(deadline, spin);
        let woke = Instant::now();
        let now = clock.seconds_at(woke);
        let reading = device.read(now);
        let (model, sequence) = link.model.read();
        let out = core.tick(now, &reading, &model, sequence);
        link.tool.publish(ToolCommand {
            position: out.proxy,
            velocity: out.pose.velocity,
            device_position: out.pose.position,
            stamp: now,
            buttons: reading.buttons,
            tick,
        });
        device.send(now, &out.command);
        let done = Instant::now();
        let mut record = out.record;
        record.lateness_us = (woke - deadline).as_secs_f64() as f32 * 1e6;
        record.work_us = (done - woke).as_secs_f64() as f32 * 1e6;
        log.push(record);
        last_done = done;
        tick += 1;

        deadline += period;
        let after = Instant::now();
        if after > deadline {
            // Skip to the next deadline still ahead; count the skipped ones inside the run.
            let behind = ((after - deadline).as_nanos() / period.as_nanos()) as u64 + 1;
            let in_run = end.map_or(behind, |e| {
                let left = e.saturating_duration_since(deadline).as_nanos();
                behind.min(left.div_ceil(period.as_nanos()) as u64)
            });
            missed += in_run;
            deadline += period * behind as u32;
        }
    }
    let wall = (last_done - start).as_secs_f64();
    Ok(ServoReport {
        stats: ServoStats::from_run(&core, &log, wall, missed),
        log,
        device: device.stats(),
        device_name,
    })
}

/// A running servo thread.
pub struct ServoHandle {
    stop: Arc<AtomicBool>,
    thread: JoinHandle<Result<ServoReport>>,
}

/// Start the servo loop on its own thread (`palpate-servo`). Errors: an invalid `config`,
/// a thread that cannot be spawned.
pub fn spawn_servo(
    mut device: Box<dyn HapticDevice>,
    mut link: ServoLink,
    config: ServoConfig,
) -> Result<ServoHandle> {
    config.validate()?;
    let stop = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&stop);
    let thread = std::thread::Builder::new()
        .name("palpate-servo".into())
        .spawn(move || run_servo(device.as_mut(), &mut link, &config, &flag))
        .map_err(|e| PalpateError::Usage(format!("haptic servo: cannot start its thread: {e}")))?;
    Ok(ServoHandle { stop, thread })
}

impl ServoHandle {
    /// Ask the loop to stop after its current tick.
    pub fn stop(&self) {
        self.stop.store(true, Ordering::Relaxed);
    }

    /// The flag [`stop`](Self::stop) sets (e.g. for a Ctrl-C handler).
    pub fn stop_flag(&self) -> Arc<AtomicBool> {
        Arc::clone(&self.stop)
    }

    /// The loop has ended (duration reached or stopped).
    pub fn is_finished(&self) -> bool {
        self.thread.is_finished()
    }

    /// Wait for the loop to end and take its report.
    pub fn join(self) -> Result<ServoReport> {
        self.thread.join().unwrap_or_else(|panic| {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            Err(PalpateError::Usage(format!(
                "haptic servo: the servo thread panicked: {what}"
            )))
        })
    }
}
