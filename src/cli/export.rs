//! `harmap export`.

use std::path::PathBuf;

use harmap::export::image::{export_image, export_ome_zarr, Field, ImageFormat};
use harmap::export::{check_target, ExportKind};
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
///   obj-sphere       the seeds' surface (the input mesh, or the labels' surface
///                    nets) with its vertices moved to the unit sphere at their
///                    arrival directions, (psi, theta) as texture coordinates (needs
///                    `harmap trace --seeds surface`)
///   vtk-streamlines  the streamlines as VTK legacy polydata (binary) for ParaView:
///                    traced again with the options of the run's trace (or --sample N
///                    of its seeds), with cell data seed, stop, theta, psi and point data
///                    arc_length
///   nifti            one field (--field, default phi) as NIfTI-1 (.nii, or .nii.gz
///                    compressed) with the affine that puts each voxel at its world
///                    position (qform and sform); for neuroimaging tools
///   vti              the fields (phi, theta, psi, labels, or --field) as VTK XML image
///                    data, point data on the voxel centers; for ParaView
///   dx               one field (--field, default phi) as an OpenDX scalar grid, as APBS
///                    writes them; for VMD, PyMOL and APBS tools
///   ome-zarr         the fields' OME-Zarr 0.5 image groups (checked, then copied) in a
///                    new Zarr group at PATH; for napari and other OME-Zarr readers
///
/// Image exports are written slab by slab within --mem. NaN marks voxels without a
/// value (outside the solid for theta and psi, outside the solved region for phi).
///
/// The file is written under a temporary name and renamed when whole.
///
/// An export never destroys what it did not create: it replaces an existing PATH only
/// when PATH is its own earlier output of the same format; --force also lets it replace
/// a file or an empty folder, or write a new file inside a run directory. A run
/// directory, a run's files and a non-empty folder harmap did not write are never
/// replaced.
///
/// Examples:
///   harmap export spot.harmap --format csv -o spot-seeds.csv
///   harmap export spot.harmap --format obj-sphere -o spot-sphere.obj
///   harmap export spot.harmap --format vtk-streamlines --sample 2000 -o spot-lines.vtk
///   harmap export spot.harmap --format nifti --field theta -o spot-theta.nii.gz
///   harmap export spot.harmap --format vti -o spot.vti
///   harmap export 1crn.harmap --format dx --field phi -o 1crn-phi.dx
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
    /// Image formats: the field to write (nifti and dx: default phi; vti: default all;
    /// ome-zarr: default all).
    #[arg(long, value_enum)]
    pub field: Option<FieldArg>,
    /// Replace an existing file (or empty folder) that is not this format's earlier
    /// output, or write inside a run directory. Never replaces a run or a non-empty
    /// folder harmap did not write.
    #[arg(long)]
    pub force: bool,
    /// Memory budget (vtk-streamlines traces again; images are written in slabs).
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
    /// One field as NIfTI-1.
    Nifti,
    /// Fields as VTK XML image data.
    Vti,
    /// One field as OpenDX.
    Dx,
    /// Fields as OME-Zarr image groups.
    OmeZarr,
}

/// `--field` values.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum FieldArg {
    /// The potential.
    Phi,
    /// Polar angle of arrival (radians).
    Theta,
    /// Azimuth of arrival (radians).
    Psi,
    /// Voxel labels.
    Labels,
}

impl FieldArg {
    fn field(self) -> Field {
        match self {
            FieldArg::Phi => Field::Phi,
            FieldArg::Theta => Field::Theta,
            FieldArg::Psi => Field::Psi,
            FieldArg::Labels => Field::Labels,
        }
    }
}

/// The fields a multi-field export writes by default: all the run has.
fn available(run: &RunDir) -> Vec<Field> {
    Field::ALL
        .into_iter()
        .filter(|f| run.has_image(f.name()))
        .collect()
}

/// Run `harmap export`.
pub fn run(a: &Args, g: &Global) -> anyhow::Result<()> {
    let run = RunDir::open(&a.run).map_err(harmap::Error::from)?;
    if a.sample.is_some() && !matches!(a.format, Format::VtkStreamlines) {
        return Err(UsageError("--sample applies to --format vtk-streamlines only".into()).into());
    }
    let image = matches!(
        a.format,
        Format::Nifti | Format::Vti | Format::Dx | Format::OmeZarr
    );
    if a.field.is_some() && !image {
        return Err(UsageError(
            "--field applies to the image formats (nifti, vti, dx, ome-zarr)".into(),
        )
        .into());
    }
    let kind = match a.format {
        Format::Csv => ExportKind::Csv,
        Format::ObjSphere => ExportKind::ObjSphere,
        Format::VtkStreamlines => ExportKind::VtkStreamlines,
        Format::Nifti => ExportKind::Image(ImageFormat::Nifti),
        Format::Vti => ExportKind::Image(ImageFormat::Vti),
        Format::Dx => ExportKind::Image(ImageFormat::Dx),
        Format::OmeZarr => ExportKind::OmeZarr,
    };
    check_target(&a.output, kind, a.force).map_err(harmap::Error::from)?;
    let one = a.field.map_or(Field::Phi, FieldArg::field);
    let some = a.field.map_or_else(|| available(&run), |f| vec![f.field()]);
    let (n, what) = match a.format {
        Format::Csv => (harmap::export::seeds_csv(&run, &a.output)?, "seeds"),
        Format::ObjSphere => (harmap::export::obj_sphere(&run, &a.output)?, "triangles"),
        Format::VtkStreamlines => (
            harmap::export::vtk_streamlines(&run, &a.output, a.sample, a.mem, &Bars::new(g))?,
            "streamlines",
        ),
        Format::Nifti | Format::Dx => {
            let fmt = if matches!(a.format, Format::Nifti) {
                ImageFormat::Nifti
            } else {
                ImageFormat::Dx
            };
            let n = export_image(&run, fmt, &[one], &a.output, a.mem, &Bars::new(g))?;
            (n, "voxels")
        }
        Format::Vti => (
            export_image(
                &run,
                ImageFormat::Vti,
                &some,
                &a.output,
                a.mem,
                &Bars::new(g),
            )?,
            "voxels per field",
        ),
        Format::OmeZarr => (export_ome_zarr(&run, &some, &a.output)?, "images"),
    };
    g.say(&format!("{}: {n} {what}", a.output.display()));
    Ok(())
}
