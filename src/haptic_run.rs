//! The `palpate haptic` job: the simulation on the calling (physics) thread and the 1 kHz
//! servo loop on its own, joined by the latest-value slots of [`crate::haptics::link`](mod@crate::haptics::link)
//! (DESIGN §7).
//!
//! Each pass of the physics loop takes the newest tool command, aims the simulated tool at
//! `home + proxy` (clamped to the device's workspace, and moved into the tissue no faster
//! than [`crate::model::Model::max_tool_speed`]), runs a batch of about
//! [`HapticOptions::batch_seconds`] of simulated time (the tool moves linearly to the new
//! place over it), and publishes the local model: the tool force f0 from `tool_force`, the
//! static stiffness K of [`crate::compliance`] (refreshed every
//! [`HapticOptions::stiffness_period`] while in contact, after the publish, so that it goes
//! out with the next model, and after the new compliance columns it needs were solved a
//! few per batch; the frozen stiffness when the body has no static stiffness), the proxy
//! it was computed at and the command's time stamp. The
//! simulation never runs ahead of the loop clock; when it cannot keep up, the realtime
//! factor in `summary.json` says so. A divergence rolls back and halves dt (the servo fades
//! the force while the model says `diverged`); when dt cannot be halved again the run ends
//! with the last finite state written.

use crate::compliance::{contact_points, ContactCompliance};
use crate::error::{PalpateError, Result};
use crate::haptics::{
    self, DeviceSpec, DeviceStats, LocalModel, LoopClock, ServoConfig, ServoReport, ServoStats,
};
use crate::inversion::{InversionProbe, Inverted};
use crate::output::state::state_vtu;
use crate::output::summary::RunSummary;
use crate::output::write_atomic;
use crate::rest::{pass_time_at_rest, RestWatch};
use crate::run::{diverged_status, summarize, RunStatus};
use crate::scene::Scene;
use crate::sim::{Backend, DivergencePolicy, Guarded, SimOptions, Simulation};
use glam::{DMat3, DVec3};
use serde::Serialize;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// The built-in scene `palpate haptic` runs when none is named.
pub const DEFAULT_HAPTIC_SCENE: &str = "lv_touch";

/// Run length when the device has none of its own (null, udp), s.
pub const DEFAULT_SECONDS: f64 = 10.0;

/// Batch and stiffness-refresh timings kept for their percentiles: those of the session's
/// first hour of 1 ms batches (the busy time counts every batch).
const MAX_TIMINGS: usize = crate::haptics::servo::MAX_LOG_TICKS;

/// The shortest session, s (ten servo ticks: shorter ones have no meaningful statistics).
pub const MIN_SECONDS: f64 = 0.01;

/// The longest session, s (the servo loop's limit; about 11.6 days).
pub const MAX_SECONDS: f64 = 1.0e6;

/// Options of a haptic session.
#[derive(Clone, Debug)]
pub struct HapticOptions {
    /// Backend (`auto` picks a hardware GPU, else the CPU).
    pub backend: Backend,
    /// CPU backend threads (None: one fewer than the cores, at least one).
    pub threads: Option<usize>,
    /// `--device`: `null`, `scripted:FILE` or `udp:ADDR`.
    pub device: String,
    /// `--device-spec` (None: [`DeviceSpec::DEFAULT_NAME`]).
    pub device_spec: Option<String>,
    /// Run length, s (None: the scripted trajectory's length, else [`DEFAULT_SECONDS`]).
    pub seconds: Option<f64>,
    /// Output directory.
    pub out: PathBuf,
    /// Simulated time per batch, s (the model is published after each batch).
    pub batch_seconds: f64,
    /// Wall time between refreshes of the static stiffness while in contact, s.
    pub stiffness_period: f64,
    /// Print a first line naming the scene, device and backend.
    pub announce: bool,
    /// Let the physics sleep while the body is at rest and the tool clear of it
    /// ([`crate::rest`]); `palpate haptic --no-sleep` turns it off.
    pub sleep_at_rest: bool,
    /// Render with the frozen-tissue stiffness (the contact springs' K) even where a static
    /// compliance can be built: what a body that is not held, or too big to factor, gets
    /// (for comparisons and tests).
    pub frozen_stiffness: bool,
}

impl Default for HapticOptions {
    fn default() -> Self {
        HapticOptions {
            backend: Backend::Auto,
            threads: None,
            device: "null".into(),
            device_spec: None,
            seconds: None,
            out: PathBuf::from("out"),
            batch_seconds: 1.0e-3,
            stiffness_period: 0.01,
            announce: false,
            sleep_at_rest: true,
            frozen_stiffness: false,
        }
    }
}

/// Percentiles of a physics-side quantity.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Spread {
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Largest.
    pub max: f64,
}

impl Spread {
    fn of(values: &mut [f64]) -> Spread {
        if values.is_empty() {
            return Spread::default();
        }
        values.sort_by(f64::total_cmp);
        let at = |q: f64| values[((values.len() - 1) as f64 * q).round() as usize];
        Spread {
            p50: at(0.5),
            p99: at(0.99),
            max: values[values.len() - 1],
        }
    }
}

/// What the physics thread did during a haptic session.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct PhysicsStats {
    /// Batches run (each publishes a local model; asleep, a contact-free model is published
    /// per servo tick without a batch, not counted here).
    pub batches: u64,
    /// Steps per batch (at the initial dt).
    pub steps_per_batch: u32,
    /// Wall time per batch, ms.
    pub batch_wall_ms: Spread,
    /// Fraction of the session's wall time spent running batches (the rest the physics
    /// thread waited for the loop clock or a servo tick, or slept at rest): above about 0.9
    /// it can barely keep up.
    pub busy_fraction: f64,
    /// Simulated seconds stepped per wall second of batch work: the realtime factor the
    /// physics could reach if it never waited or slept (≥ 1 keeps up with the hand).
    pub realtime_capacity: f64,
    /// Times the body fell asleep (at rest, the tool clear of it; see [`crate::rest`]).
    pub sleeps: u64,
    /// Simulated seconds that passed asleep, without steps.
    pub slept_seconds: f64,
    /// Where the published stiffness comes from: `static` (linear compliance, see
    /// `palpate::compliance`) or `frozen: <why not static>`.
    pub stiffness_model: String,
    /// Static-stiffness refreshes.
    pub stiffness_refreshes: u64,
    /// Wall time per refresh, ms.
    pub stiffness_refresh_ms: Spread,
    /// Batches that solved new columns of the compliance for a refresh still to come (a few
    /// per batch, [`ContactCompliance::missing_columns`]).
    pub column_warmup_batches: u64,
    /// Batches whose tool target was pulled back into the device's workspace.
    pub workspace_clamps: u64,
    /// The fastest the simulated tool may move, m/s ([`crate::model::Model::max_tool_speed`]).
    pub max_tool_speed: f64,
    /// Batches whose tool move into the tissue was shortened to that speed: in contact all
    /// but a withdrawal ([`limit_pressing_stride`]), out of it a move towards the tissue
    /// stopped at its surface. The tool then lagged the hand, or the physics caught up
    /// after falling behind (a long stride from a slow hand).
    pub speed_limited_batches: u64,
    /// Batches out of contact whose stride was measured against the deformed surface (a
    /// state read and a scan of the surface); a stride shorter than a lower bound of the
    /// clearance (the last measured one less the tool's travel and the surface's since) is
    /// not measured.
    pub approach_scans: u64,
    /// Batches in contact whose withdrawal went farther than the penetration and a reach
    /// ([`withdrawal_head`]): the rest of it was measured against the deformed surface, and
    /// limited where it would meet tissue again ([`limit_withdrawal_remainder`]).
    pub withdrawal_scans: u64,
    /// Those of them that started in contact with the hand itself moving faster than the
    /// limit (absent: none).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hand_too_fast: Option<HandTooFast>,
    /// Batches that diverged and were rolled back (dt halved).
    pub divergences: u64,
    /// The last published stiffness K = ∂F/∂x, N/m, by rows.
    pub tool_stiffness: [[f64; 3]; 3],
    /// Batches that ended with the tool in contact with the tissue.
    pub contact_batches: u64,
    /// The largest force the tissue exerted on the simulated tool over the session (the
    /// physics side, before any shaping or fading in the servo loop), N.
    pub peak_tool_force: [f64; 3],
    /// Counts of inverted elements taken while in contact, one per `stiffness_period` of
    /// wall time at most (the end state's count is `inverted_tets` / `inverted_particles`).
    pub inversion_checks: u64,
    /// The most inverted elements any of those counts found.
    pub inverted_peak: InvertedPeak,
}

