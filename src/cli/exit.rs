//! How a command's failure becomes the process's exit code: 2 for bad usage or bad
//! input, 130 or 143 for an interrupted run, 1 for a run that failed; a broken pipe
//! (output piped into `head`) is not a failure.

use super::UsageError;

/// Whether the failure is a closed output pipe.
pub(super) fn is_broken_pipe(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
    })
}

/// The exit code of a failed command.
pub(super) fn exit_code(e: &anyhow::Error) -> u8 {
    for c in e.chain() {
        if c.downcast_ref::<UsageError>().is_some() {
            return 2;
        }
        if let Some(s) = c.downcast_ref::<Stopped>() {
            return s.code;
        }
        if let Some(h) = c.downcast_ref::<harmap::Error>() {
            if let harmap::Error::Solve(
                harmap::solve::SolveError::Interrupted { .. }
                | harmap::solve::SolveError::InterruptedPolish { .. },
            ) = h
            {
                return 130;
            }
            return if h.is_bad_input() { 2 } else { 1 };
        }
    }
    1
}

/// A stage stopped by a signal: exit with `code`, after printing `message`.
#[derive(Debug, thiserror::Error)]
#[error("{message}")]
pub struct Stopped {
    /// The exit code: 128 + the signal's number (130 for SIGINT, 143 for SIGTERM).
    pub code: u8,
    /// What stopped and the command that continues.
    pub message: String,
}

/// The exit code for a stop by signal `signal` (130 when it is not known).
#[must_use]
pub fn exit_code_of(signal: usize) -> u8 {
    match signal {
        1..=127 => 128 + signal as u8,
        _ => 130,
    }
}

/// `args` as one POSIX shell command line (arguments with spaces or quotes quoted).
#[must_use]
pub fn shell_words(args: &[String]) -> String {
    args.iter()
        .map(|a| {
            let plain = !a.is_empty()
                && a.chars()
                    .all(|c| c.is_ascii_alphanumeric() || "-_./=,:+@%".contains(c));
            if plain {
                a.clone()
            } else {
                format!("'{}'", a.replace('\'', r"'\''"))
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
}

/// On MPI ranks (the `mpi` feature, more than one rank): a failed rank says so and ends
/// the job on every rank with `code` (MPI_Abort), so that no rank waits for it forever.
/// Otherwise nothing.
pub(super) fn end_ranks(msg: &str, code: u8) {
    #[cfg(feature = "mpi")]
    if harmap::grid::world().parts() > 1 {
        eprintln!("rank {}: {msg}", harmap::grid::world().part());
        harmap::grid::mpi::abort(i32::from(code));
    }
    #[cfg(not(feature = "mpi"))]
    let _ = (msg, code);
}
