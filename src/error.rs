//! One error type for everything a user can get wrong or an adapter can refuse.
//!
//! Every variant renders as a single line that names the file or item at fault, so the
//! command line can print `error: {err}` and exit non-zero without a backtrace.

use std::path::PathBuf;

/// Errors raised by palpate. Each message is one line and names what is wrong and where.
#[derive(Debug, thiserror::Error)]
pub enum PalpateError {
    /// A scene file could not be read from disk.
    #[error("{path}: cannot read scene file: {source}")]
    SceneIo {
        /// The scene file.
        path: PathBuf,
        /// The underlying I/O error.
        source: std::io::Error,
    },
    /// A scene file is not valid TOML or does not match the scene schema.
    #[error("{origin}: {message}")]
    SceneParse {
        /// The file path or built-in scene name.
        origin: String,
        /// What the parser said, including line and key.
        message: String,
    },
    /// A scene value is out of its valid range.
    #[error("{origin}: {item}: {message}")]
    SceneValue {
        /// The file path or built-in scene name.
        origin: String,
        /// The offending key, e.g. `material.poisson_ratio`.
        item: String,
        /// Why it is invalid.
        message: String,
    },
    /// A mesh is malformed (bad index, degenerate tet, …).
    #[error("{origin}: {message}")]
    Mesh {
        /// Where the mesh came from (file or generator).
        origin: String,
        /// What is wrong, naming the element or node.
        message: String,
    },
    /// A mesh file could not be read or parsed.
    #[error("{path}: {message}")]
    MeshFile {
        /// The mesh file.
        path: PathBuf,
        /// What is wrong and where in the file.
        message: String,
    },
    /// A requested time step exceeds the stability bound.
    #[error("{given} = {} ({detail}); {advice}", above_bound(*.dt, *.bound))]
    UnstableTimeStep {
        /// Where the step was given: `--dt`, or the scene file and `solver.dt`.
        given: String,
        /// The requested step.
        dt: f64,
        /// The bound it exceeds.
        bound: f64,
        /// How the bound was computed.
        detail: String,
        /// What to do, in the terms of the command that refused it (`run` has `--dt` and
        /// `--allow-unstable`, `haptic` only the scene's `solver.dt`).
        advice: &'static str,
    },
    /// No GPU adapter (hardware or software) could be found.
    #[error("no GPU adapter found ({detail}); install a software Vulkan adapter with `apt-get install -y mesa-vulkan-drivers`, or run with --backend cpu")]
    NoAdapter {
        /// What was tried.
        detail: String,
    },
    /// The mesh or its particle layer does not fit in the adapter's buffer limits.
    #[error("{subject} too big for the GPU adapter '{adapter}': buffer '{buffer}' needs {bytes} bytes but the adapter allows {limit} bytes per {what}{advice}")]
    TooBigForAdapter {
        /// What is too big: `mesh` or `particle layer`.
        subject: &'static str,
        /// What to change, with a leading separator ("" when there is nothing to add).
        advice: &'static str,
        /// Adapter name.
        adapter: String,
        /// Which buffer.
        buffer: String,
        /// Its size in bytes.
        bytes: u64,
        /// The adapter's limit.
        limit: u64,
        /// Which limit (binding or buffer).
        what: &'static str,
    },
    /// A wgpu call failed (device lost, validation error, out of memory).
    #[error("GPU error: {0}")]
    Gpu(String),
    /// A command-line argument is invalid.
    #[error("{0}")]
    Usage(String),
    /// Something the engine relies on did not hold (a bug; the message says what).
    #[error("internal error: {0}")]
    Internal(String),
    /// A stop (Ctrl-C or SIGTERM) came before the job wrote or removed anything: it ends
    /// with exit status 130 and the output folder as it was.
    #[error("stopped (Ctrl-C or SIGTERM) before {0}: nothing was written, earlier outputs kept")]
    StoppedBeforeStart(String),
    /// Writing an output file failed.
    #[error("{path}: cannot write: {source}")]
    OutputIo {
        /// The output file.
        path: PathBuf,
        /// The underlying I/O error.
        source: std::io::Error,
    },
}

/// Result alias used across the crate.
pub type Result<T, E = PalpateError> = std::result::Result<T, E>;

/// "`dt` s is above the stability bound `bound` s", each with as many digits as
/// [`distinct_pair`] needs.
fn above_bound(dt: f64, bound: f64) -> String {
    let (dt, bound) = distinct_pair(dt, bound);
    format!("{dt} s is above the stability bound {bound} s")
}

/// `a` and `b` in scientific notation with 4 significant digits, or as many more as it takes
/// for the two to read differently where they differ (a step a hair above its bound).
pub fn distinct_pair(a: f64, b: f64) -> (String, String) {
    (3..17)
        .map(|p| (format!("{a:.p$e}"), format!("{b:.p$e}")))
        .find(|(x, y)| x != y || a == b)
        .unwrap_or_else(|| (format!("{a:e}"), format!("{b:e}")))
}

#[cfg(test)]
mod tests {
    use super::{distinct_pair, PalpateError};

    /// A step a hair above its bound reads differently from it; one well above keeps 4 digits.
    #[test]
    fn a_step_above_its_bound_reads_differently_from_it() {
        let bound = 1.3944333775567906e-4;
        let e = PalpateError::UnstableTimeStep {
            given: "--dt".into(),
            dt: bound * (1.0 + 1e-9),
            bound,
            detail: "Courant".into(),
            advice: "lower it",
        }
        .to_string();
        assert!(
            e.starts_with("--dt = 1.394433379e-4 s is above the stability bound 1.394433378e-4 s"),
            "{e}"
        );
        assert_eq!(
            distinct_pair(2e-4, bound),
            ("2.000e-4".to_string(), "1.394e-4".to_string())
        );
        assert_eq!(
            distinct_pair(1.0, 1.0),
            ("1.000e0".to_string(), "1.000e0".to_string())
        );
    }
}
