//! The command line: the only place that knows clap and indicatif.
//!
//! Exit codes: 0 success, 1 the run failed, 2 bad usage or bad input, 130 interrupted
//! (SIGINT/SIGTERM) with the solve checkpointed. A closed pipe on
//! stdout (`harmap info RUN | head`) counts as success.

mod atlas;
mod bench;
mod export;
mod info;
mod inverse;
mod map;
mod progress;
mod report;
mod run;
mod solve;
mod trace;
mod voxelize;

use std::fmt::Write as _;
use std::io::Write;
use std::process::ExitCode;

use clap::{Parser, Subcommand, ValueEnum};

/// Out-of-core harmonic volumetric parameterization: map a genus-0 solid onto the ball.
///
/// The pipeline follows Gupta, Voruganti and Dasgupta ("Domain Mapping for Volumetric
/// Parameterization using Harmonic Functions"). Each stage reads and writes a run
/// directory (a Zarr v3 group with OME-Zarr images, e.g. shape.harmap/) that zarr-python
/// and napari open.
///
/// Example:
///   harmap voxelize spot.obj -o spot.harmap --resolution 128
///   harmap info spot.harmap
#[derive(Parser, Debug)]
#[command(
    name = "harmap",
    version,
    about,
    long_about,
    max_term_width = 100,
    verbatim_doc_comment
)]
pub struct Cli {
    /// Worker threads (default: all cores). Results are the same for any count.
    #[arg(long, global = true, value_name = "N")]
    threads: Option<usize>,
    /// Print only errors and warnings.
    #[arg(short, long, global = true, conflicts_with = "verbose")]
    quiet: bool,
    /// Print more about each stage.
    #[arg(short, long, global = true)]
    verbose: bool,
    /// Progress bars: auto (when stderr is a terminal), always or never.
    #[arg(long, global = true, value_enum, default_value_t = ProgressMode::Auto)]
    progress: ProgressMode,
    #[command(subcommand)]
    command: Command,
}

/// When to draw progress bars.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum ProgressMode {
    /// When stderr is a terminal.
    Auto,
    /// Always.
    Always,
    /// Never.
    Never,
}

#[derive(Subcommand, Debug)]
enum Command {
    Run(run::Args),
    Voxelize(voxelize::Args),
    Solve(solve::Args),
    Trace(trace::Args),
    Map(map::Args),
    Inverse(inverse::Args),
    Atlas(atlas::Args),
    Export(export::Args),
    Info(info::Args),
    Report(report::Args),
    Bench(bench::Args),
}

/// A usage or input error found by the CLI itself (exit code 2).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct UsageError(pub String);

/// Global settings every subcommand sees.
pub struct Global {
    /// Verbosity: 0 quiet, 1 normal, 2 verbose.
    pub verbosity: u8,
    /// Progress bar mode.
    pub progress: ProgressMode,
}

impl Global {
    /// Print a line of normal output (suppressed by -q).
    pub fn say(&self, s: &str) {
        if self.verbosity > 0 {
            let _ = writeln!(std::io::stdout(), "{s}");
        }
    }
}

/// Parse arguments, run, and map the outcome to an exit code.
pub fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            let _ = e.print();
            return if e.use_stderr() {
                ExitCode::from(2)
            } else {
                ExitCode::SUCCESS
            };
        }
    };
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            if is_broken_pipe(&e) {
                return ExitCode::SUCCESS;
            }
            let mut msg = format!("error: {e}");
            for cause in e.chain().skip(1) {
                let _ = write!(msg, "\n  caused by: {cause}");
            }
            eprintln!("{msg}");
            ExitCode::from(exit_code(&e))
        }
    }
}

fn is_broken_pipe(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
    })
}

fn exit_code(e: &anyhow::Error) -> u8 {
    for c in e.chain() {
        if c.downcast_ref::<UsageError>().is_some() {
            return 2;
        }
        if let Some(s) = c.downcast_ref::<run::Stopped>() {
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

/// `--threads` beyond this many times the cores only costs: each worker holds its own
/// buffers within `--mem`, and ten thousand threads spent minutes starting and
/// contending on a 64^3 grid that takes 0.08 s.
const THREADS_PER_CORE: usize = 4;

/// The thread count to use for `--threads n` on a machine of `cores`: at most
/// [`THREADS_PER_CORE`] per core, with the warning to print when capped.
fn cap_threads(n: usize, cores: usize) -> (usize, Option<String>) {
    let cap = THREADS_PER_CORE * cores.max(1);
    if n > cap {
        (
            cap,
            Some(format!(
                "--threads {n} is more than {THREADS_PER_CORE} per core on this machine of {cores} cores: using {cap} (results are the same for any count)"
            )),
        )
    } else {
        (n, None)
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    if let Some(n) = cli.threads {
        if n == 0 {
            return Err(UsageError("--threads must be at least 1".into()).into());
        }
        let cores = std::thread::available_parallelism().map_or(1, std::num::NonZero::get);
        let (n, warning) = cap_threads(n, cores);
        if let Some(w) = warning {
            eprintln!("warning: {w}");
        }
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()?;
    }
    let global = Global {
        verbosity: if cli.quiet {
            0
        } else if cli.verbose {
            2
        } else {
            1
        },
        progress: cli.progress,
    };
    match cli.command {
        Command::Run(a) => run::run(&a, &global),
        Command::Voxelize(a) => voxelize::run(&a, &global),
        Command::Solve(a) => solve::run(&a, &global),
        Command::Trace(a) => trace::run(&a, &global),
        Command::Map(a) => map::run(&a, &global),
        Command::Inverse(a) => inverse::run(&a, &global),
        Command::Atlas(a) => atlas::run(&a, &global),
        Command::Export(a) => export::run(&a, &global),
        Command::Info(a) => info::run(&a, &global),
        Command::Report(a) => report::run(&a, &global),
        Command::Bench(a) => bench::run(&a, &global),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn threads_are_capped_with_a_warning() {
        assert_eq!(cap_threads(8, 2), (8, None));
        let (n, w) = cap_threads(10_000, 2);
        assert_eq!(n, 8);
        assert!(w.is_some_and(|w| w.contains("10000") && w.contains("using 8")));
        assert_eq!(cap_threads(3, 0).0, 3);
    }
}
