//! Output files: VTU meshes with point and cell data (`state`), the particles as a VTU point
//! cloud (`particles`), PVD series (`series`), the summary JSON (`summary`) and the
//! studies' PNG plots (`png`); one job at a time in an output folder (`lock`).
//! Every file is written to a temporary name and renamed into place, so a failed run never
//! leaves a half-written file under the final name.

pub mod lock;
pub mod particles;
pub mod png;
pub mod series;
pub mod state;
pub mod summary;
pub mod vtu;

use crate::error::{PalpateError, Result};
use std::path::Path;

/// Create the output directory `dir` if needed and check that files can be written in it
/// (a probe file, created and removed), so that a run finds out before it starts, not after.
pub fn prepare_out_dir(dir: &Path) -> Result<()> {
    let err = |source| PalpateError::OutputIo {
        path: dir.to_path_buf(),
        source,
    };
    if dir.exists() && !dir.is_dir() {
        return Err(PalpateError::Usage(format!(
            "{}: --out is not a directory (it names an existing file); give a directory for the outputs",
            dir.display()
        )));
    }
    if !dir.exists() && dir.symlink_metadata().is_ok() {
        let target = std::fs::read_link(dir).unwrap_or_default();
        return Err(PalpateError::Usage(format!(
            "{}: --out is a symbolic link to {}, which does not exist; create that folder or give another",
            dir.display(),
            target.display()
        )));
    }
    std::fs::create_dir_all(dir).map_err(err)?;
    // A folder under the name of an output the job writes would fail that write at the end.
    for name in FIXED_OUTPUTS {
        let path = dir.join(name);
        if std::fs::symlink_metadata(&path).is_ok_and(|m| m.is_dir()) {
            return Err(PalpateError::Usage(format!(
                "{}: {name} is a folder, where the job writes its {name}; move it or give another --out",
                dir.display()
            )));
        }
    }
    // As long as the longest name a run writes (`particles_frame_NNNN.vtu.partial`, and
    // more), so that a folder path near the system's length limit fails here.
    let probe = dir.join(format!(
        "{:_<40}",
        format!(".palpate-write-probe-{}", std::process::id())
    ));
    std::fs::write(&probe, b"").map_err(err)?;
    std::fs::remove_file(&probe).map_err(err)
}

/// Refuse an output folder `dir` (which exists) holding one of the job's `inputs` (what it
/// is, its path) under a name the job writes or removes ([`is_run_output`]): a mesh read from
/// `out/final.vtu`, or a trajectory `haptic.csv`, would be replaced.
pub fn check_inputs_are_not_outputs(dir: &Path, inputs: &[(&str, &Path)]) -> Result<()> {
    let Ok(out) = dir.canonicalize() else {
        return Ok(());
    };
    for (what, path) in inputs {
        // The file itself, through any symbolic link to it (a mesh.vtu linking to
        // out/final.vtu is replaced as that is).
        let Ok(real) = path.canonicalize() else {
            continue;
        };
        let name = real.file_name().and_then(|n| n.to_str()).unwrap_or("");
        let here = real.parent().is_some_and(|parent| parent == out);
        if here && is_run_output(name) {
            return Err(PalpateError::Usage(format!(
                "{}: the {what} is in --out {} under the name of an output the job writes there ({name}), which would replace it; copy it elsewhere or give another --out",
                path.display(),
                dir.display()
            )));
        }
    }
    Ok(())
}

/// The outputs a job writes under fixed names (frames are numbered).
const FIXED_OUTPUTS: [&str; 6] = [
    "final.vtu",
    "summary.json",
    "series.pvd",
    "particles_final.vtu",
    "particles_series.pvd",
    "haptic.csv",
];

/// Whether `name` is a file `palpate run` or `palpate haptic` writes: `final.vtu`,
/// `summary.json`, `haptic.csv`, `series.pvd`, `frame_NNNN.vtu` (four digits or more), and
/// the particles' `particles_final.vtu`, `particles_series.pvd`, `particles_frame_NNNN.vtu`,
/// or one of their temporary `.partial` files.
pub fn is_run_output(name: &str) -> bool {
    // A write that a kill cut short leaves its temporary file.
    let name = name.strip_suffix(".partial").unwrap_or(name);
    let frame = |rest: &str| {
        rest.strip_prefix("frame_")
            .and_then(|r| r.strip_suffix(".vtu"))
            .is_some_and(|n| n.len() >= 4 && n.bytes().all(|b| b.is_ascii_digit()))
    };
    let own = |n: &str| matches!(n, "final.vtu" | "series.pvd") || frame(n);
    matches!(name, "summary.json" | "haptic.csv")
        || own(name)
        || name.strip_prefix("particles_").is_some_and(own)
}

