//! `harmap report`.

use std::path::PathBuf;

use harmap::run::RunDir;

use super::Global;

/// Write the report page of a run: one self-contained HTML file (pictures embedded, no
/// network) with the input, the grid, the topology and any repair, the solve's
/// convergence history, the trace's stop reasons, flips, collisions and distortion, the
/// atlas and the sphere view, slices of phi, theta and psi through the center, and the
/// seconds and peak memory of every stage. Stages not run yet are shown as missing.
///
/// `harmap run` writes this page beside the atlas (RUN's name with .report.html).
///
/// Examples:
///   harmap report starfish.harmap                 # -> starfish.report.html
///   harmap report spot.harmap -o spot-report.html
#[derive(clap::Args, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// The run directory (voxelized at least).
    pub run: PathBuf,
    /// The page to write [default: RUN's name with .report.html].
    #[arg(short, long, value_name = "FILE")]
    pub output: Option<PathBuf>,
}

/// The default page of run directory `run`: its name with .report.html.
#[must_use]
pub fn default_path(run: &std::path::Path) -> PathBuf {
    run.with_extension("report.html")
}

/// Run `harmap report`.
pub fn run(a: &Args, g: &Global) -> anyhow::Result<()> {
    let run = RunDir::open(&a.run).map_err(harmap::Error::from)?;
    let out = a.output.clone().unwrap_or_else(|| default_path(&a.run));
    harmap::report::html::write_report(&run, &out)?;
    g.say(&format!("report: {}", out.display()));
    Ok(())
}
