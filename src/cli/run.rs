//! `harmap run`: the whole pipeline in one command. The pipeline is the library's
//! [`harmap::pipeline::run`]; this parses the flags and prints.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::Context;
use harmap::input::InputOptions;
use harmap::pipeline::{PipelineError, PipelineOptions, PipelineReport, Source, StageRun};
use harmap::progress::Interrupt;
use harmap::trace::Rk45;

use super::exit::{exit_code_of, shell_words, Stopped};
use super::map::MapArgs;
use super::progress::{catch_signals, Bars};
use super::solve::SolveArgs;
use super::trace::TraceArgs;
use super::voxelize::VoxelizeArgs;
use super::{Global, UsageError};

/// Run the pipeline on a shape: voxelization (labels and center), the solve (phi,
/// multigrid; an interrupted solve resumes from its checkpoint), the trace (streamlines
/// from the vertices of the input mesh, or for other inputs of the labels' surface nets,
/// so that the summary has the bijectivity numbers; --seeds boundary traces from every
/// boundary voxel instead), the full-volume map (theta and psi for every voxel, upwind)
/// and the atlas picture (RUN's name with .atlas.png), then a summary.
///
/// Every flag of `harmap voxelize`, `solve`, `trace` and `map` is taken here, with the
/// same defaults, once: --mem bounds every stage, and the trace's integrator tolerance
/// is --trace-rtol (--rtol is the solve's). `harmap solve --resume` has no flag here:
/// an interrupted solve is resumed when its checkpoint fits.
///
/// With no INPUT, runs on the built-in five-armed starfish, centered at its middle.
///
/// Stages already done in RUN with the same options are skipped, so a run that was
/// stopped is finished by giving the same command again. A stage whose options
/// changed runs again, and so does every stage after it that reads its output (the
/// summary says which and why); other voxelization options or another input are
/// refused: --force starts over. Ctrl-C or SIGTERM stops the run at the next
/// iteration, block or tile (exit 130, or 143 for SIGTERM) and prints the command that
/// continues it.
///
/// Examples:
///   harmap run                                 # the built-in starfish -> starfish.harmap
///   harmap run spot.obj -o spot.harmap --resolution 96
///   harmap run spot.obj -o spot.harmap --resolution 96 --rtol 1e-8   # solve, trace, map again
#[derive(clap::Args, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// The shape (default: the built-in starfish).
    pub input: Option<PathBuf>,
    /// The run directory [default: INPUT's name with .harmap, or starfish.harmap].
    #[arg(short, long, value_name = "RUN")]
    pub output: Option<PathBuf>,
    /// Redo every stage, replacing RUN.
    #[arg(long)]
    pub force: bool,
    #[command(flatten, next_help_heading = "Voxelize")]
    pub voxelize: VoxelizeArgs,
    #[command(flatten)]
    pub solve: SolveArgs,
    #[command(flatten)]
    pub trace: TraceArgs,
    /// The trace's --rtol: error allowed per voxel of step, on top of --atol.
    #[arg(long, value_name = "FRACTION", default_value_t = Rk45::default().rtol, help_heading = "Integrator")]
    pub trace_rtol: f64,
    #[command(flatten)]
    pub map: MapArgs,
}