/// The first `max` bytes of `path` when it is a regular file (not a FIFO, a device or a
/// folder, which a read could block on or not end), else None.
fn head(path: &Path, max: u64) -> Option<Vec<u8>> {
    use std::io::Read;
    if !std::fs::metadata(path).ok()?.is_file() {
        return None;
    }
    let mut bytes = Vec::new();
    std::fs::File::open(path)
        .ok()?
        .take(max)
        .read_to_end(&mut bytes)
        .ok()?;
    Some(bytes)
}

/// How `haptic.csv` begins: its header's first four columns (time and the device's pose,
/// which earlier versions of the header shared).
fn haptic_csv_prologue() -> &'static str {
    let header = crate::haptics::log::CSV_HEADER;
    let end = header
        .match_indices(',')
        .nth(3)
        .map_or(header.len(), |(i, _)| i + 1);
    &header[..end]
}

/// Whether the file at `path` carries [`PVD_MARK`] in its first 4 kB (palpate's `.pvd` and,
/// since 2026-11-29, its `.vtu` files do; another tool's do not).
fn marked_by_palpate(path: &Path) -> bool {
    head(path, 4096).is_some_and(|h| String::from_utf8_lossy(&h).contains(PVD_MARK))
}

/// Whether the file `name` at `path`, named as a run output, is one palpate wrote: a `.vtu`
/// that begins as palpate's do ([`vtu::PROLOGUE`]), a `.pvd` marked [`PVD_MARK`], a `haptic.csv` with its
/// header, or a `.partial` (a write a kill cut short). (`summary.json` is proved by its keys.)
fn written_by_palpate(name: &str, path: &Path) -> bool {
    if name.ends_with(".partial") {
        return true;
    }
    let starts = |prologue: &str| {
        head(path, prologue.len() as u64).is_some_and(|h| h == prologue.as_bytes())
    };
    if name.ends_with(".vtu") {
        starts(vtu::PROLOGUE)
    } else if name.ends_with(".pvd") {
        marked_by_palpate(path)
    } else if name == "haptic.csv" {
        starts(haptic_csv_prologue())
    } else {
        false
    }
}

/// Remove what an earlier run left in `dir`, so that its frames or particle files are not
/// mixed with the new run's in ParaView: only when `dir` holds an earlier run's
/// `summary.json` (a JSON object with `scene`, `backend` and `status`), or a `series.pvd`,
/// `particles_series.pvd`, `final.vtu` or `particles_final.vtu` marked [`PVD_MARK`] (a run
/// killed before its summary), and only
/// regular files [`is_run_output`] names whose contents are palpate's (a user's
/// `haptic.csv` trajectory or a `frame_0007.vtu` of another tool stays), nothing else: its
/// `final.vtu` and `summary.json` too, so that a run that fails half-way leaves none of the
/// earlier run's results beside its own. A FIFO or device under an output's name is not
/// read (it could block). Returns how many files were removed.
pub fn remove_earlier_outputs(dir: &Path) -> Result<usize> {
    let err = |source| PalpateError::OutputIo {
        path: dir.to_path_buf(),
        source,
    };
    let earlier_run = head(&dir.join("summary.json"), 64 << 20)
        .and_then(|t| serde_json::from_slice::<serde_json::Value>(&t).ok())
        .is_some_and(|v| {
            ["scene", "backend", "status"]
                .iter()
                .all(|k| v.get(k).is_some())
        });
    // A run killed before its summary (a second signal while the outputs were written)
    // leaves its final.vtu, and maybe particles_final.vtu, which a run without particles
    // would leave beside its own: those count when marked as palpate's (an uncompressed VTK
    // 9 file of another tool begins as palpate's do).
    let killed_run = [
        "series.pvd",
        "particles_series.pvd",
        "final.vtu",
        "particles_final.vtu",
    ]
    .iter()
    .any(|name| marked_by_palpate(&dir.join(name)));
    if !(earlier_run || killed_run) {
        return Ok(0);
    }
    let mut removed = 0;
    for entry in std::fs::read_dir(dir).map_err(err)? {
        let entry = entry.map_err(err)?;
        let name = entry.file_name();
        let is_file = entry.file_type().map_err(err)?.is_file();
        let Some(name) = name.to_str().filter(|n| is_file && is_run_output(n)) else {
            continue;
        };
        let path = entry.path();
        // summary.json only when it is the earlier run's, proved above.
        let stale = match name {
            "summary.json" => earlier_run,
            _ => written_by_palpate(name, &path),
        };
        if stale {
            std::fs::remove_file(&path)
                .map_err(|source| PalpateError::OutputIo { path, source })?;
            removed += 1;
        }
    }
    Ok(removed)
}

/// A CSV field (RFC 4180): as it is, or in double quotes (inner quotes doubled) when it holds
/// a comma, a quote or a line break — labels such as `cells [10, 1, 1]` or an adapter name.
pub fn csv_field(text: &str) -> std::borrow::Cow<'_, str> {
    if text.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", text.replace('"', "\"\"")).into()
    } else {
        text.into()
    }
}