/// The batches of a session that started in contact and whose stride was speed-limited
/// while the hand moved faster than [`crate::model::Model::max_tool_speed`] (a hand that
/// slows down over the tissue's surface, out of contact, is not counted).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct HandTooFast {
    /// How many.
    pub batches: u64,
    /// Simulated time of the first, s.
    pub from_seconds: f64,
    /// The hand's fastest speed over them (pose to pose, the servo's gated pose: about at most the
    /// pose gate's speed bound), m/s.
    pub max_hand_speed: f64,
}

/// The largest count of inverted elements (tets + particles that carry strain energy, det F
/// ≤ 0; [`crate::inversion`]) over a session's checks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct InvertedPeak {
    /// Inverted tets at that check.
    pub tets: usize,
    /// Inverted particles at that check.
    pub particles: usize,
    /// Simulated time of the first check that found this many (tets + particles), s (absent:
    /// none found; an inversion may have begun at an earlier check).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub at_seconds: Option<f64>,
}

impl InvertedPeak {
    /// Keep `n`, counted at simulated time `t`, if it has more inverted elements than the
    /// peak so far.
    pub fn record(&mut self, n: Inverted, t: f64) {
        if n.tets + n.particles > self.tets + self.particles {
            *self = InvertedPeak {
                tets: n.tets,
                particles: n.particles,
                at_seconds: Some(t),
            };
        }
    }
}

/// Wall time a batch gives to solving new compliance columns before a stiffness refresh.
const COLUMN_BUDGET: Duration = Duration::from_micros(300);

/// Batches in a row that may warm columns before the refresh solves the rest at once (a
/// contact that keeps spreading faster than the budget would otherwise never refresh).
const MAX_WARMING_BATCHES: u32 = 40;

/// How many batches' travel at the tool speed limit the tool must lag the hand by before the
/// servo solves with the static stiffness instead of the contact springs' (a short lag, such
/// as a physics thread catching up after a stall, keeps the contact springs' stable fixed
/// point between servo and physics).
const LAG_BATCHES: f64 = 4.0;

/// s: a new static stiffness is rendered in over this time, from the one rendered before (a
/// smoothstep): with the tool held back a contact's first K added K × the lag at once (0.24 N
/// pressing lv_touch 6 mm at 2 m/s, in one tick), and each refresh ΔK × the lag.
const STIFFNESS_RAMP_SECONDS: f64 = 0.03;

/// Whether the tool is held back after a batch: the proxy lies more than `lag_limit` (m) from
/// the tool (`proxy_lag`), or, while the hand itself moves faster than the speed limit in
/// contact (`hand_outruns`), the hand's [`hand_balance_offset`] (`balance`, m) does. Once the
/// hand slows, the proxy alone decides, as before: the servo's solve with the static K puts a
/// held-back proxy ahead, so the tool stays held back until it has caught up. (Gated by the
/// batch's move being cut instead, the balance re-entered the held state while a fast press's
/// tool caught up, and the two solves rang, 0.28 N/ms in 1 of 8 runs; with the balance alone
/// a slow press switched back and forth at 0.35 N/ms.)
fn is_held_back(proxy_lag: f64, hand_outruns: bool, balance: f64, lag_limit: f64) -> bool {
    proxy_lag > lag_limit || (hand_outruns && balance > lag_limit)
}

/// Where the hand's pose and the settled tissue balance, from the tool: the offset e with
/// k_c (d − e) + f + K e = 0, e = (k_c I − K)⁻¹ (k_c d + f), for the coupling spring k_c
/// (N/m), the static stiffness K (N/m, negative semi-definite), the hand's offset `d` from
/// the tool (m) and the tissue's force on the tool `f` (N) less its dampers' push. Zero when
/// the hand rests on the tissue's force; about the hand's lag while the tool is held back.
fn hand_balance_offset(coupling: f64, stiffness: DMat3, d: DVec3, f: DVec3) -> DVec3 {
    let a = DMat3::from_diagonal(DVec3::splat(coupling)) - stiffness;
    if a.determinant().abs() <= f64::MIN_POSITIVE || !a.is_finite() {
        return DVec3::ZERO;
    }
    a.inverse() * (d * coupling + f)
}

/// The push the contact dampers put in the tool force `report` after a batch of
/// `batch_seconds` that moved the tool by `tool_move` (damping per unit area `damping`):
/// [`LocalModel::damper_force_of`] of that move.
fn pushed_by_dampers(
    report: &crate::stepper::ToolReport,
    damping: f64,
    batch_seconds: f64,
    tool_move: DVec3,
) -> DVec3 {
    LocalModel {
        force: report.force,
        ..Default::default()
    }
    .with_batch_damper(damping, report.contact_area, batch_seconds, tool_move)
    .damper_force
}

/// The stiffness to render at loop time `t`: `to`, ramped in from `from` since `since` over
/// [`STIFFNESS_RAMP_SECONDS`] (none: `to`).
fn ramped_stiffness(to: DMat3, ramp: Option<(DMat3, f64)>, t: f64) -> DMat3 {
    match ramp {
        Some((from, since)) => {
            let g = crate::haptics::shaping::smoothstep((t - since) / STIFFNESS_RAMP_SECONDS);
            from + (to - from) * g
        }
        None => to,
    }
}

/// A tool move `stride` in contact, limited to `reach` (m) except for its withdrawal: the part
/// along the tissue's push `normal` (unit, out of the tissue) that moves away from it is kept
/// whole, the rest (the press in and the slide along) shortened so that it moves no more than
/// `reach` while it still touches. A pull (within 30° of the normal) that withdraws by more
/// than the `penetration` (m) leaves the tissue after that fraction of it: a straight pull
/// whose contact normal is tilted slides along only that far in contact. (Out of a dimple
/// whose rim is 60° around the tool from its bottom, a press half the radius deep, a pull
/// within 30° moves away from every point of it; a stride more sideways would drag the
/// tool across the rim, and counts as sliding all the way.) None when the stride needs no
/// limit.
pub fn limit_pressing_stride(
    stride: DVec3,
    normal: DVec3,
    penetration: f64,
    reach: f64,
) -> Option<DVec3> {
    let away = stride.dot(normal).max(0.0);
    let limited = stride - away * normal;
    let depth = penetration.max(0.0);
    let pull = away >= 30f64.to_radians().cos() * stride.length();
    let touching = if pull && away > depth {
        depth / away
    } else {
        1.0
    };
    let length = limited.length() * touching;
    (length > reach).then(|| away * normal + limited * (reach / length))
}

/// The part of an in-contact `stride` (m, already [`limit_pressing_stride`]'s) that is free
/// without a look at the surface: up to where it has withdrawn `penetration` + `reach` (m)
/// along the tissue's push `normal` (unit), out of the touched surface and a reach past it.
/// None where the whole stride withdraws no farther (every stride of a hand within the speed
/// limit): it is free.
pub fn withdrawal_head(
    stride: DVec3,
    normal: DVec3,
    penetration: f64,
    reach: f64,
) -> Option<DVec3> {
    let away = stride.dot(normal);
    let free = penetration.max(0.0) + reach;
    (away > free).then(|| stride * (free / away))
}

