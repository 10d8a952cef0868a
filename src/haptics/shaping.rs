//! Force shaping, in the order of DESIGN §7:
//!
//! 1. **unilateral**: the tissue pushes, it never pulls: zero when the model is not in
//!    contact, and zero when the model's force at the tool would point against the model's
//!    force direction n = f0/|f0| (the tool left the tissue) — [`unilateral`], applied
//!    inside the coupling solve;
//! 2. **stiffness cap**: the stiffness the hand feels is at most
//!    k_max = min(2b/T, device max stiffness) — through the virtual coupling, whose spring
//!    k_c ≤ k_max bounds the series stiffness (see [`super::coupling`]);
//! 3. **magnitude clamp** to the device's force limit keeping the direction (counted) —
//!    [`clamp_magnitude`];
//! 4. **start-up ramp**: forces engage once the commanded force has stayed below
//!    `engage_force` for `engage_ticks` ticks (CHAI3D's safety rule), then the gain rises
//!    0 → 1 over `ramp_time`;
//! 5. **fade**: the gain falls smoothly to zero over `fade_out` while the model is stale
//!    (older than `stale_after`), the simulation diverged or the device is not fresh, and
//!    comes back over `fade_in` when the condition clears.
//!
//! Ramp and fade gains follow a smoothstep s²(3 − 2s) of a linear state, so the force has no
//! kink. Both are time-varying gains: raising the gain while the tool is in the tissue
//! adds energy; the passivity controller ([`super::observer`]) removes what the observer
//! sees.

use glam::DVec3;

/// Below this |f0| (N) a model has no usable force direction; it renders no force.
pub const MIN_MODEL_FORCE: f64 = 1.0e-9;

/// Stage 1: the model's force `f` at the tool, kept only while it pushes along the model's
/// force direction n = f0/|f0|: `f` if f·n > 0, else zero. Zero when |f0| is below
/// [`MIN_MODEL_FORCE`] (no contact to speak of).
pub fn unilateral(f: DVec3, f0: DVec3) -> DVec3 {
    if f0.length() <= MIN_MODEL_FORCE || f.dot(f0) <= 0.0 {
        DVec3::ZERO
    } else {
        f
    }
}

/// Stage 3: `f` scaled down to magnitude `max` keeping its direction; `true` when clamped.
pub fn clamp_magnitude(f: DVec3, max: f64) -> (DVec3, bool) {
    let n = f.length();
    if n > max && n > 0.0 {
        (f * (max / n), true)
    } else {
        (f, false)
    }
}

/// s²(3 − 2s) for s clamped to [0, 1].
pub fn smoothstep(s: f64) -> f64 {
    let s = s.clamp(0.0, 1.0);
    s * s * (3.0 - 2.0 * s)
}

/// Shaping parameters (defaults: [`ShapingParams::for_max_force`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShapingParams {
    /// N: the device's force limit.
    pub max_force: f64,
    /// s: start-up ramp length (default 1 s).
    pub ramp_time: f64,
    /// N: the force must stay below this to engage (default 0.2 N, CHAI3D).
    pub engage_force: f64,
    /// Ticks the force must stay below `engage_force` to engage (default 10).
    pub engage_ticks: u32,
    /// s: a model older than this is stale (default 20 ms: a batch of ≈ 1 ms plus a readback
    /// ring of a few batches stays well below it; a stalled physics thread does not).
    pub stale_after: f64,
    /// s: fade to zero (default 50 ms: fast enough to stop a stale or diverged force within
    /// a few hand-movement periods, slow enough to feel like a release, not a jolt).
    pub fade_out: f64,
    /// s: fade back in (default 200 ms: raising the force in contact adds energy, so slower).
    pub fade_in: f64,
}

impl ShapingParams {
    /// The defaults for a device whose force limit is `max_force` (N).
    pub fn for_max_force(max_force: f64) -> Self {
        ShapingParams {
            max_force,
            ramp_time: 1.0,
            engage_force: 0.2,
            engage_ticks: 10,
            stale_after: 0.020,
            fade_out: 0.050,
            fade_in: 0.200,
        }
    }
}

/// Why the force should fade this tick.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FadeCause {
    /// No model yet, or older than `stale_after`.
    pub stale: bool,
    /// The simulation diverged or the model is not finite.
    pub diverged: bool,
    /// The device input is not fresh.
    pub device_stale: bool,
}

impl FadeCause {
    /// Any cause.
    pub fn any(&self) -> bool {
        self.stale || self.diverged || self.device_stale
    }
}

/// What [`ForceShaper::shape`] did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shaped {
    /// N: the shaped force.
    pub force: DVec3,
    /// The gain applied after the clamp: ramp × fade, in [0, 1].
    pub gain: f64,
    /// The magnitude was clamped, and the force sent is not zero (a clamp under a zero
    /// gain, fading or before the start-up ramp, sends nothing and counts as none).
    pub clamped: bool,
    /// The start-up ramp is not finished (or not engaged).
    pub ramping: bool,
    /// The fade gain is below 1.
    pub fading: bool,
}

/// Stages 3–5 with their state.
#[derive(Clone, Debug)]
pub struct ForceShaper {
    params: ShapingParams,
    calm_ticks: u32,
    engaged: bool,
    ramp: f64,
    fade: f64,
}

impl ForceShaper {
    /// A shaper that starts disengaged and faded out.
    pub fn new(params: ShapingParams) -> Self {
        ForceShaper {
            params,
            calm_ticks: 0,
            engaged: false,
            ramp: 0.0,
            fade: 0.0,
        }
    }

    /// The parameters.
    pub fn params(&self) -> &ShapingParams {
        &self.params
    }

    /// Shape `force` (already unilateral and through the coupling), `dt` seconds after the
    /// last call.
    pub fn shape(&mut self, dt: f64, force: DVec3, cause: FadeCause) -> Shaped {
        let p = &self.params;
        let dt = dt.max(0.0);
        let (f, clamped) = clamp_magnitude(force, p.max_force);
        if !self.engaged {
            if f.length() < p.engage_force {
                self.calm_ticks += 1;
                self.engaged = self.calm_ticks >= p.engage_ticks;
            } else {
                self.calm_ticks = 0;
            }
        }
        if self.engaged {
            self.ramp = if p.ramp_time > 0.0 {
                (self.ramp + dt / p.ramp_time).min(1.0)
            } else {
                1.0
            };
        }
        self.fade = if cause.any() {
            if p.fade_out > 0.0 {
                (self.fade - dt / p.fade_out).max(0.0)
            } else {
                0.0
            }
        } else if p.fade_in > 0.0 {
            (self.fade + dt / p.fade_in).min(1.0)
        } else {
            1.0
        };
        let gain = smoothstep(self.ramp) * smoothstep(self.fade);
        Shaped {
            force: f * gain,
            gain,
            clamped: clamped && gain > 0.0,
            ramping: self.ramp < 1.0,
            fading: self.fade < 1.0,
        }
    }
}
