//! The haptic device abstraction, after CHAI3D's generic device: a pose and velocity in,
//! a force out, and a specification of what the device can render.

use super::model::ForceCommand;
use super::protocol::DropCounts;
use crate::error::{PalpateError, Result};
use glam::DVec3;
use serde::Serialize;

/// The period CHAI3D's "max closed-loop stiffness" figures refer to (a 1 kHz servo), s.
pub const SPEC_REFERENCE_PERIOD: f64 = 1.0e-3;

/// What a device can render (CHAI3D's `cHapticDeviceInfo`; values from CHAI3D's own device
/// classes, see `notes/haptics.md`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct DeviceSpec {
    /// Short name, as given to `--device-spec`.
    pub name: &'static str,
    /// N: largest continuous force.
    pub max_force: f64,
    /// N/m: largest closed-loop stiffness the device renders stably at 1 kHz.
    pub max_stiffness: f64,
    /// N·s/m: largest virtual damping the device renders stably.
    pub max_damping: f64,
    /// m: radius of the workspace.
    pub workspace_radius: f64,
}

impl DeviceSpec {
    /// How far from the origin any reading may lie, in workspace radii: scripted keyframes
    /// beyond it are refused and network poses dropped.
    pub const REACH: f64 = 10.0;

    /// Geomagic Touch.
    pub const TOUCH: DeviceSpec = DeviceSpec {
        name: "touch",
        max_force: 3.3,
        max_stiffness: 400.0,
        max_damping: 4.0,
        workspace_radius: 0.075,
    };
    /// SensAble / Geomagic Phantom Omni.
    pub const OMNI: DeviceSpec = DeviceSpec {
        name: "omni",
        max_force: 3.3,
        max_stiffness: 700.0,
        max_damping: 5.0,
        workspace_radius: 0.10,
    };
    /// SensAble Phantom Desktop.
    pub const DESKTOP: DeviceSpec = DeviceSpec {
        name: "desktop",
        max_force: 7.9,
        max_stiffness: 1000.0,
        max_damping: 5.0,
        workspace_radius: 0.10,
    };
    /// Force Dimension omega.3.
    pub const OMEGA3: DeviceSpec = DeviceSpec {
        name: "omega3",
        max_force: 12.0,
        max_stiffness: 5000.0,
        max_damping: 30.0,
        workspace_radius: 0.075,
    };
    /// Novint Falcon.
    pub const FALCON: DeviceSpec = DeviceSpec {
        name: "falcon",
        max_force: 8.0,
        max_stiffness: 3000.0,
        max_damping: 20.0,
        workspace_radius: 0.04,
    };
    /// Every named spec.
    pub const ALL: [DeviceSpec; 5] = [
        Self::TOUCH,
        Self::OMNI,
        Self::DESKTOP,
        Self::OMEGA3,
        Self::FALCON,
    ];
    /// The spec used when none is named: the most conservative (Geomagic Touch).
    pub const DEFAULT_NAME: &'static str = "touch";

    /// The named spec (case-insensitive; `omega.3`, `geomagic-touch`, `phantom-omni`,
    /// `phantom-desktop`, `novint-falcon` are accepted too). The error lists the names.
    pub fn by_name(name: &str) -> Result<DeviceSpec> {
        let key = name.trim().to_ascii_lowercase().replace(['_', '.'], "-");
        let canonical = match key.as_str() {
            "geomagic-touch" => "touch",
            "phantom-omni" => "omni",
            "phantom-desktop" => "desktop",
            "omega-3" | "omega3" => "omega3",
            "novint-falcon" => "falcon",
            other => other,
        };
        Self::ALL
            .iter()
            .find(|s| s.name == canonical)
            .copied()
            .ok_or_else(|| {
                let known: Vec<&str> = Self::ALL.iter().map(|s| s.name).collect();
                PalpateError::Usage(format!(
                    "--device-spec {name}: unknown device spec; known: {}",
                    known.join(", ")
                ))
            })
    }

    /// b, N·s/m: the device's physical damping as the spec implies it. CHAI3D's tables give
    /// no intrinsic damping, but their max closed-loop stiffness at 1 kHz is, by Colgate &
    /// Schenkel's condition b > K·T/2, the stiffness whose zero-order-hold energy leak the
    /// device's own damping absorbs: b = K_max·T₁ₖ/2. This b is what the passivity observer
    /// credits the device with and what caps the stiffness at other loop rates.
    pub fn physical_damping(&self) -> f64 {
        self.max_stiffness * SPEC_REFERENCE_PERIOD / 2.0
    }

    /// N/m: the largest stiffness that keeps a loop of period `period` (s) passive with a
    /// virtual damping `virtual_damping` (N·s/m): min(2(b − |B|)/T, max_stiffness), ≥ 0.
    pub fn max_passive_stiffness(&self, period: f64, virtual_damping: f64) -> f64 {
        let colgate = 2.0 * (self.physical_damping() - virtual_damping.abs()) / period;
        colgate.min(self.max_stiffness).max(0.0)
    }
}

impl Default for DeviceSpec {
    fn default() -> Self {
        Self::TOUCH
    }
}

