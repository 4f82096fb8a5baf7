//! Exports of a run's results for other tools: the seed table as CSV ([`seeds_csv`]), the
//! boundary -> sphere map as an OBJ mesh ([`obj_sphere`](mod@obj_sphere)), the streamlines as VTK legacy
//! polydata ([`vtk_streamlines`]), and the fields as images ([`image`]: NIfTI-1, VTK
//! image data, OpenDX, OME-Zarr).
//!
//! Safety rules ([`check_target`]): an export never destroys what it did not create. It
//! writes over an existing path only when that path is its own earlier output of the
//! same format (each format carries a mark: a header line, NIfTI's `descrip`, the
//! OME-Zarr group's `harmap_export` attribute) or, with `force`, a file or an empty
//! folder; never a run directory, a non-empty folder it did not write, or a file of a
//! run. A path inside a run directory is refused unless `force`.
//!
//! Every export is written to a temporary name next to the destination
//! (`.NAME.partial-PID`) and renamed when whole, so a killed export never leaves a
//! truncated file under the real name; the next export to the same destination removes
//! the temporary files of exports whose process is gone.

mod csv;
pub mod image;
mod marks;
mod obj_sphere;
mod safety;
mod staged;
mod streamlines;

use std::path::PathBuf;

pub use csv::seeds_csv;
pub use obj_sphere::obj_sphere;
pub use safety::{check_target, is_own_output, ExportKind};
pub(crate) use staged::Staged;
pub use streamlines::vtk_streamlines;

/// Errors of exports.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The run lacks what the format needs, or the options cannot work.
    #[error("{0}")]
    Unavailable(String),
    /// The destination is not the export's to write over (a run, a folder or a file it
    /// did not write): choose another path, or `--force` where the message allows it.
    #[error("{0}")]
    Refused(String),
    /// Writing failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
}
