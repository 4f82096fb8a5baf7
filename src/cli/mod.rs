//! The command line: the only place that knows clap and indicatif.
//!
//! Exit codes: 0 success, 1 the run failed, 2 bad usage or bad input, 130 interrupted
//! (SIGINT/SIGTERM) with the solve checkpointed. A closed pipe on
//! stdout (`harmap info RUN | head`) counts as success.

mod atlas;
mod bench;
mod exit;
mod export;
mod flags;
mod info;
mod inverse;
mod map;
mod progress;
mod report;
mod run;
mod solve;
mod threads;
mod trace;
mod voxelize;

use std::fmt::Write as _;
use std::io::Write;
use std::process::ExitCode;

use clap::{Parser, Subcommand, ValueEnum};
use exit::{exit_code, is_broken_pipe};
use threads::cap_threads;

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
    #[command(hide = true)]
    Flags(flags::Args),
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
            let code = exit_code(&e);
            exit::end_ranks(&msg, code);
            eprintln!("{msg}");
            ExitCode::from(code)
        }
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
    // On MPI ranks only rank 0 speaks; the others report errors only.
    let other_rank = harmap::grid::world().part() != 0;
    let global = Global {
        verbosity: if cli.quiet || other_rank {
            0
        } else if cli.verbose {
            2
        } else {
            1
        },
        progress: [cli.progress, ProgressMode::Never][usize::from(other_rank)],
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
        Command::Flags(a) => flags::run(&a, &global),
    }
}