/// One reading of a device.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DeviceReading {
    /// m, device frame, relative to the tool home.
    pub position: DVec3,
    /// m/s.
    pub velocity: DVec3,
    /// Bit i = button i pressed.
    pub buttons: u32,
    /// The reading is current (a network device whose packets stopped is not fresh; the
    /// servo then fades the force to zero).
    pub fresh: bool,
    /// s, loop clock: when the pose was sampled, for a device whose pose can be older than
    /// the read (a network device: when its last packet arrived); `None`: at the read.
    /// The pose gate measures how far a hand could have moved by it.
    pub sampled: Option<f64>,
}

/// Counters a device keeps (all zero for local devices).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct DeviceStats {
    /// Datagrams received.
    pub received: u64,
    /// Pose packets accepted.
    pub accepted: u64,
    /// Packets dropped, by reason.
    pub dropped: DropCounts,
    /// Force packets sent.
    pub sent: u64,
    /// Force packets the socket refused (would block, unreachable, …).
    pub send_errors: u64,
    /// Times the input went from fresh to not fresh (keep-alive expired).
    pub keepalive_timeouts: u64,
}

/// A haptic device (CHAI3D's `cGenericHapticDevice`): the servo thread calls `read` and
/// `send` once per tick. Implementations must not allocate, block or take locks in either.
pub trait HapticDevice: Send {
    /// What the device can render.
    fn spec(&self) -> DeviceSpec;
    /// A one-line description, e.g. `udp:127.0.0.1:4242` (not called inside the loop).
    fn describe(&self) -> String;
    /// The pose at loop time `now` (s).
    fn read(&mut self, now: f64) -> DeviceReading;
    /// Apply `command.force` to the hand (or send it to the device).
    fn send(&mut self, now: f64, command: &ForceCommand);
    /// Counters (packets, drops) for the summary.
    fn stats(&self) -> DeviceStats {
        DeviceStats::default()
    }
    /// How long the device's input lasts, s, when it is known in advance (a scripted
    /// trajectory's last time); `None` for live devices.
    fn duration(&self) -> Option<f64> {
        None
    }
}

/// Capacity of the [`VelocityEstimator`] history.
const HISTORY: usize = 64;

/// Velocity from a time-stamped position history, as CHAI3D estimates it for devices that
/// report positions only: the least-squares slope of x(t) over the samples of the last
/// `window` seconds (CHAI3D: 15 ms), at most 64 samples. Allocation-free.
#[derive(Clone, Debug)]
pub struct VelocityEstimator {
    window: f64,
    times: [f64; HISTORY],
    positions: [DVec3; HISTORY],
    /// Index of the newest sample.
    head: usize,
    len: usize,
}

impl VelocityEstimator {
    /// CHAI3D's window, s.
    pub const DEFAULT_WINDOW: f64 = 0.015;

    /// An empty history with a window of `window` seconds.
    pub fn new(window: f64) -> Self {
        VelocityEstimator {
            window,
            times: [0.0; HISTORY],
            positions: [DVec3::ZERO; HISTORY],
            head: 0,
            len: 0,
        }
    }

    /// Add a sample (times must not decrease; an older one is ignored).
    pub fn push(&mut self, t: f64, x: DVec3) {
        if self.len > 0 && t <= self.times[self.head] {
            if t == self.times[self.head] {
                self.positions[self.head] = x;
            }
            return;
        }
        self.head = (self.head + 1) % HISTORY;
        self.times[self.head] = t;
        self.positions[self.head] = x;
        self.len = (self.len + 1).min(HISTORY);
    }

    /// v = Σ(tᵢ − t̄)(xᵢ − x̄) / Σ(tᵢ − t̄)² over the samples within the window of the newest;
    /// zero with fewer than two.
    pub fn velocity(&self) -> DVec3 {
        if self.len < 2 {
            return DVec3::ZERO;
        }
        let newest = self.times[self.head];
        let mut n = 0usize;
        let (mut st, mut sx) = (0.0, DVec3::ZERO);
        for k in 0..self.len {
            let i = (self.head + HISTORY - k) % HISTORY;
            if newest - self.times[i] > self.window && n >= 2 {
                break;
            }
            st += self.times[i] - newest;
            sx += self.positions[i];
            n += 1;
        }
        let (tm, xm) = (st / n as f64, sx / n as f64);
        let (mut stt, mut stx) = (0.0, DVec3::ZERO);
        for k in 0..n {
            let i = (self.head + HISTORY - k) % HISTORY;
            let dt = self.times[i] - newest - tm;
            stt += dt * dt;
            stx += dt * (self.positions[i] - xm);
        }
        if stt > 0.0 {
            stx / stt
        } else {
            DVec3::ZERO
        }
    }

    /// Forget the history.
    pub fn clear(&mut self) {
        self.len = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn velocity_of_a_ramp_is_its_slope() {
        let mut e = VelocityEstimator::new(0.015);
        for k in 0..40 {
            let t = k as f64 * 1e-3;
            e.push(t, DVec3::new(0.2 * t, -0.1 * t, 0.0));
        }
        let v = e.velocity();
        assert!((v - DVec3::new(0.2, -0.1, 0.0)).length() < 1e-9, "{v}");
    }

    #[test]
    fn passive_stiffness_matches_the_spec_at_1khz() {
        for s in DeviceSpec::ALL {
            let k = s.max_passive_stiffness(1e-3, 0.0);
            assert!((k - s.max_stiffness).abs() < 1e-9);
            assert!(s.max_passive_stiffness(2e-3, 0.0) < k);
        }
    }
}
