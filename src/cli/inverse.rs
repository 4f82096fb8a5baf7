//! `harmap inverse`.

use std::path::PathBuf;

use harmap::grid::MemBudget;
use harmap::map::inverse::inverse_csv;
use harmap::run::RunDir;

use super::progress::Bars;
use super::Global;

/// The inverse map: from (phi, theta, psi) back to a point (x, y, z) of the shape.
///
/// Each point is found by starting on the stop sphere around the center in the
/// direction (theta, psi) and following the streamline backwards, up phi, until phi is
/// reached (below the stop sphere: on the ray from the center). It undoes the steps of
/// `harmap map --exact` one by one (they step on levels of ln(1 - phi)), so for
/// parameters from the exact map inverse(forward(x)) returns to x, even down thin arms
/// where the map squeezes streamlines 1e-10 together; the last fraction of a voxel
/// before the boundary is traced uphill.
///
/// IN.csv has a header naming the columns phi, theta and psi (radians; other columns are
/// ignored). A column u (= 1 - phi, as RUN/u/0 stores it) is used instead of phi when
/// present: in thin parts phi rounds to 1 in f64 and no longer tells points apart.
/// OUT.csv gets phi (or u),theta,psi,x,y,z,status per row; where a row has no point
/// (phi outside [0, 1], a direction whose streamline leaves the solid, ...) x, y, z are
/// empty and status says why. The direction field is built in tiles, into a cache that
/// stays within --mem.
///
/// Examples:
///   harmap inverse spot.harmap --points params.csv -o points.csv
#[derive(clap::Args, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// The run directory (solved; traced runs use the trace's stop ball).
    pub run: PathBuf,
    /// CSV with columns phi, theta, psi.
    #[arg(long, value_name = "IN.csv")]
    pub points: PathBuf,
    /// Where to write the points.
    #[arg(short, long, value_name = "OUT.csv")]
    pub output: PathBuf,
    /// Memory budget (e.g. 256MiB, 2GiB).
    #[arg(long, value_name = "SIZE", default_value = "1GiB")]
    pub mem: MemBudget,
}

/// Run `harmap inverse`.
pub fn run(a: &Args, g: &Global) -> anyhow::Result<()> {
    let run = RunDir::open(&a.run).map_err(harmap::Error::from)?;
    let c = inverse_csv(&run, &a.points, &a.output, a.mem, &Bars::new(g))?;
    if c.rows > 0 && c.failed == c.rows {
        // Nothing usable came out: a run that exits 0 here looks like a success.
        anyhow::bail!(
            "{}: none of the {} rows got a point (see the status column of {})",
            a.points.display(),
            c.rows,
            a.output.display()
        );
    }
    g.say(&format!(
        "{}: {} rows, {} with a point, {} without (see their status)",
        a.output.display(),
        c.rows,
        c.rows - c.failed,
        c.failed
    ));
    Ok(())
}
