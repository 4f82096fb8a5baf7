//! `harmap voxelize`.

use std::path::PathBuf;

use anyhow::Context;
use harmap::grid::MemBudget;
use harmap::input::molecule::MoleculeOptions;
use harmap::input::{InputOptions, RawDtype, RawSpec};
use harmap::pipeline::{serve_voxelize, voxelize_new_run_on, Source};
use harmap::voxelize::spheres::MolSurface;
use harmap::voxelize::{labels::NAMES, repair_summary, Scratch, TopologyMode, VoxelizeOptions};

use super::progress::Bars;
use super::{Global, UsageError};

/// Voxelize a shape into a new run directory: labels and the shape center.
///
/// INPUT is a closed triangle surface (.obj, .stl, .ply), a TetGen mesh (.node/.ele),
/// a molecule (.pdb, .cif/.mmcif, .pqr, .xyzr, .xyz; Bondi radii by element, PQR radii
/// as given) or a point set (.csv of x,y,z with --radius), a label volume (a Zarr v3
/// array directory, or .raw with --raw-shape and --raw-dtype; anything > 0 is inside),
/// any of them optionally .gz. Molecules become the solid --surface says (default: ses
/// with a 1.4 Angstrom probe); waters are left out, and other hetero groups unless
/// --keep-hetatm. The solid must be one piece of genus 0: enclosed cavities are filled,
/// and handles and extra pieces are repaired (reported; see --topology), except for a
/// mesh whose own surface has handles, which is refused unless --topology repair,
/// --allow-genus or --keep-largest says otherwise.
///
/// Labels written to RUN/labels/0: 0 exterior, 1 boundary, 2 interior, 3 center,
/// 4..7 the exterior layers 1..4.
///
/// Examples:
///   harmap voxelize spot.obj -o spot.harmap --resolution 128
///   harmap voxelize armadillo.obj.gz -o arm.harmap --resolution 1024 --mem 256MiB
///   harmap voxelize seg.raw --raw-shape 200,256,256 --raw-dtype u8 --spacing 0.5 -o seg.harmap
///   harmap voxelize 1crn.pdb -o 1crn.harmap --spacing 0.5 --surface ses --probe 1.4
#[derive(clap::Args, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// The shape to voxelize.
    pub input: PathBuf,
    /// The run directory to create.
    #[arg(short, long, value_name = "RUN")]
    pub output: PathBuf,
    /// Replace RUN if it exists.
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub opts: VoxelizeArgs,
}

