//! A time series of states: numbered `frame_NNNN.vtu` files and the `series.pvd` collection
//! that lists them with their times (ParaView opens the `.pvd` and plays it); in a scene with
//! particles, `particles_frame_NNNN.vtu` and `particles_series.pvd` beside them.

use super::state::state_vtu;
use super::{pvd, pvd_line, write_atomic, PVD_TAIL};
use crate::error::{PalpateError, Result};
use crate::model::Model;
use crate::stepper::{ParticleSnapshot, State};
use std::io::{Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

/// A `.pvd` kept up to date frame by frame: written whole for the first frame, then each
/// frame's line written over the closing tags, followed by them again (constant work a
/// frame, where rewriting the whole index grew with the square of the frames).
struct LiveIndex {
    file: std::fs::File,
    /// Bytes before the closing tags ([`PVD_TAIL`]).
    body: u64,
}

impl LiveIndex {
    /// Bring `path` up to `entries` (the last one new, or all when `index` is None).
    fn update(index: &mut Option<LiveIndex>, path: &Path, entries: &[(f64, String)]) -> Result<()> {
        let io = |source| PalpateError::OutputIo {
            path: path.to_path_buf(),
            source,
        };
        match index {
            Some(live) => {
                let Some((t, name)) = entries.last() else {
                    return Ok(());
                };
                let line = pvd_line(*t, name);
                live.file.seek(SeekFrom::Start(live.body)).map_err(io)?;
                live.file
                    .write_all(format!("{line}{PVD_TAIL}").as_bytes())
                    .map_err(io)?;
                live.body += line.len() as u64;
            }
            None => {
                let text = pvd(entries);
                write_atomic(path, text.as_bytes())?;
                let file = std::fs::OpenOptions::new()
                    .write(true)
                    .open(path)
                    .map_err(io)?;
                *index = Some(LiveIndex {
                    file,
                    body: (text.len() - PVD_TAIL.len()) as u64,
                });
            }
        }
        Ok(())
    }
}

/// Frames written so far into one directory.
pub struct FrameSeries {
    dir: PathBuf,
    frames: Vec<(f64, String)>,
    particle_frames: Vec<(f64, String)>,
    index: Option<LiveIndex>,
    particle_index: Option<LiveIndex>,
}

impl FrameSeries {
    /// An empty series in `dir`.
    pub fn new(dir: &Path) -> FrameSeries {
        FrameSeries {
            dir: dir.to_path_buf(),
            frames: Vec::new(),
            particle_frames: Vec::new(),
            index: None,
            particle_index: None,
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
        if particles.is_some() {
            LiveIndex::update(
                &mut self.particle_index,
                &self.dir.join("particles_series.pvd"),
                &self.particle_frames,
            )?;
        }
        LiveIndex::update(&mut self.index, &self.dir.join("series.pvd"), &self.frames)
    }

    /// Frames written.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Whether no frame was written.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Time of the last frame written, if any.
    pub fn last_time(&self) -> Option<f64> {
        self.frames.last().map(|(t, _)| *t)
    }

    /// Write `series.pvd` listing the frames, and `particles_series.pvd` listing the
    /// particles' (nothing when there are none), whole and atomically ([`FrameSeries::write`]
    /// keeps them up to date frame by frame).
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_live_index_equals_the_whole_one_after_every_frame() {
        let dir = std::env::temp_dir().join(format!("palpate-live-pvd-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("series.pvd");
        let mut index = None;
        let mut entries = Vec::new();
        for k in 0..12 {
            entries.push((0.25 * k as f64, format!("frame_{k:04}.vtu")));
            LiveIndex::update(&mut index, &path, &entries).unwrap();
            assert_eq!(
                std::fs::read_to_string(&path).unwrap(),
                pvd(&entries),
                "frame {k}"
            );
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
