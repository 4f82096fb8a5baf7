//! Progress reporting without a terminal dependency: the library reports through
//! [`Progress`]; the CLI adapts it to indicatif bars. [`Interrupt`] is the cancellation
//! token the long loops poll: the CLI sets it from SIGINT and SIGTERM.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;

use crate::grid::GridError;

/// Receives progress of long stages. Implementations must be cheap and thread-safe.
pub trait Progress: Send + Sync {
    /// A new phase of `total` units begins (`name` is shown to the user).
    fn start(&self, name: &str, total: u64);
    /// `n` more units of the current phase are done.
    fn advance(&self, n: u64);
    /// The current phase's total changed (e.g. a new estimate of iterations left).
    fn set_total(&self, total: u64) {
        let _ = total;
    }
    /// The current phase has done `pos` units.
    fn set_position(&self, pos: u64) {
        let _ = pos;
    }
    /// Show `message` with the current phase (e.g. the residual).
    fn message(&self, message: &str) {
        let _ = message;
    }
    /// The current phase is done.
    fn finish(&self);
    /// A warning for the user (printed whatever the verbosity).
    fn warn(&self, message: &str);
    /// An informational line (shown with -v or when no bar is drawn).
    fn info(&self, message: &str) {
        let _ = message;
    }
    /// The cancellation token the stages poll, if the caller can stop them.
    fn interrupt(&self) -> Option<&Interrupt> {
        None
    }
    /// Whether the caller asked the work to stop (see [`Interrupt`]).
    fn interrupted(&self) -> bool {
        self.interrupt().is_some_and(Interrupt::is_set)
    }
}

/// Reports nothing; warnings go to stderr.
pub struct Silent;

impl Progress for Silent {
    fn start(&self, _: &str, _: u64) {}
    fn advance(&self, _: u64) {}
    fn finish(&self) {}
    fn warn(&self, message: &str) {
        eprintln!("warning: {message}");
    }
}

/// A cancellation token: set once (by a signal handler, or by [`Interrupt::set`]), and
/// polled by the long loops of the stages, which then stop at the next block, tile or
/// iteration. Clones share the same state.
#[derive(Clone, Debug, Default)]
pub struct Interrupt {
    stop: Arc<AtomicBool>,
    signal: Arc<AtomicUsize>,
}

impl Interrupt {
    /// A token that is not set.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// Ask the work to stop, giving the signal number that asked (0: none).
    pub fn set(&self, signal: usize) {
        // The signal first, so whoever sees the flag sees which signal set it.
        self.signal.store(signal, Ordering::SeqCst);
        self.stop.store(true, Ordering::SeqCst);
    }

    /// Whether the work was asked to stop.
    #[must_use]
    pub fn is_set(&self) -> bool {
        self.stop.load(Ordering::SeqCst)
    }

    /// The signal that asked (0 when set otherwise, or not set).
    #[must_use]
    pub fn signal(&self) -> usize {
        self.signal.load(Ordering::SeqCst)
    }

    /// The flag itself, for the solve (which takes an `AtomicBool`) and for signal
    /// handlers that set it.
    #[must_use]
    pub fn flag(&self) -> &Arc<AtomicBool> {
        &self.stop
    }

    /// The signal number's cell, for signal handlers that record which signal came.
    #[must_use]
    pub fn signal_cell(&self) -> &Arc<AtomicUsize> {
        &self.signal
    }
}

/// `Err` when `progress` says the work should stop: the block and tile loops of the
/// stages call it once per block or round, so a stop request ends them within a second.
/// The error is an I/O error of kind `Interrupted`; the caller that set the token knows
/// why and reports it.
pub fn check_interrupt(progress: &dyn Progress) -> Result<(), GridError> {
    if progress.interrupted() {
        return Err(GridError::Io {
            path: std::path::PathBuf::from("(stopped)"),
            source: std::io::Error::new(
                std::io::ErrorKind::Interrupted,
                "stopped on request (a signal)",
            ),
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    struct WithToken(Interrupt);
    impl Progress for WithToken {
        fn start(&self, _: &str, _: u64) {}
        fn advance(&self, _: u64) {}
        fn finish(&self) {}
        fn warn(&self, _: &str) {}
        fn interrupt(&self) -> Option<&Interrupt> {
            Some(&self.0)
        }
    }

    #[test]
    fn a_set_token_stops_the_loops_and_clones_share_it() {
        let t = Interrupt::new();
        let p = WithToken(t.clone());
        assert!(check_interrupt(&p).is_ok());
        assert!(!Silent.interrupted());
        t.set(15);
        assert!(p.interrupted());
        assert_eq!(p.0.signal(), 15);
        let e = check_interrupt(&p).unwrap_err();
        assert!(
            matches!(&e, GridError::Io { source, .. } if source.kind() == std::io::ErrorKind::Interrupted),
            "{e}"
        );
    }
}
