//! The errors of the solve stage.

use std::path::PathBuf;

/// Errors of the solve stage.
#[derive(Debug, thiserror::Error)]
pub enum SolveError {
    /// Options that cannot work.
    #[error("{0}")]
    Options(String),
    /// `--resume` with no usable checkpoint, or one made for other inputs or options.
    #[error("{}: {reason}", path.display())]
    Checkpoint {
        /// The checkpoint directory.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// Stopped by a signal while polishing the tiny values, after the iterations; the
    /// state checkpointed last (if any) is kept.
    #[error("interrupted while polishing the tiny values after {iterations} iterations; {then}")]
    InterruptedPolish {
        /// Iterations done.
        iterations: u64,
        /// What to do now.
        then: String,
    },
    /// Stopped by a signal after writing a checkpoint.
    #[error("interrupted after {iterations} iterations; the state is checkpointed in {}; continue with `harmap solve {} --resume`", path.display(), run.display())]
    Interrupted {
        /// Iterations done.
        iterations: u64,
        /// The checkpoint directory.
        path: PathBuf,
        /// The run.
        run: PathBuf,
    },
}

impl SolveError {
    /// Whether the user's options or files are at fault (exit code 2).
    #[must_use]
    pub fn is_bad_input(&self) -> bool {
        matches!(self, SolveError::Options(_) | SolveError::Checkpoint { .. })
    }
}