/// The rest of a long withdrawal in contact, `remainder` (m, the stride after its
/// [`withdrawal_head`]), limited where the tool swept along it would meet tissue again: the
/// opposite wall of a cavity after a stall, say, which a withdrawal kept whole used to put the
/// tool deep into. The `survey` is of the remainder (from the head's end). None, no limit,
/// where the swept tool stays clear by more than `margin` (m: what the surface may move
/// meanwhile), or gets no closer to the tissue anywhere than where the remainder starts (out
/// of a dimple, whatever its depth); otherwise cut to that start's clearance or `reach`,
/// whichever is longer, as a move towards the tissue ([`limit_approaching_stride`]).
pub fn limit_withdrawal_remainder(
    remainder: DVec3,
    survey: crate::rest::StrideSurvey,
    reach: f64,
    margin: f64,
) -> Option<DVec3> {
    cut_to_clearance(remainder, survey, reach, margin, |_| true)
}

/// `stride` cut to the `survey`'s clearance at its start or `reach`, whichever is longer;
/// None where that is the whole stride, where the swept tool stays clear by more than
/// `margin`, or where it gets no closer than it starts and `moves_away(length)` agrees.
fn cut_to_clearance(
    stride: DVec3,
    survey: crate::rest::StrideSurvey,
    reach: f64,
    margin: f64,
    moves_away: impl Fn(f64) -> bool,
) -> Option<DVec3> {
    let length = stride.length();
    let clear_path = survey.swept_clear > margin;
    let away = survey.swept_clear >= survey.clear - 1e-9 * length && moves_away(length);
    let free = survey.clear.max(reach);
    (!clear_path && !away && length > free).then(|| stride * (free / length))
}

/// A tool move `stride` out of contact, limited to where the tool meets the tissue (the
/// `survey`'s clearance at its start) or to `reach` (m), whichever is longer: towards the
/// tissue, up to its surface at the hand's speed and into it at the limit from the next batch
/// on (a batch moves the tool at one speed: one that ended a reach inside met the tissue at
/// up to 0.8 m/s, its contact dampers pushing 0.9 N into the hand). None, no limit, where that
/// is the whole stride; where the tool swept along it stays clear of the tissue by more than
/// `margin` (m: what the surface may move meanwhile); or where it moves away (the clearance
/// grows by at least 0.9 × the stride, and the swept tool gets no closer than it starts).
/// So a long stride after a stall that grazes an edge or ends on the body's far side is
/// limited, and so is a slide along a face the tool already touches (no contact found at a
/// vertex, or after a rollback).
pub fn limit_approaching_stride(
    stride: DVec3,
    survey: crate::rest::StrideSurvey,
    reach: f64,
    margin: f64,
) -> Option<DVec3> {
    cut_to_clearance(stride, survey, reach, margin, |length| {
        survey.clear_after >= survey.clear + 0.9 * length
    })
}

/// A survey of the surface by `survey` (given the awake body's state, None asleep: the
/// sleeping surface is kept), its time added to the physics thread's `busy` seconds.
fn survey_timed(
    sim: &mut Simulation,
    rest: &RestWatch,
    busy: &mut f64,
    survey: impl FnOnce(Option<&crate::stepper::State>) -> crate::rest::StrideSurvey,
) -> Result<crate::rest::StrideSurvey> {
    let t = Instant::now();
    let state = match rest.is_asleep() {
        true => None,
        false => Some(sim.state()?),
    };
    let surveyed = survey(state.as_ref());
    *busy += t.elapsed().as_secs_f64();
    Ok(surveyed)
}

/// The `haptic` section of `summary.json`.
#[derive(Clone, Debug, Serialize)]
pub struct HapticStats {
    /// The device (`HapticDevice::describe`).
    pub device: String,
    /// Its specification.
    pub device_spec: DeviceSpec,
    /// The servo loop's statistics (rate, lateness, missed deadlines, model age, clamps,
    /// passivity observer).
    pub servo: ServoStats,
    /// The device's packet counters.
    pub device_stats: DeviceStats,
    /// The physics thread's counters.
    pub physics: PhysicsStats,
}

/// `summary.json` of a haptic session: the run summary plus the `haptic` section.
#[derive(Clone, Debug, Serialize)]
pub struct HapticSummary {
    /// The fields every run reports.
    #[serde(flatten)]
    pub run: RunSummary,
    /// Loop and device statistics.
    pub haptic: HapticStats,
}

impl HapticSummary {
    /// Write `summary.json` into `dir`.
    pub fn write(&self, dir: &std::path::Path) -> Result<()> {
        let json = serde_json::to_string_pretty(self)
            .map_err(|e| PalpateError::Usage(format!("summary.json: {e}")))?;
        write_atomic(&dir.join("summary.json"), json.as_bytes())
    }
}

/// Where the published stiffness comes from.
enum StiffnessSource {
    Static(Box<ContactCompliance>),
    Frozen(String),
}

