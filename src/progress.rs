//! Progress reporting without a terminal dependency: the library reports through
//! [`Progress`]; the CLI adapts it to indicatif bars.

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