/// Run `harmap run`.
pub fn run(a: &Args, g: &Global) -> anyhow::Result<()> {
    let out = a.output.clone().unwrap_or_else(|| {
        let stem =
            a.input
                .as_ref()
                .and_then(|p| p.file_name())
                .map_or("starfish".to_owned(), |n| {
                    let n = n.to_string_lossy();
                    n.split('.').next().unwrap_or("shape").to_owned()
                });
        PathBuf::from(format!("{stem}.harmap"))
    });
    let (mut vopts, iopts): (_, InputOptions) = a.voxelize.options()?;
    a.trace.check()?;
    if a.input.is_none() && vopts.center.is_none() {
        // The starfish is symmetric about the origin: its middle is the natural center
        // (the deepest voxel lies off-middle, toward an arm's root).
        vopts.center = Some([0.0, 0.0, 0.0]);
    }
    let mem = a.voxelize.mem;
    let opts = PipelineOptions {
        out: out.clone(),
        force: a.force,
        voxelize: vopts,
        solve: a.solve.options(false, mem),
        trace: a.trace.options(a.trace_rtol, mem),
        map: a.map.options(None, mem),
        atlas: Some(out.with_extension("atlas.png")),
        report: Some(super::report::default_path(&out)),
    };
    let source = a
        .input
        .as_ref()
        .map_or(Source::Starfish, |p| Source::File(p, &iopts));
    let interrupt = catch_signals()?;
    let bars = Bars::with_interrupt(g, interrupt.clone());
    let done = AtomicBool::new(false);
    let result = std::thread::scope(|s| {
        s.spawn(|| watchdog(&interrupt, &done, &bars, &out));
        let r = harmap::pipeline::run(&source, &opts, &bars);
        done.store(true, Ordering::SeqCst);
        r
    });
    let report = match result {
        Ok(r) => r,
        Err(PipelineError::Interrupted { run, stage, signal }) => {
            return Err(Stopped {
                code: exit_code_of(signal),
                message: stopped_message(&run, stage),
            }
            .into());
        }
        Err(e @ PipelineError::OtherRun { .. }) => return Err(UsageError(e.to_string()).into()),
        Err(PipelineError::Stage(e)) => {
            return Err(anyhow::Error::from(e))
                .with_context(|| format!("harmap run into {}", out.display()));
        }
    };
    print(&report, g);
    Ok(())
}

/// How long a stage has, after SIGINT or SIGTERM, to stop at its next block, tile or
/// iteration before [`watchdog`] ends the process: a second in all from the signal.
const GRACE: Duration = Duration::from_millis(700);

/// What an interrupted run prints: the stage it stopped in and the command that
/// continues it (the same command, without --force, which would start over).
fn stopped_message(run: &Path, stage: &str) -> String {
    let args: Vec<String> = std::env::args().filter(|a| a != "--force").collect();
    format!(
        "{}: stopped during the {stage} stage; the finished stages are kept. Continue with `{}`",
        run.display(),
        shell_words(&args)
    )
}

