//! `harmap solve`.

use std::path::PathBuf;

use harmap::grid::MemBudget;
use harmap::run::RunDir;
use harmap::solve::driver::Method;
use harmap::solve::{solve, Cycle, CycleOptions, SolveError, SolveOptions, SolveReport};

use super::progress::Bars;
use super::{Global, UsageError};

/// Solve Laplace's equation for phi on a voxelized run (the paper's steps 4-5).
///
/// phi = 1 on the boundary, 0 in the center ball and 1 + k*eps on the four exterior
/// layers; interior voxels are the unknowns of the 7-point finite-difference system.
/// The result goes to RUN/phi/0 (f64, NaN outside the problem); the stop criterion, the
/// iterations and the residual history go to the run's attributes (`harmap info RUN`).
///
/// Multigrid starts with full multigrid (--cycle fmg, the default): the problem solved
/// on the coarsest level, each level's solution interpolated up as the next one's
/// start and improved by a V-cycle, then V-cycles on the finest level. --cycle v starts
/// the V-cycles from the initial values instead.
///
/// Stopping: --rtol stops when the residual ||r||_2 has fallen by that factor from the
/// start (the initial values); --tol is the paper's criterion (largest change of phi in
/// an iteration). The change criterion alone stops slow methods (Jacobi, SOR) far from
/// the answer: their changes are small long before the error is (see docs/solve.md).
/// With --cycle fmg, --rtol 0 (and no --tol) stops when the algebraic error is a tenth
/// of the discretization error (about 15 fine-grid sweeps): phi is then as accurate as
/// the grid allows, but the tiny values of u in thin parts are not accurate enough for
/// the trace, which needs the default 1e-6.
///
/// Interrupting (Ctrl-C, SIGTERM) writes a checkpoint and exits with code 130;
/// `--resume` continues from it and gives the same bytes as an uninterrupted run.
///
/// Examples:
///   harmap solve spot.harmap
///   harmap solve big.harmap --mem 1GiB --checkpoint-every 10m
///   harmap solve big.harmap --resume
///   harmap solve spot.harmap --method jacobi --tol 1e-6 --max-iter 100000
#[derive(clap::Args, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// The run directory (made by `harmap voxelize`).
    pub run: PathBuf,
    #[command(flatten)]
    pub opts: SolveArgs,
    /// Continue from the last checkpoint of an interrupted solve (with the same
    /// options: the command an interrupted solve prints has them).
    #[arg(long)]
    pub resume: bool,
    /// Memory budget: peak resident memory (e.g. 256MiB, 2GiB).
    #[arg(long, value_name = "SIZE", default_value_t = MemBudget::default())]
    pub mem: MemBudget,
}

/// Solve flags, shared with `harmap run` (which flattens them under "Solve"); the
/// defaults are [`SolveOptions::default`]'s.
#[derive(clap::Args, Debug, Clone)]
#[command(next_help_heading = "Solve")]
pub struct SolveArgs {
    /// The iteration: multigrid (V-cycles), sor (red-black, optimal omega) or jacobi
    /// (the paper's, slow; a reference).
    #[arg(long, value_enum, default_value_t = MethodArg::from(SolveOptions::default().method))]
    pub method: MethodArg,
    /// Multigrid's start: fmg (full multigrid, then V-cycles) or v (V-cycles from the
    /// initial values).
    #[arg(long, value_enum, default_value_t = CycleArg::from(SolveOptions::default().cycle.kind))]
    pub cycle: CycleArg,
    /// Stop when the relative residual ||r||_2 / ||r_0||_2 is below R, in [0, 1) (0:
    /// off, with --tol; with --cycle fmg, stop at the discretization error).
    #[arg(long, value_name = "R", default_value_t = SolveOptions::default().rtol)]
    pub rtol: f64,
    /// The paper's zeta: stop when the largest change of an iteration is below it (0:
    /// off).
    #[arg(long, value_name = "ZETA", default_value_t = SolveOptions::default().tol)]
    pub tol: f64,
    /// Spacing of the exterior layers' values, 1 + k*eps.
    #[arg(long, value_name = "E", default_value_t = SolveOptions::default().eps)]
    pub eps: f64,
    /// Iteration limit (cycles for multigrid, sweeps for sor and jacobi; at least 1).
    #[arg(long, value_name = "N", default_value_t = SolveOptions::default().max_iter)]
    pub max_iter: u64,
    /// Over-relaxation factor for --method sor [default: 2/(1+sin(pi/n)), n the longest
    /// axis].
    #[arg(long, value_name = "W")]
    pub omega: Option<f64>,
    /// Time between checkpoints, seconds or 90s, 10m, 1h (0: only when interrupted).
    #[arg(long, value_name = "DURATION", default_value_t = SolveOptions::default().checkpoint_every, value_parser = parse_duration)]
    pub checkpoint_every: f64,
}

