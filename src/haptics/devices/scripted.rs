//! `scripted:FILE`: a device that plays a trajectory from a CSV file.
//!
//! Format: one row `t,x,y,z` per line (s, m; positions relative to the tool home, the
//! physics side adds the scene's home). `#` starts a comment; blank lines are skipped; the
//! first non-blank line may be the header `t,x,y,z` (any case; no other header is
//! accepted). Times must be ≥ 0 and strictly increase. The position is linear between rows, held at
//! the first row before it and at the last row after it. Time 0 is the device's first read.
//! A row more than 10 workspace radii from the origin is refused (no device gets there).

use crate::error::{PalpateError, Result};
use crate::haptics::device::{DeviceReading, DeviceSpec, HapticDevice, VelocityEstimator};
use crate::haptics::model::ForceCommand;
use glam::DVec3;
use std::path::Path;

/// A piecewise-linear path x(t).
#[derive(Clone, Debug, PartialEq)]
pub struct Trajectory {
    times: Vec<f64>,
    points: Vec<DVec3>,
}

impl Trajectory {
    /// A trajectory through `(t, x)` keyframes; times must strictly increase and there must
    /// be at least one.
    pub fn new(keyframes: &[(f64, DVec3)]) -> Result<Trajectory> {
        if keyframes.is_empty() {
            return Err(PalpateError::Usage("trajectory: no keyframes".into()));
        }
        for (i, w) in keyframes.windows(2).enumerate() {
            if w[1].0 <= w[0].0 || !w[1].0.is_finite() {
                return Err(PalpateError::Usage(format!(
                    "trajectory: keyframe {}: time {} s is not after {} s",
                    i + 1,
                    crate::scene::Num(w[1].0),
                    crate::scene::Num(w[0].0)
                )));
            }
        }
        Ok(Trajectory {
            times: keyframes.iter().map(|k| k.0).collect(),
            points: keyframes.iter().map(|k| k.1).collect(),
        })
    }

    /// Read a trajectory CSV; errors name the file and the line.
    pub fn from_file(path: &Path) -> Result<Trajectory> {
        Self::read_rows(path).map(|(trajectory, _)| trajectory)
    }

    /// [`Trajectory::from_file`], with the file's line number of each row.
    fn read_rows(path: &Path) -> Result<(Trajectory, Vec<usize>)> {
        let text = crate::input::read_regular_text(path, crate::input::MAX_TRAJECTORY_BYTES)
            .map_err(|e| {
                PalpateError::Usage(format!("{}: cannot read trajectory: {e}", path.display()))
            })?;
        Self::parse_rows(&text, &path.display().to_string())
    }

    /// Parse trajectory CSV text; `origin` (the file name) prefixes every error, which is one
    /// line `origin: line N: what`.
    pub fn parse(text: &str, origin: &str) -> Result<Trajectory> {
        Self::parse_rows(text, origin).map(|(trajectory, _)| trajectory)
    }

    /// [`Trajectory::parse`], with the text's line number of each row (for later errors).
    fn parse_rows(text: &str, origin: &str) -> Result<(Trajectory, Vec<usize>)> {
        let err = |line: usize, what: String| {
            PalpateError::Usage(format!("{origin}: line {line}: {what}"))
        };
        let mut times = Vec::new();
        let mut points = Vec::new();
        let mut lines = Vec::new();
        let mut seen_content = false;
        // A byte-order mark (spreadsheets write one) is not part of the header.
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        for (index, raw) in text.lines().enumerate() {
            let line_no = index + 1;
            let line = raw.split('#').next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            // Counted before anything is collected: a line of 60 million commas took 1 GB.
            let count = line.split(',').count();
            let first_content = !seen_content;
            seen_content = true;
            if count != 4 {
                return Err(err(
                    line_no,
                    format!(
                        "expected 4 comma-separated fields t,x,y,z, found {count}{}",
                        if line.contains('\r') {
                            " (its lines end in a carriage return alone: save the file with LF or CRLF line endings)"
                        } else {
                            ""
                        }
                    ),
                ));
            }
            let fields: Vec<&str> = line.split(',').map(str::trim).collect();
            let parsed: Vec<Option<f64>> = fields.iter().map(|f| f.parse().ok()).collect();
            if first_content && parsed.iter().all(Option::is_none) {
                // A header: it must name the columns in the order they are read.
                let names: Vec<String> = fields.iter().map(|f| f.to_lowercase()).collect();
                if names != ["t", "x", "y", "z"] {
                    return Err(err(
                        line_no,
                        format!(
                            "header '{line}' does not name the columns t,x,y,z (in that order; they are read in that order)"
                        ),
                    ));
                }
                continue;
            }
            let mut row = [0.0; 4];
            for (k, (value, name)) in parsed.iter().zip(["t", "x", "y", "z"]).enumerate() {
                match value {
                    Some(v) if v.is_finite() => row[k] = *v,
                    Some(v) => return Err(err(line_no, format!("{name} = {v} is not finite"))),
                    None => {
                        return Err(err(
                            line_no,
                            format!("{name} = '{}' is not a number", fields[k]),
                        ))
                    }
                }
            }
            if row[0] < 0.0 {
                return Err(err(
                    line_no,
                    format!(
                        "time {} s is before the session's start at 0 s",
                        crate::scene::Num(row[0])
                    ),
                ));
            }
            if let Some(&last) = times.last() {
                if row[0] <= last {
                    return Err(err(
                        line_no,
                        format!(
                            "time {} s is not after the previous row's {} s (time must strictly increase)",
                            crate::scene::Num(row[0]),
                            crate::scene::Num(last)
                        ),
                    ));
                }
            }
            times.push(row[0]);
            points.push(DVec3::new(row[1], row[2], row[3]));
            lines.push(line_no);
        }
        if times.is_empty() {
            return Err(PalpateError::Usage(format!(
                "{origin}: no data rows (expected lines t,x,y,z in s and m)"
            )));
        }
        Ok((Trajectory { times, points }, lines))
    }