/// Run a haptic session of `scene` (which must have a `[tool]`) and write `haptic.csv`,
/// `final.vtu` (and `particles_final.vtu`) and `summary.json` into `opts.out`.
pub fn run_haptic(scene: &Scene, opts: &HapticOptions) -> Result<HapticSummary> {
    if scene.tool.is_none() {
        return Err(PalpateError::Usage(format!(
            "{}: a haptic session needs a [tool] (radius and stiffness; home, where the device's origin sits, defaults to the path's start)",
            scene.origin
        )));
    }
    for (name, v) in [
        ("batch_seconds", opts.batch_seconds),
        ("stiffness_period", opts.stiffness_period),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(PalpateError::Usage(format!(
                "haptic: {name} = {v} must be a positive number of seconds"
            )));
        }
    }
    let spec = DeviceSpec::by_name(
        opts.device_spec
            .as_deref()
            .unwrap_or(DeviceSpec::DEFAULT_NAME),
    )?;
    let device = haptics::DeviceArg::parse(&opts.device)?.open(spec)?;
    let seconds = match opts.seconds {
        Some(s) if !(s.is_finite() && s >= MIN_SECONDS) => {
            return Err(PalpateError::Usage(format!(
                "--seconds {}: must be a number of seconds, at least {MIN_SECONDS} (ten servo ticks)",
                crate::scene::Num(s)
            )))
        }
        Some(s) => s,
        None => match device.duration() {
            Some(d) if d.is_nan() || d < MIN_SECONDS => {
                return Err(PalpateError::Usage(format!(
                    "{}: the trajectory lasts {} s, less than a session's {MIN_SECONDS} s; give it a later last time, or --seconds",
                    device.describe(),
                    crate::scene::Num(d)
                )))
            }
            d => d.unwrap_or(DEFAULT_SECONDS),
        },
    };
    if seconds > MAX_SECONDS {
        return Err(PalpateError::Usage(format!(
            "{}: a session of {seconds:e} s is longer than the {MAX_SECONDS:e} s a session may last",
            if opts.seconds.is_some() {
                "--seconds".to_string()
            } else {
                device.describe()
            }
        )));
    }
    crate::output::prepare_out_dir(&opts.out)?;
    let trajectory = match haptics::DeviceArg::parse(&opts.device)? {
        haptics::DeviceArg::Scripted(path) => Some(path),
        _ => None,
    };
    let mut inputs: Vec<_> = scene.inputs().collect();
    inputs.extend(trajectory.as_deref().map(|p| ("scripted trajectory", p)));
    crate::output::check_inputs_are_not_outputs(&opts.out, &inputs)?;
    let threads = opts.threads.or_else(|| {
        (opts.backend != Backend::Gpu).then(|| {
            crate::cpu::stepper::available_cores()
                .saturating_sub(1)
                .max(1)
        })
    });
    let mut sim = Simulation::new(
        scene,
        opts.backend,
        SimOptions {
            threads,
            // This thread steps it: on one thread, no pool worker competes with the servo.
            step_on_this_thread: true,
            ..Default::default()
        },
    )?;
    let model = sim.model.clone();
    let home = model.tool.as_ref().map_or(DVec3::ZERO, |t| t.tool.home);
    let tool_damping = model.tool.as_ref().map_or(0.0, |t| t.tool.damping);
    sim.tool_position = home;
    sim.tool_target = Some(home);
    let mut stiffness = match opts.frozen_stiffness {
        true => StiffnessSource::Frozen("asked for".into()),
        false => match ContactCompliance::new(&model) {
            Ok(c) => StiffnessSource::Static(Box::new(c)),
            Err(why) => StiffnessSource::Frozen(why.to_string()),
        },
    };
    let config = ServoConfig::new(spec).with_duration(seconds);
    // A tissue farther from the tool's home than the device reaches cannot be touched (hm1's
    // lengths are unitless, the device's are metres).
    if let (true, Some(t)) = (opts.announce, &model.tool) {
        let gap = t.tool.surface_gap(&scene.mesh, home);
        if gap > spec.workspace_radius {
            crate::say_err!(
                "warning: {}: the tissue is {gap:.3e} m from the tool's surface at its home, beyond the device's reach ({} m, spec {}): the hand cannot touch it (move tool.home nearer the surface; a scene in other units than metres cannot be touched)",
                scene.origin,
                spec.workspace_radius,
                spec.name
            );
        }
        // In contact the tool moves no faster than the speed limit: its travel between two
        // particle activation updates.
        if let Some(ps) = scene.particles.as_ref().filter(|p| !p.all_active) {
            let speed = model.max_tool_speed();
            let travel = speed * ps.activation_interval as f64 * sim.dt;
            if let Some(w) = crate::scene::activation_lag_warning(
                "the tool presses into the tissue",
                speed,
                travel,
                ps.activation_interval,
                ps.activation_radius,
            ) {
                crate::say_err!("warning: {}: {w}", scene.origin);
            }
        }
    }
    // (No tunnelling warning for a fast scripted hand: near the tissue the physics moves
    // the tool no farther in a batch than its clearance to the surface plus the speed
    // limit's reach, so it cannot pass through a surface between two steps.)
    if opts.announce {
        crate::say!(
            "{}: {} tets, {} vertices{}; device {} ({}); backend {} on {} ({}); {seconds} s",
            scene.name,
            model.n_tets(),
            model.n_vertices(),
            model
                .particles
                .as_ref()
                .map(|p| format!(", {} particles", p.len()))
                .unwrap_or_default(),
            device.describe(),
            spec.name,
            if sim.backend == Backend::Gpu {
                "gpu"
            } else {
                "cpu"
            },
            sim.backend_name(),
            sim.backend_reason,
        );
    }

    // Held until the outputs are written: a second job into this folder is refused.
    let _lock = crate::output::lock::OutLock::claim(&opts.out, "the session started")?;
    // Set up (the contact compliance factored too: seconds on a large mesh): a signal from
    // now on stops after a batch and writes the outputs; before, it ends the process with
    // nothing written.
    crate::interrupt::setup_done();
    // Built before the servo starts: with hm1's 28,000 particles it takes milliseconds.
    let probe = InversionProbe::new(&model);
    let steps_per_batch = ((opts.batch_seconds / sim.dt).round() as u32).max(1);
    let clock = LoopClock::new();
    let (servo_end, mut physics) = haptics::link(clock);
    let servo = haptics::spawn_servo(device, servo_end, config)?;
    // The session has started: now the earlier run's files may go.
    let removed = match crate::output::remove_earlier_outputs(&opts.out) {
        Ok(n) => n,
        Err(e) => {
            servo.stop();
            let _ = servo.join();
            return Err(e);
        }
    };
    if opts.announce && removed > 0 {
        crate::say_err!(
            "note: removed {removed} output files of an earlier run from {}",
            opts.out.display()
        );
    }
    let mut stats = PhysicsStats {
        steps_per_batch,
        max_tool_speed: model.max_tool_speed(),
        stiffness_model: match &stiffness {
            StiffnessSource::Static(c) => format!(
                "static (linear compliance, {} degrees of freedom)",
                c.dofs()
            ),
            StiffnessSource::Frozen(why) => format!("frozen: no static stiffness, {why}"),
        },
        ..Default::default()
    };
    let mut batch_ms = Vec::new();
    let mut busy_seconds = 0.0f64;
    let mut refresh_ms = Vec::new();
    let mut status = RunStatus::Ok;
    // The last divergence not yet followed by a good batch (the session may end while dt is
    // still being halved: then it did not end ok).
    let mut unrecovered: Option<(u64, u32, f64)> = None;
    let mut published_k = DMat3::ZERO;
    // Design 8's floor under the strain energy ([`crate::run::energy_floor`]).
    let energy_floor = crate::run::energy_floor(&model);
    let coupling_stiffness = config.coupling.stiffness;
    let mut last_refresh: Option<Instant> = None;
    // Inverted elements are counted on the same period while in contact.
    let mut last_check: Option<Instant> = None;
    let mut rest = RestWatch::new(scene);
    let period = Duration::from_secs_f64(config.period());
    let mut last_used = 0u64;
    // The direction the tissue pushed the tool at the end of the last batch, in contact.
    let mut contact_normal: Option<DVec3> = None;
    // Out of contact: a lower bound of the tool's clearance from the tissue's surface, from
    // the last scan less the tool's travel and twice the surface's fastest vertex speed over
    // each batch since (None: unknown).
    let mut clearance_floor: Option<f64> = None;
    // The surface's fastest vertex after the last batch, m/s (0 asleep or before any).
    let mut surface_speed = 0.0f64;
    // The hand's pose (offset from home) and stamp when the last batch started: at home when
    // the session starts, as the tool is (a hand that moved before the first batch did so
    // since then).
    let mut last_hand = (DVec3::ZERO, clock.now());
    // Batches in a row that warmed compliance columns for a refresh still to come.
    let mut warming_batches = 0u32;
    // The static K rendered before the last refresh and the loop time of that refresh (the
    // new K ramps in from it); and whether `published_k` is the contact springs' K.
    let mut stiffness_ramp: Option<(DMat3, f64)> = None;
    let mut k_is_springs = false;
    let start = Instant::now();
    let sim_start = clock.now();
    let outcome = (|| -> Result<()> {
        while !servo.is_finished() {
            if crate::interrupt::requested() {
                status = RunStatus::Interrupted {
                    at_seconds: sim.time,
                };
                servo.stop();
                break;
            }
            // Never run ahead of the loop clock. Unless a period or more behind it, start on a
            // fresh pose: when the newest was used already or is more than 10 % of a period
            // old, wait for the next servo tick. A batch that starts just after a tick
            // publishes its model before the following tick, so the servo renders a model one
            // period old, not two.
            let ahead = sim.time - (clock.now() - sim_start);
            if ahead > 0.0 {
                std::thread::sleep(Duration::from_secs_f64(ahead));
            }
            let t_period = period.as_secs_f64();
            if (clock.now() - sim_start) - sim.time < t_period {
                let (newest, tick) = physics.tool();
                if tick == last_used || clock.now() - newest.stamp > 0.1 * t_period {
                    let due = clock.instant_at(newest.stamp + t_period);
                    wait_for_a_tick(&mut physics, tick, due, period);
                }
            }
            let (command, tick) = physics.tool();
            last_used = tick;
            let mut offset = command.position;
            if offset.length() > spec.workspace_radius {
                offset *= spec.workspace_radius / offset.length();
                stats.workspace_clamps += 1;
            }
            let steps = ((opts.batch_seconds / sim.dt).round() as u32).max(1);
            // The hand's own speed since the last batch's pose (the physics may have fallen
            // behind: then the stride below is long though the hand was slow).
            let hand = command.device_position;
            let (x, t) = last_hand;
            let hand_speed = if command.stamp > t {
                (hand - x).length() / (command.stamp - t)
            } else {
                0.0
            };
            last_hand = (hand, command.stamp);
            // Pressed or slid into the tissue no faster than it can move out of the tool's
            // way (the servo renders the hand's force from the local model meanwhile): in
            // contact, all but a withdrawal; out of it, up to the tissue's surface at the
            // hand's speed and no farther.
            let mut target = home + offset;
            let reach = stats.max_tool_speed * steps as f64 * sim.dt;
            // What the surface may move while the batch runs (nothing asleep).
            let margin = match rest.is_asleep() {
                true => 0.0,
                false => 2.0 * surface_speed * steps as f64 * sim.dt,
            };
            let stride = target - sim.tool_position;
            let limited = match contact_normal {
                Some(normal) => {
                    let penetration = sim.last_tool.map_or(0.0, |r| r.max_penetration);
                    let pressed = limit_pressing_stride(stride, normal, penetration, reach);
                    let kept = pressed.unwrap_or(stride);
                    match withdrawal_head(kept, normal, penetration, reach) {
                        None => pressed,
                        Some(head) => {
                            // A withdrawal longer than the speed limit's reach past the
                            // touched surface (after a stall, or a hand faster than the
                            // limit): what the tool sweeps past that may be more tissue.
                            stats.withdrawal_scans += 1;
                            let tool = sim.tool_position;
                            let survey =
                                survey_timed(&mut sim, &rest, &mut busy_seconds, |state| {
                                    rest.survey_withdrawal(state, tool, tool + head, tool + kept)
                                })?;
                            match limit_withdrawal_remainder(kept - head, survey, reach, margin) {
                                Some(rest_of_it) => Some(head + rest_of_it),
                                None => pressed,
                            }
                        }
                    }
                }
                // Clear of the surface by more than the stride: nothing to limit.
                None if clearance_floor.is_some_and(|f| f >= stride.length()) => None,
                None if stride.length() > reach => {
                    // Physics-thread work (a state read, the surface's distance): busy time.
                    stats.approach_scans += 1;
                    let tool = sim.tool_position;
                    let survey = survey_timed(&mut sim, &rest, &mut busy_seconds, |state| {
                        rest.survey_stride(state, tool, target)
                    })?;
                    clearance_floor = Some(survey.clear);
                    limit_approaching_stride(stride, survey, reach, margin)
                }
                None => None,
            };
            // Held back by more than a few batches' travel (the hand well ahead, not a
            // physics thread catching up after a short stall): the servo then solves with
            // the static K once there is one (see the published model below).
            // (Measured after the batch, against where the tool then is: a batch that was
            // not limited but ended in a first contact with the hand far ahead counts too.)
            let wanted = home + offset;
            let lag_limit = LAG_BATCHES * reach;
            if let Some(stride) = limited {
                target = sim.tool_position + stride;
                stats.speed_limited_batches += 1;
                if hand_speed > stats.max_tool_speed && contact_normal.is_some() {
                    let first = stats.hand_too_fast.get_or_insert(HandTooFast {
                        batches: 0,
                        from_seconds: sim.time,
                        max_hand_speed: 0.0,
                    });
                    first.batches += 1;
                    first.max_hand_speed = first.max_hand_speed.max(hand_speed);
                }
            }
            sim.tool_target = Some(target);
            let tool_before = sim.tool_position;
            if rest.is_asleep() && !rest.wakes_for(target) {
                pass_time_at_rest(&mut sim, steps);
                // Asleep, the surface stays where it is.
                clearance_floor = clearance_floor.map(|f| f - (target - tool_before).length());
                stats.slept_seconds += steps as f64 * sim.dt;
                physics.publish(LocalModel {
                    proxy: sim.tool_position - home,
                    stamp: command.stamp,
                    sim_time: sim.time,
                    active_particles: 0,
                    ..Default::default()
                });
                continue;
            }
            let t0 = Instant::now();
            let batch_seconds = steps as f64 * sim.dt;
            let result = sim.advance_with(steps, DivergencePolicy::HalveDt)?;
            let elapsed = t0.elapsed().as_secs_f64();
            busy_seconds += elapsed;
            if batch_ms.len() < MAX_TIMINGS {
                batch_ms.push(elapsed * 1e3);
            }
            stats.batches += 1;
            // A divergence the halvings could not mend, or design 8 running away down its
            // remainder energy (see `run`), ends the session.
            let ended = match &result {
                Guarded::Diverged { step, vertex } => {
                    Some(diverged_status(&sim, *step, *vertex, sim.dt))
                }
                Guarded::Done(s) => energy_floor.and_then(|floor| {
                    let elastic = crate::run::BodyEnergy::of(&sim, s).elastic;
                    (elastic < floor).then_some(RunStatus::EnergyBelowZero {
                        step: sim.steps_done,
                        elastic,
                    })
                }),
                Guarded::Retry { .. } => None,
            };
            if let Some(end) = ended {
                status = end;
                physics.publish(LocalModel {
                    diverged: true,
                    stamp: command.stamp,
                    sim_time: sim.time,
                    ..Default::default()
                });
                servo.stop();
                break;
            }
            let diverged = match result {
                Guarded::Retry { step, vertex, dt } => {
                    stats.divergences += 1;
                    // It diverged at the step before the halving.
                    unrecovered = Some((step, vertex, 2.0 * dt));
                    true
                }
                Guarded::Done(_) | Guarded::Diverged { .. } => {
                    unrecovered = None;
                    false
                }
            };
            let report = sim.last_tool.unwrap_or_default();
            let in_contact = report.contacts > 0 && !diverged;
            // Less the tool's travel and the surface's over the batch (twice its fastest
            // vertex at the batch's end: a settling surface slows); unknown in contact or
            // after a divergence (the state went back).
            surface_speed = match &result {
                Guarded::Done(s) => s.max_speed(),
                _ => 0.0,
            };
            clearance_floor = match &result {
                Guarded::Done(s) if !in_contact => clearance_floor.map(|f| {
                    f - (sim.tool_position - tool_before).length()
                        - 2.0 * s.max_speed() * batch_seconds
                }),
                _ => None,
            };
            // Also held back when the pose where the hand and the settled tissue balance
            // lies that far from the tool: with the contact springs' K in the solve the proxy
            // stays within a fraction of a batch's travel of the tool however far ahead the
            // hand is, so by the proxy alone a press that began following never showed a lag,
            // and the hand felt the coupling spring stretched over it (a brisk 3 mm press on
            // lv_touch peaked at 0.46 N, held 0.065 N, on one 2-core host, 0.18 N now; on
            // another the press had begun held back and peaked at 0.2–0.25 N).
            // The hand clamped to the workspace as the tool's target is; the static K only
            // (with only the contact springs' K there is none: the servo then solves with
            // none while held back, and the springs' K would give the proxy's offset again).
            let mut hand_offset = command.device_position;
            if hand_offset.length() > spec.workspace_radius {
                hand_offset *= spec.workspace_radius / hand_offset.length();
            }
            let settled_k = if k_is_springs {
                DMat3::ZERO
            } else {
                ramped_stiffness(published_k, stiffness_ramp, command.stamp)
            };
            let balance = hand_balance_offset(
                coupling_stiffness,
                settled_k,
                home + hand_offset - sim.tool_position,
                report.force
                    - pushed_by_dampers(
                        &report,
                        tool_damping,
                        batch_seconds,
                        sim.tool_position - tool_before,
                    ),
            );
            // The balance counts only while the hand itself outruns the speed limit (see
            // `is_held_back`).
            let held_back = is_held_back(
                (wanted - sim.tool_position).length(),
                in_contact && hand_speed > stats.max_tool_speed,
                balance.length(),
                lag_limit,
            );
            contact_normal =
                (in_contact && report.force.length() > 0.0).then(|| report.force.normalize());
            if in_contact {
                stats.contact_batches += 1;
                if report.force.length() > DVec3::from(stats.peak_tool_force).length() {
                    stats.peak_tool_force = report.force.to_array();
                }
            }
            // Whether the inversion count and the static-stiffness refresh are due; both run
            // after the model is published, on a state read then: a refresh that needs new
            // columns of the compliance (the first contact, a contact that spreads) took 5–35
            // ms, and the servo rendered no force meanwhile at a first contact. The refreshed
            // K goes out with the next batch's model.
            let mut read_due = None;
            let mut to_refresh = None;
            if !in_contact {
                published_k = DMat3::ZERO;
                last_refresh = None;
                last_check = None;
                // A warm-up cut short by the contact ending starts over at the next one.
                warming_batches = 0;
                stiffness_ramp = None;
                k_is_springs = false;
            } else {
                let due = |t: Option<Instant>| {
                    t.is_none_or(|t| t.elapsed().as_secs_f64() >= opts.stiffness_period)
                };
                let refresh = matches!(stiffness, StiffnessSource::Static(_)) && due(last_refresh);
                let check = due(last_check);
                let t = Instant::now();
                match &stiffness {
                    StiffnessSource::Frozen(_) => {
                        published_k = report.stiffness;
                        k_is_springs = true;
                    }
                    StiffnessSource::Static(_) if refresh => {
                        // Stamped at the read, as the count's timer is (after a warm-up the
                        // two drift apart, and a period may read the state twice).
                        to_refresh = Some(t);
                        last_refresh = Some(t);
                    }
                    StiffnessSource::Static(_) => {}
                }
                if check {
                    last_check = Some(t);
                }
                read_due = (refresh || check).then_some(check);
            }
            // Held back with only the contact springs' K (the frozen tissue's, or no contact
            // points for the static one), the servo solves with no K at all: the springs' K
            // renders k_c × lag.
            let model_out = LocalModel {
                force: if diverged { DVec3::ZERO } else { report.force },
                stiffness: if held_back && k_is_springs {
                    DMat3::ZERO
                } else {
                    ramped_stiffness(published_k, stiffness_ramp, command.stamp)
                },
                // A tool held back (by more than LAG_BATCHES batches' travel) does not
                // follow the proxy: the servo solves with the static K (the force the
                // hand's pose will meet once the tissue has moved), not with the contact
                // springs' K, which rendered the coupling spring stretched over the lag
                // (k_c·lag: 0.57 N against 0.1 N pressing lv_touch 3 mm at 0.1 m/s).
                // Before a first contact's static K is ready (a few tens of batches) the
                // solve has no K: the hand feels f0, the tissue's force at the lagging
                // tool (less the dampers' push of the batch's own move), and K adds K·lag
                // when it comes, over STIFFNESS_RAMP_SECONDS (0.24 N pressing 6 mm at
                // 2 m/s; the contact springs' K there rendered 1.1–1.5 N).
                contact_stiffness: if in_contact && !held_back {
                    report.stiffness
                } else {
                    DMat3::ZERO
                },
                proxy: sim.tool_position - home,
                stamp: command.stamp,
                sim_time: sim.time,
                diverged,
                in_contact,
                penetration: report.max_penetration,
                active_particles: sim.last_particles.map_or(0, |p| p.dynamic),
                ..Default::default()
            }
            .with_batch_damper(
                if in_contact { tool_damping } else { 0.0 },
                report.contact_area,
                batch_seconds,
                sim.tool_position - tool_before,
            );
            physics.publish(if held_back {
                model_out.without_damper(reach)
            } else {
                model_out
            });
            let state_read = match read_due {
                Some(check) => Some(((sim.state()?, sim.particle_state()?), check)),
                None => None,
            };
            if let (Some(t), StiffnessSource::Static(compliance), Some(((state, particles), _))) =
                (to_refresh, &mut stiffness, &state_read)
            {
                let points = contact_points(
                    &model,
                    &state.displacements,
                    particles.as_ref(),
                    sim.tool_position,
                );
                // New compliance columns (a first contact, a contact that spreads) are solved
                // a few per batch, the refresh due again until they are all there: at once
                // they held the physics thread 5–35 ms, the servo rendering a stale model.
                let missing = compliance.missing_columns(&points);
                let warm = missing.is_empty()
                    || !compliance.fits_in_cache(missing.len())
                    || warming_batches >= MAX_WARMING_BATCHES
                    || compliance.warm_columns(&missing, COLUMN_BUDGET) == missing.len();
                warming_batches = if warm { 0 } else { warming_batches + 1 };
                let took = if warm {
                    let now = clock.now();
                    let rendered = ramped_stiffness(published_k, stiffness_ramp, now);
                    k_is_springs = points.is_empty();
                    published_k = if k_is_springs {
                        report.stiffness
                    } else {
                        compliance.stiffness(&points)
                    };
                    stiffness_ramp = Some((rendered, now));
                    stats.stiffness_refreshes += 1;
                    let took = t.elapsed().as_secs_f64();
                    if refresh_ms.len() < MAX_TIMINGS {
                        refresh_ms.push(took * 1e3);
                    }
                    took
                } else {
                    stats.column_warmup_batches += 1;
                    last_refresh = None;
                    t.elapsed().as_secs_f64()
                };
                // Physics-thread work between batches, as the count below.
                busy_seconds += took;
            }
            if let Some(((state, particles), true)) = state_read {
                let t = Instant::now();
                let n = match &probe {
                    Some(p) => p.inverted(&model, &state, particles.as_ref()),
                    None => crate::inversion::inverted(&model, &state, None),
                };
                stats.inversion_checks += 1;
                stats.inverted_peak.record(n, sim.time);
                // Physics-thread work between batches: counted as busy time.
                busy_seconds += t.elapsed().as_secs_f64();
            }
            if let Guarded::Done(s) = result {
                if opts.sleep_at_rest
                    && rest.after_batch(&sim, &s, in_contact)
                    && rest.try_sleep(&sim.state()?, sim.tool_position)
                {
                    stats.sleeps += 1;
                }
            }
        }
        Ok(())
    })();
    if outcome.is_err() {
        servo.stop();
    }
    let servo_report: ServoReport = servo.join()?;
    outcome?;
    if let (RunStatus::Ok, Some((step, vertex, dt))) = (&status, unrecovered) {
        // The state is the one rolled back to, for a retry at the halved dt.
        status = diverged_status(&sim, step, vertex, dt);
        if let RunStatus::Diverged { rolled_back_to, .. } = &mut status {
            *rolled_back_to = Some((sim.steps_done, sim.dt));
        }
    }
    let wall = start.elapsed().as_secs_f64();
    stats.tool_stiffness = published_k.transpose().to_cols_array_2d();
    let busy = busy_seconds;
    stats.busy_fraction = busy / wall.max(1e-9);
    stats.realtime_capacity = (sim.time - stats.slept_seconds) / busy.max(1e-9);
    stats.batch_wall_ms = Spread::of(&mut batch_ms);
    stats.stiffness_refresh_ms = Spread::of(&mut refresh_ms);

    // Every output is tried even after one fails (a full disk may still take the small
    // summary.json, which lists the failures); the session's error names them all.
    let mut output_errors = crate::output::OutputErrors::default();
    let mut keep = |r| output_errors.keep(r);
    keep(servo_report.log.write_csv(&opts.out.join("haptic.csv")));
    let state = sim.state()?;
    keep(write_atomic(
        &opts.out.join("final.vtu"),
        state_vtu(&model, &state).as_bytes(),
    ));
    let particles = sim.particle_state()?;
    if let Some(snap) = &particles {
        keep(write_atomic(
            &opts.out.join("particles_final.vtu"),
            crate::output::particles::particles_vtu(&model, &state, snap).as_bytes(),
        ));
    }
    let mut summary = HapticSummary {
        run: summarize(scene, &sim, &state, particles.as_ref(), wall, status, None),
        haptic: HapticStats {
            device: servo_report.device_name,
            device_spec: spec,
            servo: servo_report.stats,
            device_stats: servo_report.device,
            physics: stats,
        },
    };
    summary.run.output_errors = output_errors.messages();
    output_errors.keep(summary.write(&opts.out));
    output_errors.into_result().map(|()| summary)
}