/// `--method` values.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum MethodArg {
    /// Geometric multigrid V-cycles.
    Multigrid,
    /// Red-black successive over-relaxation.
    Sor,
    /// The paper's Jacobi iteration.
    Jacobi,
}

impl From<Method> for MethodArg {
    fn from(m: Method) -> Self {
        match m {
            Method::Multigrid => MethodArg::Multigrid,
            Method::Sor => MethodArg::Sor,
            Method::Jacobi => MethodArg::Jacobi,
        }
    }
}

/// `--cycle` values.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum CycleArg {
    /// Full multigrid, then V-cycles.
    Fmg,
    /// V-cycles from the initial values.
    V,
}

impl From<Cycle> for CycleArg {
    fn from(c: Cycle) -> Self {
        match c {
            Cycle::Fmg => CycleArg::Fmg,
            Cycle::V => CycleArg::V,
        }
    }
}

impl SolveArgs {
    /// The library options, with the memory budget `mem`.
    #[must_use]
    pub fn options(&self, resume: bool, mem: MemBudget) -> SolveOptions {
        SolveOptions {
            method: match self.method {
                MethodArg::Multigrid => Method::Multigrid,
                MethodArg::Sor => Method::Sor,
                MethodArg::Jacobi => Method::Jacobi,
            },
            tol: self.tol,
            rtol: self.rtol,
            eps: self.eps,
            cycle: CycleOptions {
                kind: match self.cycle {
                    CycleArg::Fmg => Cycle::Fmg,
                    CycleArg::V => Cycle::V,
                },
                ..CycleOptions::default()
            },
            max_iter: self.max_iter,
            omega: self.omega,
            mem,
            checkpoint_every: self.checkpoint_every,
            resume,
            ..SolveOptions::default()
        }
    }
}

/// Parse `90s`, `10m`, `1h`, or plain seconds.
pub fn parse_duration(s: &str) -> Result<f64, String> {
    let t = s.trim();
    let (num, mult) = match t.chars().last() {
        Some('s') => (&t[..t.len() - 1], 1.0),
        Some('m') => (&t[..t.len() - 1], 60.0),
        Some('h') => (&t[..t.len() - 1], 3600.0),
        _ => (t, 1.0),
    };
    match num.trim().parse::<f64>() {
        Ok(v) if v >= 0.0 && v.is_finite() => Ok(v * mult),
        _ => Err(format!("'{s}' is not a duration like 90s, 10m or 1h")),
    }
}

/// One line about a finished solve.
#[must_use]
pub fn summary(r: &SolveReport, seconds: f64) -> String {
    format!(
        "{} iterations of {} in {seconds:.2} s, stopped by {} (relative residual {:.2e}, largest change {:.2e}), {} unknowns",
        r.iterations,
        r.method.name(),
        r.stopped_by.name(),
        r.relative_residual,
        r.max_change,
        r.unknowns
    )
}

/// Run `harmap solve`.
pub fn run(a: &Args, g: &Global) -> anyhow::Result<()> {
    let run = RunDir::open(&a.run).map_err(harmap::Error::from)?;
    let opts = a.opts.options(a.resume, a.mem);
    harmap::pipeline::check_solve(&opts)?;
    if a.resume && !run.has_checkpoint() {
        return Err(UsageError(format!(
            "{}: no checkpoint to resume from (the solve was not started, or stopped before its first checkpoint); run `{}` without --resume",
            a.run.display(),
            continue_command(false)
        ))
        .into());
    }
    let interrupt = super::progress::catch_signals()?;
    let t = std::time::Instant::now();
    let r = match solve(
        &run,
        &opts,
        interrupt.flag(),
        &Bars::with_interrupt(g, interrupt.clone()),
    ) {
        Ok(r) => r,
        Err(harmap::Error::Solve(SolveError::Interrupted {
            iterations, path, ..
        })) => {
            // The library's hint names the run only; the checkpoint is for these
            // options, so the command that continues it repeats them.
            return Err(super::exit::Stopped {
                code: super::exit::exit_code_of(interrupt.signal()),
                message: format!(
                    "interrupted after {iterations} iterations; the state is checkpointed in {}; continue with `{}`",
                    path.display(),
                    continue_command(true)
                ),
            }
            .into());
        }
        Err(e) => return Err(e.into()),
    };
    g.say(&format!(
        "{}: {}; phi in {}",
        a.run.display(),
        summary(&r, t.elapsed().as_secs_f64()),
        run.root().join("phi").display()
    ));
    Ok(())
}

/// This process's command line, with `--resume` (`resume`) or without it, quoted for
/// a POSIX shell.
fn continue_command(resume: bool) -> String {
    let mut args: Vec<String> = std::env::args().filter(|a| a != "--resume").collect();
    if resume {
        args.push("--resume".into());
    }
    super::exit::shell_words(&args)
}