/// Write `bytes` to `path` atomically (temporary file + rename).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic_with(path, |w| std::io::Write::write_all(w, bytes))
}

/// Write `path` atomically (temporary file + rename) through a buffered writer that `fill`
/// writes to, so that large outputs are streamed rather than built in memory.
pub fn write_atomic_with(
    path: &Path,
    fill: impl FnOnce(&mut std::io::BufWriter<std::fs::File>) -> std::io::Result<()>,
) -> Result<()> {
    use std::io::Write;
    let err = |source| PalpateError::OutputIo {
        path: path.to_path_buf(),
        source,
    };
    let tmp = path.with_extension(format!(
        "{}.partial",
        path.extension()
            .map(|e| e.to_string_lossy().into_owned())
            .unwrap_or_default()
    ));
    let mut w = std::io::BufWriter::new(std::fs::File::create(&tmp).map_err(err)?);
    let written = fill(&mut w).and_then(|()| w.flush());
    drop(w);
    // A failed write leaves no temporary file behind.
    match written.and_then(|()| std::fs::rename(&tmp, path)) {
        Ok(()) => Ok(()),
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            Err(err(e))
        }
    }
}

/// The failures of a set of outputs that are all tried even after one fails (a full disk may
/// still take the small summary.json, which lists them as `output_errors`).
#[derive(Debug, Default)]
pub struct OutputErrors(Vec<PalpateError>);

impl OutputErrors {
    /// Keep `r`'s error, if any, unless the same one is kept already (the series index a
    /// frame could not update fails again when the run closes the series).
    pub fn keep(&mut self, r: Result<()>) {
        if let Err(e) = r {
            let text = e.to_string();
            if !self.0.iter().any(|k| k.to_string() == text) {
                self.0.push(e);
            }
        }
    }

    /// None failed so far.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// Each failure as its one-line message.
    pub fn messages(&self) -> Vec<String> {
        self.0.iter().map(|e| e.to_string()).collect()
    }

    /// Ok when none failed; the one failure; or one error naming them all.
    pub fn into_result(mut self) -> Result<()> {
        match self.0.len() {
            0 => Ok(()),
            1 => Err(self.0.remove(0)),
            n => Err(PalpateError::Usage(format!(
                "{n} outputs could not be written: {}",
                self.messages().join("; ")
            ))),
        }
    }
}

/// The comment that marks a `.pvd` or `.vtu` as written by palpate (see
/// [`remove_earlier_outputs`]).
pub const PVD_MARK: &str = "<!-- written by palpate -->";

/// The end of a `.pvd` after its last `DataSet` line (see [`pvd`]).
pub const PVD_TAIL: &str = "  </Collection>\n</VTKFile>\n";

/// One `DataSet` line of a `.pvd`: the file `file` at time `t` s.
pub fn pvd_line(t: f64, file: &str) -> String {
    format!("    <DataSet timestep=\"{t:e}\" group=\"\" part=\"0\" file=\"{file}\"/>\n")
}

/// A ParaView collection (`.pvd`) listing `(time, file name)` pairs, marked [`PVD_MARK`].
pub fn pvd(frames: &[(f64, String)]) -> String {
    let mut s = format!(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n  {PVD_MARK}\n  <Collection>\n",
    );
    for (t, file) in frames {
        s.push_str(&pvd_line(*t, file));
    }
    s.push_str(PVD_TAIL);
    s
}

#[cfg(test)]
mod write_tests {
    use super::*;

    #[test]
    fn a_failed_atomic_write_leaves_no_temporary_file() {
        let dir = std::env::temp_dir().join(format!("palpate-atomic-{}", std::process::id()));
        // A folder where the file should go: the rename onto it fails.
        std::fs::create_dir_all(dir.join("final.vtu")).unwrap();
        let path = dir.join("final.vtu");
        let e = write_atomic(&path, b"data").unwrap_err().to_string();
        assert!(e.contains("final.vtu"), "{e}");
        assert!(!dir.join("final.vtu.partial").exists());
        // And a writer that fails half-way.
        let other = dir.join("summary.json");
        let failed = write_atomic_with(&other, |w| {
            std::io::Write::write_all(w, b"{")?;
            Err(std::io::Error::other("disk full"))
        });
        assert!(failed.is_err() && !dir.join("summary.json.partial").exists() && !other.exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn run_outputs_and_their_temporary_files_are_named_and_nothing_else() {
        for name in [
            "final.vtu",
            "summary.json",
            "haptic.csv",
            "series.pvd",
            "frame_0012.vtu",
            "particles_frame_0002.vtu",
            "particles_frame_0002.vtu.partial",
            "final.vtu.partial",
        ] {
            assert!(is_run_output(name), "{name}");
        }
        for name in [
            "frame_1.vtu",
            "notes.txt",
            "frame_0001.vtu.bak",
            "x.partial",
            ".partial",
        ] {
            assert!(!is_run_output(name), "{name}");
        }
    }
}
