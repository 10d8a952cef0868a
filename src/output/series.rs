//! A time series of states: numbered `frame_NNNN.vtu` files and the `series.pvd` collection
//! that lists them with their times (ParaView opens the `.pvd` and plays it); in a scene with
//! particles, `particles_frame_NNNN.vtu` and `particles_series.pvd` beside them.

use super::state::state_vtu;
use super::{pvd, write_atomic};
use crate::error::Result;
use crate::model::Model;
use crate::stepper::{ParticleSnapshot, State};
use std::path::{Path, PathBuf};

/// Frames written so far into one directory.
pub struct FrameSeries {
    dir: PathBuf,
    frames: Vec<(f64, String)>,
    particle_frames: Vec<(f64, String)>,
}

impl FrameSeries {
    /// An empty series in `dir`.
    pub fn new(dir: &Path) -> FrameSeries {
        FrameSeries {
            dir: dir.to_path_buf(),
            frames: Vec::new(),
            particle_frames: Vec::new(),
        }
    }

    /// Write the next frame (`frame_NNNN.vtu`, N = frames written so far) at `time` s, and
    /// the particles' (`particles_frame_NNNN.vtu`) when given.
    pub fn write(
        &mut self,
        model: &Model,
        state: &State,
        particles: Option<&ParticleSnapshot>,
        time: f64,
    ) -> Result<()> {
        let name = format!("frame_{:04}.vtu", self.frames.len());
        write_atomic(&self.dir.join(&name), state_vtu(model, state).as_bytes())?;
        if let Some(snap) = particles {
            let name = format!("particles_frame_{:04}.vtu", self.frames.len());
            let text = super::particles::particles_vtu(model, state, snap);
            write_atomic(&self.dir.join(&name), text.as_bytes())?;
            self.particle_frames.push((time, name));
        }
        self.frames.push((time, name));
        // The index after every frame: a run killed half-way (SIGKILL, out of memory) leaves
        // a series ParaView opens, and the next run into the folder knows it for palpate's.
        self.finish()
    }

    /// Time of the last frame written, if any.
    pub fn last_time(&self) -> Option<f64> {
        self.frames.last().map(|(t, _)| *t)
    }

    /// Write `series.pvd` listing the frames, and `particles_series.pvd` listing the
    /// particles' (nothing when there are none). [`FrameSeries::write`] does it after each
    /// frame too.
    pub fn finish(&self) -> Result<()> {
        if !self.particle_frames.is_empty() {
            write_atomic(
                &self.dir.join("particles_series.pvd"),
                pvd(&self.particle_frames).as_bytes(),
            )?;
        }
        if self.frames.is_empty() {
            return Ok(());
        }
        write_atomic(&self.dir.join("series.pvd"), pvd(&self.frames).as_bytes())
    }
}
