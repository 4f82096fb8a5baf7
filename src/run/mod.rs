//! The run directory: a Zarr v3 group holding every array of a run and its metadata.
//!
//! Layout (format version [`FORMAT_VERSION`], documented in `docs/format.md`):
//! ```text
//! RUN/zarr.json        group; attributes {"harmap": {format_version, grid, center,
//!                      input, stages}}
//! RUN/labels/zarr.json OME-Zarr 0.5 image group ("ome" multiscales, one level)
//! RUN/labels/0/        u8 labels [z, y, x]
//! ```
//! A new run is built under a staging name next to its destination and renamed into
//! place when whole, so an interrupted run never leaves a directory that looks complete.
//! Metadata updates go through a temporary file, fsync and rename.

pub(crate) mod atomic;
mod checkpoint;
mod dir;
mod ome;
pub mod stages;
mod staging;

use std::path::{Path, PathBuf};

pub use atomic::write_atomic;
pub use checkpoint::{CheckpointFiles, GenerationWriter};
pub use dir::{RunDir, StagedImages};
pub use ome::ome_multiscales;
pub use stages::{
    options_in, peak_rss, report_in, stage_done, stage_record, Freshness, StageRecord, STAGES,
};
pub use staging::{staging_path, RunLock, Staging};

/// Version of the on-disk layout this build writes and reads.
pub const FORMAT_VERSION: u64 = 1;

/// Errors of the run directory.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// A filesystem operation failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The path.
        path: PathBuf,
        /// What the OS said.
        source: std::io::Error,
    },
    /// The path is not a harmap run directory.
    ///
    /// Fix: give the directory written by `harmap voxelize -o RUN`.
    #[error("{}: not a harmap run directory ({reason})", path.display())]
    NotARun {
        /// The path.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// The destination exists.
    ///
    /// Fix: choose another `-o`, or pass `--force` to replace it.
    #[error("{}: already exists; choose another -o or pass --force to replace it", path.display())]
    Exists {
        /// The path.
        path: PathBuf,
    },
    /// Another harmap process is building the same run.
    ///
    /// Fix: wait for it, or choose another `-o`.
    #[error("{}: another harmap process is writing this run (its lock file is held); wait for it or choose another -o", path.display())]
    Busy {
        /// The run.
        path: PathBuf,
    },
    /// The directory that should hold the run does not exist.
    ///
    /// Fix: create it, or give another `-o`.
    #[error("{}: the directory for the run does not exist; create it or give another -o", path.display())]
    NoParent {
        /// The missing directory.
        path: PathBuf,
    },
    /// The run was written by an incompatible version of harmap.
    #[error("{}: format version {found}, this harmap reads version {FORMAT_VERSION}; redo the run with this version", path.display())]
    Version {
        /// The path.
        path: PathBuf,
        /// Version found.
        found: u64,
    },
    /// A stage this command needs has not been run.
    #[error("{}: stage '{stage}' has not completed; run `harmap {stage}` first", path.display())]
    StageMissing {
        /// The run.
        path: PathBuf,
        /// The stage.
        stage: String,
    },
    /// A stage this command needs is done, but one of its inputs changed since.
    ///
    /// Fix: run that stage again (`harmap info RUN` lists the stale stages).
    #[error("{}: stage '{stage}' is out of date: {why}; run `harmap {stage} {}` again, or `harmap run` with the options you want", path.display(), path.display())]
    StageStale {
        /// The run.
        path: PathBuf,
        /// The stage.
        stage: String,
        /// What changed.
        why: String,
    },
}

impl RunError {
    /// Whether this is the user's mistake (exit code 2).
    #[must_use]
    pub fn is_bad_input(&self) -> bool {
        !matches!(self, RunError::Io { .. })
    }
}

pub(crate) fn io(path: &Path) -> impl FnOnce(std::io::Error) -> RunError + '_ {
    move |source| RunError::Io {
        path: path.to_owned(),
        source,
    }
}
