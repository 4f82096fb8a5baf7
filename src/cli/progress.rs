//! indicatif adapter for the library's `Progress` trait.

use std::io::IsTerminal;
use std::sync::Mutex;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use super::{Global, ProgressMode};

/// Progress bars on stderr, one per phase.
pub struct Bars {
    bar: Mutex<Option<ProgressBar>>,
    draw: bool,
    verbosity: u8,
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
        }
    }
}

impl harmap::progress::Progress for Bars {
    fn start(&self, name: &str, total: u64) {
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
}
