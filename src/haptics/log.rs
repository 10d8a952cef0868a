//! The per-tick log of the servo loop: preallocated (and touched) before the loop, so
//! logging a tick never allocates or page-faults; written as `haptic.csv`.

use super::model::flags;
use crate::error::Result;
use std::path::Path;

/// One servo tick (f32 where logging precision suffices, to keep a long run small).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TickRecord {
    /// s on the loop clock when the tick started.
    pub time: f64,
    /// µs the tick started after its deadline.
    pub lateness_us: f32,
    /// µs the tick's work took (read → send).
    pub work_us: f32,
    /// m, device position.
    pub device: [f32; 3],
    /// m, proxy (simulated tool) position.
    pub proxy: [f32; 3],
    /// N, force sent.
    pub force: [f32; 3],
    /// m, the model's penetration.
    pub penetration: f32,
    /// The model's active particles.
    pub active_particles: u32,
    /// ms, age of the model used (NaN before the first model).
    pub model_age_ms: f32,
    /// Shaping gain (ramp × fade).
    pub gain: f32,
    /// J, passivity observer energy E(n).
    pub energy: f32,
    /// [`flags`] bits.
    pub flags: u32,
}

/// The CSV header of `haptic.csv`.
pub const CSV_HEADER: &str = "time_s,device_x,device_y,device_z,proxy_x,proxy_y,proxy_z,force_x,force_y,force_z,penetration_m,active_particles,model_age_ms,lateness_us,work_us,gain,energy_j,flags,in_contact,clamped,fading,device_fresh";

/// A preallocated tick log.
#[derive(Clone, Debug, Default)]
pub struct TickLog {
    records: Vec<TickRecord>,
    len: usize,
    overflow: u64,
}

impl TickLog {
    /// A log for `capacity` ticks; the memory is allocated and written now.
    pub fn with_capacity(capacity: usize) -> Self {
        TickLog {
            records: vec![TickRecord::default(); capacity],
            len: 0,
            overflow: 0,
        }
    }

    /// Append a record (allocation-free); once full, further ticks are only counted.
    pub fn push(&mut self, record: TickRecord) {
        if let Some(slot) = self.records.get_mut(self.len) {
            *slot = record;
            self.len += 1;
        } else {
            self.overflow += 1;
        }
    }

    /// The ticks logged.
    pub fn records(&self) -> &[TickRecord] {
        &self.records[..self.len]
    }

    /// Ticks not logged because the log was full.
    pub fn overflow(&self) -> u64 {
        self.overflow
    }

    /// Write the CSV (header and one row per tick) to `out`.
    fn write_rows(&self, out: &mut impl std::io::Write) -> std::io::Result<()> {
        writeln!(out, "{CSV_HEADER}")?;
        for r in self.records() {
            let bit = |b: u32| u8::from(r.flags & b != 0);
            writeln!(
                out,
                "{:.6},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
                r.time,
                r.device[0],
                r.device[1],
                r.device[2],
                r.proxy[0],
                r.proxy[1],
                r.proxy[2],
                r.force[0],
                r.force[1],
                r.force[2],
                r.penetration,
                r.active_particles,
                r.model_age_ms,
                r.lateness_us,
                r.work_us,
                r.gain,
                r.energy,
                r.flags,
                bit(flags::IN_CONTACT),
                bit(flags::CLAMPED),
                bit(flags::FADING),
                1 - bit(flags::DEVICE_STALE),
            )?;
        }
        Ok(())
    }

    /// Write the CSV to `path` atomically (`*.partial`, then rename), streamed: an hour of
    /// ticks is about 0.6 GB of text, which is not built in memory.
    pub fn write_csv(&self, path: &Path) -> Result<()> {
        crate::output::write_atomic_with(path, |w| self.write_rows(w))
    }
}
