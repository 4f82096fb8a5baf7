//! Errors of the map stage and of the inverse map.

use std::path::PathBuf;

/// Errors of `harmap map` and `harmap inverse`. Every one is the user's input or
/// options (exit code 2); failures of storage come as [`crate::grid::GridError`].
#[derive(Debug, thiserror::Error)]
pub enum MapError {
    /// The run was solved by a harmap that did not store u = 1 - phi.
    #[error(
        "{}: solved by an older harmap that did not store u = 1 - phi; run `harmap solve` again",
        run.display()
    )]
    NoU {
        /// The run directory.
        run: PathBuf,
    },
    /// Options that cannot work (the stop ball's radius, ...).
    #[error("{0}")]
    Options(String),
    /// The points file of the inverse map does not exist.
    #[error(
        "{}: no such file; --points takes a CSV file with a header naming phi (or u), theta and psi",
        path.display()
    )]
    PointsMissing {
        /// The file.
        path: PathBuf,
    },
    /// The points file exists but cannot be read.
    #[error("{}: cannot read: {source}", path.display())]
    PointsUnreadable {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// A line of the points file is wrong.
    #[error("{}:{line}: {what}", path.display())]
    Points {
        /// The file.
        path: PathBuf,
        /// Its line, from 1.
        line: u64,
        /// What is wrong and what to do.
        what: String,
    },
}

impl MapError {
    /// Whether the error is the user's input or options (exit code 2): all are.
    #[must_use]
    pub fn is_bad_input(&self) -> bool {
        true
    }
}