    /// The position at time `t`, m: linear between rows, held outside them. Allocation-free
    /// (binary search).
    pub fn at(&self, t: f64) -> DVec3 {
        let n = self.times.len();
        if t <= self.times[0] {
            return self.points[0];
        }
        if t >= self.times[n - 1] {
            return self.points[n - 1];
        }
        let i = self.times.partition_point(|&ti| ti <= t);
        let (t0, t1) = (self.times[i - 1], self.times[i]);
        let s = (t - t0) / (t1 - t0);
        self.points[i - 1].lerp(self.points[i], s)
    }

    /// The last row's time, s.
    pub fn end_time(&self) -> f64 {
        self.times[self.times.len() - 1]
    }

    /// Number of rows.
    pub fn len(&self) -> usize {
        self.times.len()
    }

    /// Never true (a trajectory has at least one row); for clippy's `len` convention.
    pub fn is_empty(&self) -> bool {
        self.times.is_empty()
    }
}

/// A device that plays a [`Trajectory`]; its velocity is estimated from the positions it
/// played ([`VelocityEstimator`]), as for a real device that reports positions only.
#[derive(Clone, Debug)]
pub struct ScriptedDevice {
    spec: DeviceSpec,
    trajectory: Trajectory,
    source: String,
    start: Option<f64>,
    velocity: VelocityEstimator,
    /// The last command sent (for tests and logging).
    pub last_command: ForceCommand,
}

impl ScriptedDevice {
    /// Play `trajectory`; `source` names it in [`HapticDevice::describe`].
    pub fn new(trajectory: Trajectory, spec: DeviceSpec, source: &str) -> Self {
        ScriptedDevice {
            spec,
            trajectory,
            source: source.to_string(),
            start: None,
            velocity: VelocityEstimator::new(VelocityEstimator::DEFAULT_WINDOW),
            last_command: ForceCommand::default(),
        }
    }

    /// Read the trajectory CSV at `path`. A row farther than [`DeviceSpec::REACH`] workspace radii
    /// from the device's origin is refused: no device moves there (within that, the physics
    /// clamps the tool to the workspace and counts it).
    pub fn from_file(path: &Path, spec: DeviceSpec) -> Result<Self> {
        let (trajectory, lines) = Trajectory::read_rows(path)?;
        let reach = DeviceSpec::REACH * spec.workspace_radius;
        // The largest coordinate first: |x| of a row of 1e300 overflows to inf.
        let beyond = |x: &DVec3| x.abs().max_element() > reach || x.length() > reach;
        if let Some(k) = trajectory.points.iter().position(beyond) {
            let (x, num) = (trajectory.points[k], crate::scene::Num);
            return Err(PalpateError::Usage(format!(
                "{}: line {} (t = {} s): ({}, {}, {}) m is beyond any reach of the device ({} m, {} workspace radii of {} m)",
                path.display(),
                lines[k],
                num(trajectory.times[k]),
                num(x.x),
                num(x.y),
                num(x.z),
                num(reach),
                DeviceSpec::REACH,
                num(spec.workspace_radius)
            )));
        }
        Ok(Self::new(
            trajectory,
            spec,
            &format!("scripted:{}", path.display()),
        ))
    }

    /// The trajectory played.
    pub fn trajectory(&self) -> &Trajectory {
        &self.trajectory
    }
}

impl HapticDevice for ScriptedDevice {
    fn spec(&self) -> DeviceSpec {
        self.spec
    }
    fn describe(&self) -> String {
        self.source.clone()
    }
    fn read(&mut self, now: f64) -> DeviceReading {
        let start = *self.start.get_or_insert(now);
        let position = self.trajectory.at(now - start);
        self.velocity.push(now, position);
        DeviceReading {
            position,
            velocity: self.velocity.velocity(),
            buttons: 0,
            fresh: true,
            sampled: None,
        }
    }
    fn send(&mut self, _now: f64, command: &ForceCommand) {
        self.last_command = *command;
    }
    fn duration(&self) -> Option<f64> {
        Some(self.trajectory.end_time().max(0.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_row_beyond_reach_is_named_by_its_line_and_its_coordinates() {
        let dir = std::env::temp_dir().join(format!("palpate-scripted-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let spec = DeviceSpec::TOUCH;
        let far = 2.0 * DeviceSpec::REACH * spec.workspace_radius;
        for (row, want) in [
            (format!("0.5,{far},0,0"), format!("({far}, 0, 0) m")),
            // |x| of this row overflows to inf; the coordinates are still printed.
            (
                "0.5,1e300,1e300,0".to_string(),
                "(1e300, 1e300, 0) m".to_string(),
            ),
        ] {
            let path = dir.join("far.csv");
            // Header, a comment and a blank line before the far row: it is line 5.
            std::fs::write(&path, format!("t,x,y,z\n# approach\n0,0,0,0\n\n{row}\n")).unwrap();
            let e = ScriptedDevice::from_file(&path, spec)
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("far.csv: line 5 (t = 0.5 s)")
                    && e.contains(&want)
                    && e.contains("beyond any reach")
                    && !e.contains("inf"),
                "{e}"
            );
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