/// Wait until the servo publishes a tool command newer than `seen`, at most `period`: sleep
/// until 100 µs before the tick is `due`, then poll, yielding the core between polls (a sleep
/// of tens of µs lasts up to 100 µs on Linux, most of the margin a batch has).
fn wait_for_a_tick(
    physics: &mut crate::haptics::PhysicsLink,
    seen: u64,
    due: Instant,
    period: Duration,
) {
    let start = Instant::now();
    let until = start + period;
    let wake = due.checked_sub(Duration::from_micros(100)).unwrap_or(start);
    if wake > start {
        std::thread::sleep((wake - start).min(period));
    }
    while physics.tool().1 <= seen && Instant::now() < until {
        std::thread::yield_now();
    }
}

#[cfg(test)]
mod tests {
    use super::{
        hand_balance_offset, is_held_back, limit_approaching_stride, limit_pressing_stride,
        limit_withdrawal_remainder, withdrawal_head,
    };
    use crate::rest::StrideSurvey;
    use glam::{DMat3, DVec3};

    /// The brisk press's batch (lv_touch, 3 mm at 0.1 m/s): the proxy 110 µm from the tool,
    /// under the 142 µm limit (the contact springs' K held it there), the hand's balance 0.82
    /// mm away, the hand faster than the speed limit: held back (by the proxy alone it was
    /// not, and the hand felt k_c × its 1.3 mm lag, 0.46 N). Not once the hand is slower.
    #[test]
    fn a_hand_outrunning_the_speed_limit_far_from_its_balance_holds_the_tool_back() {
        let limit = 1.42e-4;
        // (proxy lag, hand faster than the limit in contact, balance)
        assert!(is_held_back(1.1e-4, true, 0.82e-3, limit));
        assert!(!is_held_back(1.1e-4, false, 0.82e-3, limit));
        assert!(is_held_back(2.0e-4, false, 0.0, limit));
        assert!(!is_held_back(1.1e-4, true, 1.0e-4, limit));
    }

