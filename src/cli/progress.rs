//! indicatif adapter for the library's `Progress` trait.

use std::io::IsTerminal;
use std::sync::Mutex;
use std::time::Duration;

use harmap::progress::Interrupt;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use super::{Global, ProgressMode};

/// Progress bars on stderr, one per phase.
pub struct Bars {
    bar: Mutex<Option<ProgressBar>>,
    draw: bool,
    verbosity: u8,
    interrupt: Option<Interrupt>,
    /// The name of the phase last started (empty before the first).
    phase: Mutex<String>,
}

impl Bars {
    /// Bars per the global `--progress` and `-q` settings.
    pub fn new(g: &Global) -> Self {
        let draw = g.verbosity > 0
            && match g.progress {
                ProgressMode::Always => true,
                ProgressMode::Never => false,
                ProgressMode::Auto => std::io::stderr().is_terminal(),
            };
        Self {
            bar: Mutex::new(None),
            draw,
            verbosity: g.verbosity,
            interrupt: None,
            phase: Mutex::new(String::new()),
        }
    }

    /// Bars whose stages poll `interrupt` (set by [`catch_signals`]).
    pub fn with_interrupt(g: &Global, interrupt: Interrupt) -> Self {
        Self {
            interrupt: Some(interrupt),
            ..Self::new(g)
        }
    }

    /// The name of the phase last started (empty before the first).
    pub fn phase(&self) -> String {
        self.phase.lock().expect("lock").clone()
    }
}

/// SIGINT and SIGTERM set the returned token (and record which came) instead of
/// killing the process: the stages poll it and stop at the next iteration, block or
/// tile. A second signal while the first is being handled ends the process at once
/// with 128 + its number.
pub fn catch_signals() -> anyhow::Result<Interrupt> {
    let token = Interrupt::new();
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        // Registered first, so it sees the flag as the earlier signal left it.
        signal_hook::flag::register_conditional_shutdown(
            sig,
            128 + sig,
            std::sync::Arc::clone(token.flag()),
        )?;
        signal_hook::flag::register_usize(
            sig,
            std::sync::Arc::clone(token.signal_cell()),
            sig as usize,
        )?;
        signal_hook::flag::register(sig, std::sync::Arc::clone(token.flag()))?;
    }
    Ok(token)
}

impl harmap::progress::Progress for Bars {
    fn start(&self, name: &str, total: u64) {
        name.clone_into(&mut self.phase.lock().expect("lock"));
        if !self.draw {
            if self.verbosity > 1 {
                eprintln!("{name} ...");
            }
            return;
        }
        let bar = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr());
        bar.set_style(
            ProgressStyle::with_template(
                "{msg:50} [{bar:25}] {pos}/{len} {elapsed_precise} eta {eta}",
            )
            .expect("template")
            .progress_chars("=> "),
        );
        bar.set_message(name.to_owned());
        bar.enable_steady_tick(Duration::from_millis(200));
        *self.bar.lock().expect("lock") = Some(bar);
    }

    fn advance(&self, n: u64) {
        if let Some(b) = &*self.bar.lock().expect("lock") {
            b.inc(n);
        }
    }

    fn set_total(&self, total: u64) {
        if let Some(b) = &*self.bar.lock().expect("lock") {
            b.set_length(total);
        }
    }

    fn set_position(&self, pos: u64) {
        if let Some(b) = &*self.bar.lock().expect("lock") {
            b.set_position(pos);
        }
    }

    fn message(&self, message: &str) {
        if let Some(b) = &*self.bar.lock().expect("lock") {
            b.set_message(message.to_owned());
        }
    }

    fn finish(&self) {
        if let Some(b) = self.bar.lock().expect("lock").take() {
            b.finish_and_clear();
        }
    }

    fn warn(&self, message: &str) {
        let guard = self.bar.lock().expect("lock");
        match &*guard {
            Some(b) => b.suspend(|| eprintln!("warning: {message}")),
            None => eprintln!("warning: {message}"),
        }
    }

    fn info(&self, message: &str) {
        if self.verbosity > 1 {
            eprintln!("{message}");
        }
    }

    fn interrupt(&self) -> Option<&Interrupt> {
        self.interrupt.as_ref()
    }
}
