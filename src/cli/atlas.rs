//! `harmap atlas`.

use std::path::PathBuf;

use harmap::report::domains::{parse_domains, Domain};
use harmap::report::{atlas, ColorBy};
use harmap::run::RunDir;

use super::{Global, UsageError};

/// Draw the theta-psi atlas of a traced run (the paper's figures), or the mapped sphere.
///
/// Each seed that reached the center is a point at its arrival angles: psi (azimuth,
/// -180..180 degrees) across, theta (polar angle, 0 at the top) down. Points are colored
/// by their place on the shape (default: the position along the shape's main axis), so
/// regions of the shape can be matched to lobes of the atlas; separate lobes with no
/// overlap show a one-to-one map. For molecules, --color chain, residue or domain colors
/// each seed by the chain, residue number or --domains stretch of its nearest atom (the
/// input file is read again; it must be where it was and unchanged), so domains show
/// as lobes. The title gives the counts and, for surface seeds, the
/// flipped triangles.
///
/// --sphere draws the unit sphere with every seed at its arrival direction, seen from
/// four sides.
///
/// Examples:
///   harmap atlas spot.harmap -o spot-atlas.png
///   harmap atlas spot.harmap -o spot-sphere.svg --sphere
///   harmap atlas adk.harmap -o adk-atlas.png --color residue
///   harmap atlas adk.harmap -o adk-domains.png --color domain --domains NMP=30-59,LID=122-159
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
    /// What colors the points: axis (position along the shape's main axis), z,
    /// distance (from the center), or for molecules chain, residue or domain (of the
    /// nearest atom).
    #[arg(long, value_enum, default_value_t = ColorArg::Axis)]
    pub color: ColorArg,
    /// With --color domain: named stretches of residues, NAME=[CHAIN:]FIRST-LAST,
    /// comma-separated (e.g. NMP=30-59,LID=122-159); a name may repeat.
    // The full path keeps clap from reading `Vec` as "the flag may repeat".
    #[arg(long, value_name = "SPEC", value_parser = parse_domains)]
    pub domains: Option<std::vec::Vec<Domain>>,
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
    /// Molecules: the chain of the nearest atom (a color per chain, with a legend).
    Chain,
    /// Molecules: the residue number of the nearest atom (a rainbow along the sequence,
    /// with a color bar).
    Residue,
    /// Molecules: the --domains stretch of residues the nearest atom is in.
    Domain,
}

/// Run `harmap atlas`.
pub fn run(a: &Args, g: &Global) -> anyhow::Result<()> {
    let run = RunDir::open(&a.run).map_err(harmap::Error::from)?;
    let by = match a.color {
        ColorArg::Axis => ColorBy::Axis,
        ColorArg::Z => ColorBy::Z,
        ColorArg::Distance => ColorBy::Distance,
        ColorArg::Chain => ColorBy::Chain,
        ColorArg::Residue => ColorBy::Residue,
        ColorArg::Domain => ColorBy::Domains(a.domains.clone().ok_or_else(|| {
            UsageError(
                "--color domain needs --domains NAME=FIRST-LAST,... (e.g. NMP=30-59,LID=122-159)"
                    .into(),
            )
        })?),
    };
    if a.domains.is_some() && !matches!(by, ColorBy::Domains(_)) {
        return Err(UsageError("--domains goes with --color domain".into()).into());
    }
    let n = atlas(&run, &a.output, a.sphere, &by)?;
    g.say(&format!("{}: {n} points", a.output.display()));
    Ok(())
}
