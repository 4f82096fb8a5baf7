//! `harmap export`.

use std::path::PathBuf;

use harmap::grid::MemBudget;
use harmap::run::RunDir;

use super::progress::Bars;
use super::{Global, UsageError};

/// Export a run's results for other tools.
///
/// Formats:
///   csv              the seed table: x,y,z,theta,psi,phi,stop,stop_name,steps,length
///                    (+ vertex for surface seeds); angles in radians, empty where the
///                    streamline did not reach the center
///   obj-sphere       the input surface with its vertices moved to the unit sphere at
///                    their arrival directions, (psi, theta) as texture coordinates
///                    (needs `harmap trace --seeds surface`)
///   vtk-streamlines  the streamlines as VTK legacy polydata (binary) for ParaView:
///                    traced again with the options of the run's trace (or --sample N
///                    of its seeds), with cell data seed, stop, theta, psi and point data
///                    arc_length
///
/// The file is written under a temporary name and renamed when whole.
///
/// Examples:
///   harmap export spot.harmap --format csv -o spot-seeds.csv
///   harmap export spot.harmap --format obj-sphere -o spot-sphere.obj
///   harmap export spot.harmap --format vtk-streamlines --sample 2000 -o spot-lines.vtk
#[derive(clap::Args, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// The run directory.
    pub run: PathBuf,
    /// What to write.
    #[arg(long, value_enum)]
    pub format: Format,
    /// The file to write.
    #[arg(short, long, value_name = "PATH")]
    pub output: PathBuf,
    /// vtk-streamlines: trace this many of the seeds (a deterministic subset).
    #[arg(long, value_name = "N")]
    pub sample: Option<u64>,
    /// Memory budget (vtk-streamlines traces again).
    #[arg(long, value_name = "SIZE", default_value = "1GiB")]
    pub mem: MemBudget,
}

/// Export formats.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum Format {
    /// The seed table as CSV.
    Csv,
    /// The boundary -> sphere map as an OBJ mesh.
    ObjSphere,
    /// Streamlines as VTK legacy polydata.
    VtkStreamlines,
}

/// Run `harmap export`.
pub fn run(a: &Args, g: &Global) -> anyhow::Result<()> {
    let run = RunDir::open(&a.run).map_err(harmap::Error::from)?;
    if a.sample.is_some() && !matches!(a.format, Format::VtkStreamlines) {
        return Err(UsageError("--sample applies to --format vtk-streamlines only".into()).into());
    }
    let (n, what) = match a.format {
        Format::Csv => (harmap::export::seeds_csv(&run, &a.output)?, "seeds"),
        Format::ObjSphere => (harmap::export::obj_sphere(&run, &a.output)?, "triangles"),
        Format::VtkStreamlines => (
            harmap::export::vtk_streamlines(&run, &a.output, a.sample, a.mem, &Bars::new(g))?,
            "streamlines",
        ),
    };
    g.say(&format!("{}: {n} {what}", a.output.display()));
    Ok(())
}
