//! Image exports of the run's fields, written slab by slab (never the whole grid in
//! memory): NIfTI-1 (`.nii`, `.nii.gz`, [`nifti`]) for neuroimaging tools, VTK XML image
//! data (`.vti`, [`vti`]) for ParaView, OpenDX (`.dx`, [`dx`]) for APBS, VMD and PyMOL,
//! and OME-Zarr ([`ome_zarr`]) for napari. One writer per file; [`source`] reads the
//! fields.
//!
//! The writers are small and hand-written on purpose: the crates for these formats
//! (`nifti`, `vtkio`) take a whole in-memory array, which a 10^9-voxel field is not.
//! Layouts follow the format documents: the NIfTI-1 header of nifti1.h (348 bytes, then
//! a 4-byte extension flag, data at byte 352, x fastest); VTK's XML file formats
//! (ImageData, appended raw data with UInt64 size headers); and the OpenDX field as
//! APBS writes it (counts nx ny nz, z fastest).

mod dx;
mod nifti;
mod ome_zarr;
mod source;
mod vti;

use std::path::Path;

pub use ome_zarr::export_ome_zarr;

use super::{ExportError, Staged};
use crate::grid::{GridError, MemBudget};
use crate::progress::Progress;
use crate::run::RunDir;
use source::Source;

/// The image formats.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageFormat {
    /// NIfTI-1 single file; gzip-compressed when the name ends in `.gz`.
    Nifti,
    /// VTK XML image data, every field as point data.
    Vti,
    /// OpenDX scalar field (text).
    Dx,
}

/// A field of the run and its stored element type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Field {
    /// The potential (f64).
    Phi,
    /// Polar angle of arrival (f32 radians).
    Theta,
    /// Azimuth of arrival (f32 radians).
    Psi,
    /// Voxel labels (u8).
    Labels,
}

impl Field {
    /// Every field, in export order.
    pub const ALL: [Field; 4] = [Field::Phi, Field::Theta, Field::Psi, Field::Labels];

    /// The image name in the run.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Field::Phi => "phi",
            Field::Theta => "theta",
            Field::Psi => "psi",
            Field::Labels => "labels",
        }
    }

    pub(crate) fn bytes(self) -> usize {
        match self {
            Field::Phi => 8,
            Field::Theta | Field::Psi => 4,
            Field::Labels => 1,
        }
    }

    pub(crate) fn stage(self) -> &'static str {
        match self {
            Field::Phi => "solve",
            Field::Theta | Field::Psi => "map",
            Field::Labels => "voxelize",
        }
    }
}

/// Write `fields` of `run` to `dest` in `format`. NIfTI and DX hold one field; VTI holds
/// them all as point data. Returns the voxels written per field.
pub fn export_image(
    run: &RunDir,
    format: ImageFormat,
    fields: &[Field],
    dest: &Path,
    mem: MemBudget,
    progress: &dyn Progress,
) -> Result<u64, crate::Error> {
    if fields.is_empty() {
        return Err(ExportError::Unavailable("no field to export".into()).into());
    }
    if format != ImageFormat::Vti && fields.len() != 1 {
        return Err(ExportError::Unavailable(format!(
            "{format:?} holds one field; choose it with --field"
        ))
        .into());
    }
    let spec = run.grid()?;
    let sources = fields
        .iter()
        .map(|&f| Source::open(run, f))
        .collect::<Result<Vec<_>, _>>()?;
    // The slab a writer holds: one chunk row of planes (decoded chunks and the bytes).
    let widest = fields.iter().map(|f| f.bytes()).max().unwrap_or(8) as u64;
    let slab = spec.chunk[0] * spec.shape[1] * spec.shape[2] * (widest + 8);
    if format != ImageFormat::Dx && slab > mem.work_bytes() {
        return Err(GridError::Budget {
            budget: mem.to_string(),
            what: format!("exporting {format:?} (a slab of {} planes)", spec.chunk[0]),
            needed: crate::grid::human(slab + crate::grid::BASE_BYTES),
            suggest: crate::grid::human((slab + crate::grid::BASE_BYTES).next_power_of_two()),
        }
        .into());
    }
    let mut out = Staged::create(dest)?;
    match format {
        ImageFormat::Nifti => {
            nifti::write(&mut out, run, &spec, fields[0], &sources[0], dest, progress)?;
        }
        ImageFormat::Vti => vti::write(&mut out, &spec, fields, &sources, dest, progress)?,
        ImageFormat::Dx => {
            dx::write(&mut out, run, &spec, fields[0], &sources[0], mem, progress)?;
        }
    }
    out.commit()?;
    Ok(spec.num_voxels())
}

/// Whether the file at `path` is harmap's own export in `format` (its marker, read from
/// its first bytes): an export may replace its own earlier output without `--force`.
#[must_use]
pub fn is_own_image(path: &Path, format: ImageFormat) -> bool {
    match format {
        ImageFormat::Nifti => nifti::is_own(path),
        ImageFormat::Vti => crate::export::marks::starts_with_line(path, 1, vti::MARK),
        ImageFormat::Dx => crate::export::marks::first_line(path)
            .is_some_and(|l| l.starts_with("# ") && l.ends_with("(harmap)")),
    }
}