/// Voxelization flags, shared with `harmap run`.
#[derive(clap::Args, Debug, Clone)]
pub struct VoxelizeArgs {
    /// Voxels along the longest side of the shape's bounding box [default: 128].
    #[arg(long, value_name = "N", conflicts_with = "spacing")]
    pub resolution: Option<u64>,
    /// Voxel size in world units (instead of --resolution). For label volumes: the size
    /// of their voxels [default: 1].
    #[arg(long, value_name = "H")]
    pub spacing: Option<f64>,
    /// Voxels of empty space added on every side (at least 5).
    #[arg(long, value_name = "VOXELS", default_value_t = 6)]
    pub padding: u64,
    /// Shape center in world coordinates [default: the voxel deepest inside].
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_point)]
    pub center: Option<[f64; 3]>,
    /// phi = 0 on every voxel within this many voxels of the center.
    #[arg(long, value_name = "VOXELS", default_value_t = 2.0)]
    pub center_radius: f64,
    /// When the voxel solid is not one genus-0 piece: repair it (drop specks, cut or
    /// fill handles with as few voxel changes as possible, and report them) or refuse
    /// (strict). auto: repair, except a mesh whose own surface has handles (refused
    /// unless --topology repair is given).
    #[arg(long, value_enum, value_name = "MODE", default_value_t = TopologyArg::Auto)]
    pub topology: TopologyArg,
    /// Go on with the raw solid when it has handles (genus > 0) or several pieces (no
    /// repair).
    #[arg(long)]
    pub allow_genus: bool,
    /// Keep only the largest piece of the solid.
    #[arg(long)]
    pub keep_largest: bool,
    /// Close the solid by a ball of this radius (morphological closing) before the
    /// topology check: plugs tunnels and gaps narrower than about twice it. When the
    /// genus is above 0, harmap reports where a closing would plug handles.
    #[arg(long, value_name = "VOXELS", default_value_t = 0)]
    pub close: u32,
    /// Unit of the input coordinates, written to the OME-Zarr metadata (e.g. millimeter,
    /// micrometer, angstrom).
    #[arg(long)]
    pub unit: Option<String>,
    /// Block (chunk) edge in voxels.
    #[arg(long, value_name = "VOXELS", default_value_t = 64)]
    pub chunk: u64,
    /// Memory budget: peak resident memory of the run (e.g. 256MiB, 2GiB).
    #[arg(long, value_name = "SIZE", default_value = "1GiB")]
    pub mem: MemBudget,
    /// Where the intermediate solid grid lives: auto (memory when it fits in half of
    /// --mem), memory, or disk (a scratch file in the run directory).
    #[arg(long, value_enum, default_value_t = ScratchArg::Auto)]
    pub scratch: ScratchArg,
    /// Shape of a .raw label volume, z,y,x.
    #[arg(long, value_name = "Z,Y,X", value_parser = parse_shape)]
    pub raw_shape: Option<[u64; 3]>,
    /// Element type of a .raw label volume: u8, u16, i16, u32, i32, f32, f64.
    #[arg(long, value_name = "DTYPE")]
    pub raw_dtype: Option<RawDtype>,
    /// Molecules: the solid, from the atoms' balls: vdw (their union), sas (grown by the
    /// probe) or ses (solvent-excluded: what no probe ball in the solvent reaches).
    #[arg(long, value_enum, default_value_t = SurfaceArg::Ses, help_heading = "Molecules and point sets")]
    pub surface: SurfaceArg,
    /// Molecules: probe radius of sas and ses, Angstrom. Several radii (1.4,2,3) are
    /// tried in turn until the solid is one genus-0 piece; the summary says which one
    /// made it so (the last is kept either way, and --allow-genus decides then).
    #[arg(
        long,
        value_name = "A[,A...]",
        value_delimiter = ',',
        num_args = 1..,
        default_values_t = [1.4],
        help_heading = "Molecules and point sets"
    )]
    pub probe: Vec<f64>,
    /// PDB and mmCIF: the model to read [default: the first].
    #[arg(long, value_name = "N", help_heading = "Molecules and point sets")]
    pub model: Option<u32>,
    /// Keep hetero groups (ligands, ions) other than water.
    #[arg(long, help_heading = "Molecules and point sets")]
    pub keep_hetatm: bool,
    /// Point sets (.csv of x,y,z, or any atom file): one radius for every point.
    #[arg(long, value_name = "R", help_heading = "Molecules and point sets")]
    pub radius: Option<f64>,
}

/// `--surface` values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum SurfaceArg {
    /// Union of van der Waals balls.
    Vdw,
    /// Solvent-accessible: balls grown by the probe.
    Sas,
    /// Solvent-excluded (molecular) surface.
    Ses,
}

/// `--topology` values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum TopologyArg {
    /// Repair, except a mesh whose own surface has handles (refused, as strict).
    Auto,
    /// Make the solid one genus-0 piece, reporting every change.
    Repair,
    /// Refuse a solid that is not one genus-0 piece.
    Strict,
}

/// `--scratch` values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ScratchArg {
    /// Memory when the grid fits in half the budget, else disk.
    Auto,
    /// Always memory.
    Memory,
    /// Always a scratch file.
    Disk,
}

#[allow(clippy::many_single_char_names)] // x, y, z as the user types them
fn parse_point(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|t| t.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("'{s}' is not a point; write it as X,Y,Z"))?;
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok([x, y, z]),
        _ => Err(format!(
            "'{s}' is not a point; write it as X,Y,Z with three finite numbers"
        )),
    }
}