    /// The balance of hand and settled tissue: none for a hand resting on the tissue's force
    /// (the coupling stretched f/k_c), about the lag for a hand ahead of a barely pushed tool
    /// (the brisk press's 1.3 mm lag against f = 0.14 N, k_c = 360 N/m, K = −38 N/m: 0.82
    /// mm), and the series of coupling and tissue in between.
    #[test]
    fn the_hands_balance_is_where_coupling_and_settled_tissue_meet() {
        let (kc, k) = (360.0, DMat3::from_diagonal(DVec3::splat(-38.0)));
        let f = DVec3::new(0.14, 0.0, 0.0);
        let resting = DVec3::new(-0.14 / kc, 0.0, 0.0);
        assert!(hand_balance_offset(kc, k, resting, f).length() < 1e-15);
        let ahead = DVec3::new(-1.3e-3, 0.0, 0.0);
        let e = hand_balance_offset(kc, k, ahead, f);
        let want = (kc * -1.3e-3 + 0.14) / (kc + 38.0);
        assert!(
            (e.x - want).abs() < 1e-12 && e.y == 0.0 && e.z == 0.0,
            "{e}"
        );
        assert!((e.x + 0.824e-3).abs() < 0.001e-3, "{e}");
        // With no static K yet, the hand's lag less the coupling's stretch.
        let e = hand_balance_offset(kc, DMat3::ZERO, ahead, f);
        assert!((e.x - (-1.3e-3 + 0.14 / kc)).abs() < 1e-12, "{e}");
    }