/// The stop within a second, whatever the stage is doing: once `interrupt` is set,
/// the pipeline has [`GRACE`] to return (`done`); a stage still busy in a step that
/// polls nothing (a long single pass) is then ended with the process, as a kill would
/// end it. Every file of a run is written under a temporary name and renamed, so that
/// leaves what a kill leaves: the finished stages, and leftovers the next run sweeps.
fn watchdog(interrupt: &Interrupt, done: &AtomicBool, bars: &Bars, run: &Path) {
    while !done.load(Ordering::SeqCst) {
        if interrupt.is_set() {
            let t = Instant::now();
            while t.elapsed() < GRACE {
                if done.load(Ordering::SeqCst) {
                    return;
                }
                std::thread::sleep(Duration::from_millis(10));
            }
            let phase = bars.phase();
            // The stage is the phase's first word ("voxelize: labels", "map (upwind)").
            let stage = phase
                .split([':', ' ', '('])
                .next()
                .filter(|s| !s.is_empty())
                .unwrap_or("voxelize");
            eprintln!("error: {}", stopped_message(run, stage));
            std::process::exit(i32::from(exit_code_of(interrupt.signal())));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The lines of a finished run: each stage, then the summary.
fn print(r: &PipelineReport, g: &Global) {
    let out = r.run.display();
    for (stage, how) in &r.stages {
        match how {
            StageRun::Skipped => g.say(&format!(
                "{stage}: already done in {out} with these options (skipped; --force redoes every stage)"
            )),
            StageRun::Ran { again, resumed } => {
                if let Some(why) = again {
                    g.say(&format!("{stage}: run again: {why}"));
                }
                if *resumed {
                    g.say(&format!("{stage}: continued from its checkpoint"));
                }
                g.say(&stage_line(r, stage));
            }
        }
    }
    if let Some(w) = &r.atlas_fallback {
        eprintln!("warning: atlas colored by the main axis: {w}");
    }
    let s = &r.summary;
    let bijectivity = match s.flipped {
        Some((flipped, measured)) => format!(
            "{flipped} of {measured} surface triangles flipped on the sphere, {} colliding seeds",
            s.colliding_seeds
        ),
        None => format!("{} colliding seeds", s.colliding_seeds),
    };
    let atlas = r
        .atlas
        .as_ref()
        .map_or_else(|| "none".to_owned(), |p| p.display().to_string());
    let page = r
        .report
        .as_ref()
        .map_or_else(|| "none".to_owned(), |p| p.display().to_string());
    g.say(&format!(
        "{out}: done. Seconds per stage: voxelize {:.2}, solve {:.2}, trace {:.2}, map {:.2}.\n  \
         {:.3}% of the streamlines reached the center; {bijectivity}; {} of {} voxels mapped.\n  \
         fields: {out}/phi, {out}/theta, {out}/psi (Zarr); seed table: {out}/seeds; atlas: {atlas}; report: {page}\n  \
         `harmap info {out}` shows the numbers; `harmap export {out} --format nifti|vti|csv|...` exports.",
        s.seconds[0],
        s.seconds[1],
        s.seconds[2],
        s.seconds[3],
        100.0 * s.reached_fraction,
        s.mapped.0,
        s.mapped.1,
    ));
}

/// The line of a stage that ran now.
fn stage_line(r: &PipelineReport, stage: &str) -> String {
    match stage {
        "voxelize" => r.voxelize.as_ref().map_or_else(String::new, |v| {
            let s = v.grid.shape;
            let mut line = format!(
                "voxelize: {} x {} x {} voxels, {} solid, genus {}, center ({:.3}, {:.3}, {:.3}), {:.2}s",
                s[2],
                s[1],
                s[0],
                v.counts[1] + v.counts[2] + v.counts[3],
                v.genus,
                v.center[0],
                v.center[1],
                v.center[2],
                v.timings.iter().map(|t| t.1).sum::<f64>()
            );
            if let Some(p) = v.probe_summary() {
                let _ = write!(line, "\nvoxelize: {p}");
            }
            line
        }),
        "solve" => r.solve.as_ref().map_or_else(String::new, |(s, t)| {
            format!("solve: {}", super::solve::summary(s, *t))
        }),
        "trace" => r.trace.as_ref().map_or_else(String::new, |(s, t)| {
            format!("trace: {}", super::trace::summary(s, *t))
        }),
        "map" => r.map.as_ref().map_or_else(String::new, |(s, t)| {
            format!("map: {}", super::map::summary(s, *t))
        }),
        _ => String::new(),
    }
}

#[cfg(test)]
mod tests {
    use clap::CommandFactory;

    /// Stage flags that `harmap run` names otherwise (the trace's --rtol, since --rtol
    /// is the solve's) or does without (`solve --resume`: run resumes by itself).
    const RENAMED: [(&str, &str, Option<&str>); 2] = [
        ("trace", "rtol", Some("trace-rtol")),
        ("solve", "resume", None),
    ];

    /// Every long flag of `harmap voxelize`, `solve`, `trace` and `map` is a flag of
    /// `harmap run` (but the renames above), with the same default value.
    #[test]
    fn run_takes_every_stage_flag_with_the_same_default() {
        let cli = super::super::Cli::command();
        let run = cli.find_subcommand("run").expect("run");
        for stage in ["voxelize", "solve", "trace", "map"] {
            let sc = cli.find_subcommand(stage).expect("stage");
            let mut checked = 0;
            for arg in sc.get_arguments() {
                let Some(long) = arg.get_long() else {
                    continue; // the positional RUN or INPUT
                };
                let want = match RENAMED.iter().find(|(s, l, _)| *s == stage && *l == long) {
                    Some((_, _, None)) => continue,
                    Some((_, _, Some(renamed))) => *renamed,
                    None => long,
                };
                let Some(r) = run.get_arguments().find(|a| a.get_long() == Some(want)) else {
                    panic!("`harmap {stage} --{long}` has no `harmap run --{want}`");
                };
                assert_eq!(
                    r.get_default_values(),
                    arg.get_default_values(),
                    "the default of `harmap run --{want}` differs from `harmap {stage} --{long}`'s"
                );
                checked += 1;
            }
            assert!(checked > 0, "{stage}: no flags found");
        }
    }
}
