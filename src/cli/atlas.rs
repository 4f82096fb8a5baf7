//! `harmap atlas`.

use std::path::PathBuf;

use harmap::report::{atlas, ColorBy};
use harmap::run::RunDir;

use super::Global;

/// Draw the theta-psi atlas of a traced run (the paper's figures), or the mapped sphere.
///
/// Each seed that reached the center is a point at its arrival angles: psi (azimuth,
/// -180..180 degrees) across, theta (polar angle, 0 at the top) down. Points are colored
/// by their place on the shape (default: the position along the shape's main axis), so
/// regions of the shape can be matched to lobes of the atlas; separate lobes with no
/// overlap show a one-to-one map. The title gives the counts and, for surface seeds, the
/// flipped triangles.
///
/// --sphere draws the unit sphere with every seed at its arrival direction, seen from
/// four sides.
///
/// Examples:
///   harmap atlas spot.harmap -o spot-atlas.png
///   harmap atlas spot.harmap -o spot-sphere.svg --sphere
#[derive(clap::Args, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// The run directory (traced).
    pub run: PathBuf,
    /// The picture to write: .png or .svg.
    #[arg(short, long, value_name = "FILE")]
    pub output: PathBuf,
    /// Draw the mapped sphere instead of the atlas.
    #[arg(long)]
    pub sphere: bool,
    /// What colors the points: axis (position along the shape's main axis), z, or
    /// distance (from the center).
    #[arg(long, value_enum, default_value_t = ColorArg::Axis)]
    pub color: ColorArg,
}

/// `--color` values.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum ColorArg {
    /// Position along the shape's main axis.
    Axis,
    /// Height (world z).
    Z,
    /// Distance from the center (protrusions light).
    Distance,
}

/// Run `harmap atlas`.
pub fn run(a: &Args, g: &Global) -> anyhow::Result<()> {
    let run = RunDir::open(&a.run).map_err(harmap::Error::from)?;
    let by = match a.color {
        ColorArg::Axis => ColorBy::Axis,
        ColorArg::Z => ColorBy::Z,
        ColorArg::Distance => ColorBy::Distance,
    };
    let n = atlas(&run, &a.output, a.sphere, by)?;
    g.say(&format!("{}: {n} points", a.output.display()));
    Ok(())
}