    #[test]
    fn an_approaching_stride_stops_at_the_surface_unless_it_stays_clear() {
        let survey = |clear, clear_after, swept_clear| StrideSurvey {
            clear,
            clear_after,
            swept_clear,
        };
        let close = |a: DVec3, b: DVec3| (a - b).length() < 1e-12;
        let stride = DVec3::new(0.0, 0.0, -0.5);
        let limit = |s, margin| limit_approaching_stride(stride, s, 0.01, margin);
        // Towards the tissue 0.1 away (the swept tool meets it): stopped there.
        let s = limit(survey(0.1, 0.0, -0.01), 0.0).unwrap();
        assert!(close(s, DVec3::new(0.0, 0.0, -0.1)));
        // Closer than a reach: a reach.
        let s = limit(survey(0.001, 0.0, -0.01), 0.0).unwrap();
        assert!(close(s, DVec3::new(0.0, 0.0, -0.01)));
        // Within the clearance: free.
        assert_eq!(limit(survey(0.6, 0.1, 0.1), 0.0), None);
        // Clear all the way past the body, by more than the surface may move: free.
        assert_eq!(limit(survey(0.1, 0.1, 0.05), 0.01), None);
        // Passing 1 µm over an awake surface: limited to the start's clearance.
        let s = limit(survey(0.1, 0.1, 1e-6), 0.01).unwrap();
        assert!(close(s, DVec3::new(0.0, 0.0, -0.1)));
        // Straight away: free, however long, and from a face it touches too.
        assert_eq!(limit(survey(0.001, 0.501, 0.001), 0.01), None);
        assert_eq!(limit(survey(-0.001, 0.499, -0.001), 0.01), None);
        // Grazing an edge on the way (the swept tool dips into it): stopped at the start's
        // clearance.
        let s = limit(survey(0.1, 0.6, -0.002), 0.0).unwrap();
        assert!(close(s, DVec3::new(0.0, 0.0, -0.1)));
        // Sliding along a face it touches (clearance −1 mm all the way, contact found at no
        // vertex): a reach, as a slide in contact; deeper, a reach too.
        let s = limit(survey(-0.001, -0.001, -0.001), 0.0).unwrap();
        assert!(close(s, DVec3::new(0.0, 0.0, -0.01)));
        let s = limit(survey(-0.001, -0.004, -0.004), 0.0).unwrap();
        assert!(close(s, DVec3::new(0.0, 0.0, -0.01)));
    }

    #[test]
    fn a_long_withdrawal_stops_at_tissue_it_would_meet_again() {
        let n = DVec3::Z;
        let close = |a: DVec3, b: DVec3| (a - b).length() < 1e-12;
        // Within the penetration and a reach (1 mm and 10 mm): no head, nothing to survey.
        assert_eq!(withdrawal_head(0.011 * n, n, 0.001, 0.01), None);
        assert_eq!(
            withdrawal_head(DVec3::new(0.01, 0.0, -0.5), n, 0.001, 0.01),
            None
        );
        // Farther: the head is the stride up to 11 mm out, along the stride.
        let stride = DVec3::new(0.01, 0.0, 0.044);
        let head = withdrawal_head(stride, n, 0.001, 0.01).unwrap();
        assert!(close(head, stride / 4.0));
        // A negative penetration counts as none.
        assert!(close(
            withdrawal_head(0.04 * n, n, -0.5, 0.01).unwrap(),
            0.01 * n
        ));
        let survey = |clear, clear_after, swept_clear| StrideSurvey {
            clear,
            clear_after,
            swept_clear,
        };
        let remainder = 0.05 * n;
        let limit = |s, margin| limit_withdrawal_remainder(remainder, s, 0.01, margin);
        // Out of a shallow dimple into free space, clearance growing: free.
        assert_eq!(limit(survey(0.01, 0.06, 0.01), 0.02), None);
        // Out of a deep dimple (the clearance grows slower than the stride, and the surface
        // springs back faster than the margin allows): still free, it never gets closer.
        assert_eq!(limit(survey(0.002, 0.02, 0.002), 0.02), None);
        // Still overlapping the dimple's rim where it starts, and receding: free.
        assert_eq!(limit(survey(-0.001, 0.01, -0.001), 0.02), None);
        // Across a cavity into its opposite wall 30 mm on (the swept tool meets it): cut to
        // the start's clearance, 30 mm of clearance the wall leaves at the start...
        let s = limit(survey(0.03, -0.015, -0.02), 0.0).unwrap();
        assert!(close(s, 0.03 * n));
        // ... or to a reach where the start is closer than that.
        let s = limit(survey(0.004, -0.015, -0.02), 0.0).unwrap();
        assert!(close(s, 0.01 * n));
        // Past another part of the body without touching it, by more than the margin: free.
        assert_eq!(limit(survey(0.02, 0.05, 0.005), 0.001), None);
        // Past it by less than the surface may move: cut.
        let s = limit(survey(0.02, 0.05, 0.005), 0.01).unwrap();
        assert!(close(s, 0.02 * n));
    }

