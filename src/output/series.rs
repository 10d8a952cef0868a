//! A time series of states: numbered `frame_NNNN.vtu` files and the `series.pvd` collection
//! that lists them with their times (ParaView opens the `.pvd` and plays it).

use super::state::state_vtu;
use super::{pvd, write_atomic};
use crate::error::Result;
use crate::model::Model;
use crate::stepper::State;
use std::path::{Path, PathBuf};

/// Frames written so far into one directory.
pub struct FrameSeries {
    dir: PathBuf,
    frames: Vec<(f64, String)>,
}

impl FrameSeries {
    /// An empty series in `dir`.
    pub fn new(dir: &Path) -> FrameSeries {
        FrameSeries {
            dir: dir.to_path_buf(),
            frames: Vec::new(),
        }
    }

    /// Write the next frame (`frame_NNNN.vtu`, N = frames written so far) at `time` s.
    pub fn write(&mut self, model: &Model, state: &State, time: f64) -> Result<()> {
        let name = format!("frame_{:04}.vtu", self.frames.len());
        write_atomic(&self.dir.join(&name), state_vtu(model, state).as_bytes())?;
        self.frames.push((time, name));
        Ok(())
    }

    /// Time of the last frame written, if any.
    pub fn last_time(&self) -> Option<f64> {
        self.frames.last().map(|(t, _)| *t)
    }

    /// Write `series.pvd` listing the frames (nothing when there are none).
    pub fn finish(&self) -> Result<()> {
        if self.frames.is_empty() {
            return Ok(());
        }
        write_atomic(&self.dir.join("series.pvd"), pvd(&self.frames).as_bytes())
    }
}