#[allow(clippy::many_single_char_names)] // x, y, z as the user types them
fn parse_shape(s: &str) -> Result<[u64; 3], String> {
    let v: Vec<u64> = s
        .split(',')
        .map(|t| t.trim().parse::<u64>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("'{s}' is not a shape; write it as Z,Y,X"))?;
    match v[..] {
        [z, y, x] => Ok([z, y, x]),
        _ => Err(format!("'{s}' is not a shape; write it as Z,Y,X")),
    }
}

impl VoxelizeArgs {
    /// The library options and input options these flags say.
    pub fn options(&self) -> anyhow::Result<(VoxelizeOptions, InputOptions)> {
        let raw = match (self.raw_shape, self.raw_dtype) {
            (Some(shape), Some(dtype)) => Some(RawSpec { shape, dtype }),
            (None, None) => None,
            _ => return Err(UsageError("--raw-shape and --raw-dtype go together".into()).into()),
        };
        Ok((
            VoxelizeOptions {
                resolution: self.resolution,
                spacing: self.spacing,
                padding: self.padding,
                center: self.center,
                center_radius: self.center_radius,
                allow_genus: self.allow_genus,
                keep_largest: self.keep_largest,
                chunk: self.chunk,
                mem: self.mem,
                unit: self.unit.clone(),
                scratch: match self.scratch {
                    ScratchArg::Auto => Scratch::Auto,
                    ScratchArg::Memory => Scratch::Memory,
                    ScratchArg::Disk => Scratch::Disk,
                },
                surface: match self.surface {
                    SurfaceArg::Vdw => MolSurface::Vdw,
                    SurfaceArg::Sas => MolSurface::Sas,
                    SurfaceArg::Ses => MolSurface::Ses,
                },
                probe: self.probe[0],
                close: self.close,
                probe_ladder: self.probe[1..].to_vec(),
                skip_handle_search: false,
                topology: match self.topology {
                    TopologyArg::Auto => TopologyMode::Auto,
                    TopologyArg::Repair => TopologyMode::Repair,
                    TopologyArg::Strict => TopologyMode::Strict,
                },
            },
            InputOptions {
                raw,
                molecule: MoleculeOptions {
                    model: self.model,
                    keep_hetatm: self.keep_hetatm,
                    radius: self.radius,
                },
                mem: Some(self.mem),
            },
        ))
    }
}

/// Run `harmap voxelize`.
pub fn run(a: &Args, g: &Global) -> anyhow::Result<()> {
    let (opts, iopts) = a.opts.options()?;
    let bars = Bars::new(g);
    let source = Source::File(&a.input, &iopts);
    // On MPI ranks every rank computes its slab of the solid; rank 0 does the rest
    // (and writes the run) while the others wait.
    let world = harmap::grid::world();
    if !world.is_root() {
        serve_voxelize(&source, &bars, world)
            .with_context(|| format!("voxelizing {}", a.input.display()))?;
        world.barrier()?;
        return Ok(());
    }
    let done = harmap::grid::solo(|| {
        voxelize_new_run_on(&source, &opts, &a.output, a.force, &bars, world)
    });
    let (run, r) = done.with_context(|| format!("voxelizing {}", a.input.display()))?;
    world.barrier()?;
    let s = r.grid.shape;
    g.say(&format!(
        "{}: {} x {} x {} voxels of {:.6} ({} solid), center ({:.4}, {:.4}, {:.4}) at depth {:.1} voxels, genus {}",
        run.root().display(),
        s[2],
        s[1],
        s[0],
        r.grid.spacing,
        r.counts[1] + r.counts[2] + r.counts[3],
        r.center[0],
        r.center[1],
        r.center[2],
        r.center_depth,
        r.genus
    ));
    if let Some(p) = r.probe_summary() {
        g.say(&format!("probe: {p}"));
    }
    if let Some(rep) = &r.repair {
        g.say(&format!("topology repair: {}", repair_summary(rep)));
    }
    if r.closing_voxels > 0 {
        g.say(&format!(
            "closing by {} voxels added {} voxels",
            opts.close, r.closing_voxels
        ));
    }
    if g.verbosity > 1 {
        for (n, c) in NAMES.iter().zip(r.counts) {
            g.say(&format!("  {n:>9}: {c}"));
        }
    }
    Ok(())
}