    /// On the built-in LV (SI, the cavity about 1 cm across at z = -5 mm) with a 1 mm tool:
    /// a withdrawal from the endocardium across the cavity does not jump into the far wall, and one
    /// from the epicardium out into the room, or back from the endocardium to the cavity's
    /// middle, is free.
    #[test]
    fn a_withdrawal_across_the_lv_cavity_does_not_jump_into_its_far_wall() {
        let (watch, state) = crate::rest::tests::watch_at_rest(
            "lv",
            "radius = 0.001\nstiffness = 1.0e8\nhome = [0.0, 0.0, 0.02]\n",
        );
        let r = 0.001;
        let (reach, p) = (5e-4, 1e-4);
        let at = |c: DVec3| watch.survey_stride(Some(&state), c, c).clear;
        // Where a line from the axis at z = -5 mm along `dir` crosses the surface (a point's
        // distance, the clearance plus r, at a local minimum near zero): the endocardium,
        // then the epicardium.
        let axis = DVec3::new(0.0, 0.0, -0.005);
        let crossings = |dir: DVec3| {
            let d = |k: usize| at(axis + dir * (k as f64 * 1e-5)) + r;
            (1..2000)
                .filter(|&k| d(k) < 2e-5 && d(k) <= d(k - 1) && d(k) <= d(k + 1))
                .map(|k| k as f64 * 1e-5)
                .collect::<Vec<_>>()
        };
        let (minus, plus) = (crossings(-DVec3::X), crossings(DVec3::X));
        assert!(minus.len() == 2 && plus.len() == 2, "{minus:?} {plus:?}");
        assert!(plus[0] > 0.003 && plus[1] > plus[0] + 0.002, "{plus:?}");
        // Pressing the endocardium at -x (the push along +x), 0.1 mm in.
        let c = axis - DVec3::X * (minus[0] - r + p);
        let limited = |stride: DVec3, normal: DVec3| {
            let head = withdrawal_head(stride, normal, p, reach)?;
            let survey = watch.survey_withdrawal(Some(&state), c, c + head, c + stride);
            limit_withdrawal_remainder(stride - head, survey, reach, 0.0).map(|s| head + s)
        };
        // Across the cavity to 2 mm into the far wall, in one batch (a stall): it leaves the
        // near wall by the head and the remainder's start clearance, clear of both walls.
        let across = DVec3::X * (minus[0] + plus[0] - 2.0 * r + p + 0.002);
        let s = limited(across, DVec3::X).expect("limited");
        assert!(
            s.x > p + reach && at(c + s) > 0.0,
            "{s:?} leaves {}",
            at(c + s)
        );
        // The batches after it, out of contact, approach the far wall no deeper than a reach
        // into it (a sphere march at the clearance): as fast as they may, never a jump in.
        let (mut tool, target) = (c + s, c + across);
        let mut batches = 0;
        while at(tool) > 0.0 {
            let stride = target - tool;
            let survey = watch.survey_stride(Some(&state), tool, target);
            tool += limit_approaching_stride(stride, survey, reach, 0.0).unwrap_or(stride);
            batches += 1;
            assert!(
                at(tool) >= -reach - 1e-9 && batches < 100,
                "{tool:?}: {}",
                at(tool)
            );
        }
        assert!(batches > 1 && tool.x < target.x, "{batches} {tool:?}");
        // Back to the cavity's middle: free.
        assert_eq!(limited(DVec3::X * (minus[0] - r + p), DVec3::X), None);
        // From the epicardium at +x out 5 cm into the room: free.
        let c_out = axis + DVec3::X * (plus[1] + r - p);
        let head = withdrawal_head(0.05 * DVec3::X, DVec3::X, p, reach).unwrap();
        let survey =
            watch.survey_withdrawal(Some(&state), c_out, c_out + head, c_out + 0.05 * DVec3::X);
        assert_eq!(
            limit_withdrawal_remainder(0.05 * DVec3::X - head, survey, reach, 0.0),
            None,
            "{survey:?}"
        );
        // The same with the tool's centre 1 mm inside the epicardium (as where particles
        // resolve a deep press and the coarse surface passes through the tool): free, though
        // against the whole surface the way out first nears it.
        let c_in = axis + DVec3::X * (plus[1] - 0.001);
        let out = 0.05 * DVec3::X;
        let head = withdrawal_head(out, DVec3::X, p, reach).unwrap();
        let survey = watch.survey_withdrawal(Some(&state), c_in, c_in + head, c_in + out);
        assert_eq!(
            limit_withdrawal_remainder(out - head, survey, reach, 0.0),
            None,
            "{survey:?}"
        );
        let whole = watch.survey_stride(Some(&state), c_in + head, c_in + out);
        assert!(limit_withdrawal_remainder(out - head, whole, reach, 0.0).is_some());
    }

    #[test]
    fn a_pressing_stride_is_limited_and_a_withdrawal_is_not() {
        let n = DVec3::X;
        let close = |a: DVec3, b: DVec3| (a - b).length() < 1e-12;
        // 0.1 of penetration, deeper than any stride below unless said.
        let limit = |s, p| limit_pressing_stride(s, n, p, 1.0);
        // Straight out of the tissue, however far: no limit.
        assert_eq!(limit(10.0 * n, 20.0), None);
        // Within reach: no limit.
        assert_eq!(limit(DVec3::new(-0.5, 0.5, 0.0), 20.0), None);
        // Straight in: shortened to the reach.
        assert!(close(limit(-3.0 * n, 20.0).unwrap(), -n));
        // Out and along, still touching all the way: the withdrawal kept whole, the slide
        // shortened.
        assert!(close(
            limit(DVec3::new(5.0, 3.0, 0.0), 20.0).unwrap(),
            DVec3::new(5.0, 1.0, 0.0)
        ));
        // A pull 25° off the normal from a penetration of 1: it leaves the tissue after a
        // tenth of it, having slid 0.47 in contact: free. From 4: 1.9 in contact, the slide
        // shortened to 1 / 0.4.
        let pull_25 = DVec3::new(10.0, 10.0 * 25f64.to_radians().tan(), 0.0);
        assert_eq!(limit(pull_25, 1.0), None);
        assert!(close(
            limit(pull_25, 4.0).unwrap(),
            DVec3::new(10.0, 2.5, 0.0)
        ));
        // A stride 31° off it, from a penetration of 1: sliding all the way, shortened to 1.
        let s = limit(DVec3::new(10.0, 10.0 * 31f64.to_radians().tan(), 0.0), 1.0);
        assert!(close(s.unwrap(), DVec3::new(10.0, 1.0, 0.0)));
        // A straight pull of 20 whose contact normal is tilted 10° from it, from a penetration
        // of 2: it slides 0.35 in contact, free; from no penetration, free too.
        let pull = 20.0 * DVec3::new(10f64.to_radians().cos(), 10f64.to_radians().sin(), 0.0);
        assert_eq!(limit(pull, 2.0), None);
        assert_eq!(limit(pull, 0.0), None);
        // ... while deeper than the pull, the whole slide is in contact: shortened.
        assert!(limit(pull, 30.0).is_some());
        // In and along: the whole stride shortened, its direction kept.
        let s = limit(DVec3::new(-2.0, 0.0, 2.0), 0.0).unwrap();
        assert!(close(s, DVec3::new(-1.0, 0.0, 1.0) / 2f64.sqrt()));
    }
}
