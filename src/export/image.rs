//! Image exports of the run's fields, written slab by slab (never the whole grid in
//! memory): NIfTI-1 (`.nii`, `.nii.gz`) for neuroimaging tools, VTK XML image data
//! (`.vti`) for ParaView, and OpenDX (`.dx`) for APBS, VMD and PyMOL.
//!
//! The writers are small and hand-written on purpose: the crates for these formats
//! (`nifti`, `vtkio`) take a whole in-memory array, which a 10^9-voxel field is not.
//! Layouts follow the format documents: the NIfTI-1 header of nifti1.h (348 bytes, then
//! a 4-byte extension flag, data at byte 352, x fastest); VTK's XML file formats
//! (ImageData, appended raw data with UInt64 size headers); and the OpenDX field as
//! APBS writes it (counts nx ny nz, z fastest).

use std::fmt::Write as _;
use std::io::Write;
use std::path::Path;

use super::{ExportError, Staged};
use crate::grid::{BlockStore, GridError, GridSpec, MemBudget};
use crate::progress::Progress;
use crate::run::RunDir;

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

    fn bytes(self) -> usize {
        match self {
            Field::Phi => 8,
            Field::Theta | Field::Psi => 4,
            Field::Labels => 1,
        }
    }

    fn stage(self) -> &'static str {
        match self {
            Field::Phi => "solve",
            Field::Theta | Field::Psi => "map",
            Field::Labels => "voxelize",
        }
    }
}

/// One field opened for reading, whatever its type.
enum Source {
    F64(crate::grid::ZarrStore<f64>),
    F32(crate::grid::ZarrStore<f32>),
    /// theta or psi of the exact map, stored in f64, exported in f32 like the upwind
    /// map's.
    F64AsF32(crate::grid::ZarrStore<f64>),
    U8(crate::grid::ZarrStore<u8>),
}

impl Source {
    fn open(run: &RunDir, f: Field) -> Result<Self, crate::Error> {
        run.refuse_stale(f.stage())?;
        if run.require_stage(f.stage()).is_err() || !run.root().join(f.name()).exists() {
            return Err(ExportError::Unavailable(format!(
                "{}: the run has no {} yet; run `harmap {}` first",
                run.root().display(),
                f.name(),
                f.stage()
            ))
            .into());
        }
        Ok(match f {
            Field::Phi => Source::F64(run.open_image(f.name())?),
            // The upwind map stores f32, the exact map f64 (docs/format.md).
            Field::Theta | Field::Psi => {
                if run.image_data_type(f.name())? == "float64" {
                    Source::F64AsF32(run.open_image(f.name())?)
                } else {
                    Source::F32(run.open_image(f.name())?)
                }
            }
            Field::Labels => Source::U8(run.open_image(f.name())?),
        })
    }

    /// Voxels `z0..z0 + nz` of every row as little-endian bytes, C order (x fastest).
    fn z_slab(&self, spec: &GridSpec, bz: u64) -> Result<Vec<u8>, GridError> {
        fn slab<T: crate::grid::Scalar>(
            s: &dyn BlockStore<T>,
            spec: &GridSpec,
            bz: u64,
        ) -> Result<Vec<u8>, GridError> {
            let z0 = bz * spec.chunk[0];
            let nz = spec.block_shape([bz, 0, 0])[0] as usize;
            let (ny, nx) = (spec.shape[1] as usize, spec.shape[2] as usize);
            let region = s.read_region([z0 as i64, 0, 0], [nz, ny, nx], fill::<T>())?;
            let mut out = vec![0u8; region.data.len() * T::SIZE];
            for (v, o) in region.data.iter().zip(out.chunks_exact_mut(T::SIZE)) {
                v.write_le(o);
            }
            Ok(out)
        }
        match self {
            Source::F64(s) => slab(s, spec, bz),
            Source::F32(s) => slab(s, spec, bz),
            Source::F64AsF32(s) => {
                let wide = slab(s, spec, bz)?;
                Ok(wide
                    .chunks_exact(8)
                    .flat_map(|b| (<f64 as crate::grid::Scalar>::read_le(b) as f32).to_le_bytes())
                    .collect())
            }
            Source::U8(s) => slab(s, spec, bz),
        }
    }

    /// Voxels `x0..x0 + w` as text values in the order x, y, z (z fastest).
    fn x_slab_text(&self, spec: &GridSpec, x0: u64, w: u64) -> Result<Vec<String>, GridError> {
        fn slab<T: crate::grid::Scalar>(
            s: &dyn BlockStore<T>,
            spec: &GridSpec,
            x0: u64,
            w: u64,
            text: impl Fn(T) -> String,
        ) -> Result<Vec<String>, GridError> {
            let (nz, ny) = (spec.shape[0] as usize, spec.shape[1] as usize);
            let w = w as usize;
            let region = s.read_region([0, 0, x0 as i64], [nz, ny, w], fill::<T>())?;
            let mut out = Vec::with_capacity(region.data.len());
            for x in 0..w {
                for y in 0..ny {
                    for z in 0..nz {
                        out.push(text(region.data[(z * ny + y) * w + x]));
                    }
                }
            }
            Ok(out)
        }
        match self {
            Source::F64(s) => slab(s, spec, x0, w, |v| g(v, 12)),
            Source::F32(s) => slab(s, spec, x0, w, |v| g(f64::from(v), 8)),
            Source::F64AsF32(s) => slab(s, spec, x0, w, |v| g(f64::from(v as f32), 8)),
            Source::U8(s) => slab(s, spec, x0, w, |v| v.to_string()),
        }
    }
}

/// The fill value of `T` for voxels off the grid (never asked for here).
fn fill<T: crate::grid::Scalar>() -> T {
    T::read_le(&vec![0u8; T::SIZE])
}

/// `v` with `digits` significant digits, as C's %g would (nan for NaN).
fn g(v: f64, digits: usize) -> String {
    if v.is_nan() {
        return "nan".into();
    }
    if v == 0.0 {
        return "0".into();
    }
    let e = v.abs().log10().floor() as i32;
    if (-5..digits as i32).contains(&e) {
        let decimals = (digits as i32 - 1 - e).max(0) as usize;
        let s = format!("{v:.decimals$}");
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_owned()
        } else {
            s
        }
    } else {
        format!("{v:.prec$e}", prec = digits - 1)
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
    let n = spec.num_voxels();
    match format {
        ImageFormat::Nifti => {
            let gz = dest.extension().is_some_and(|e| e == "gz");
            let header = nifti_header(&spec, fields[0], run);
            if gz {
                let mut enc =
                    flate2::write::GzEncoder::new(&mut out.out, flate2::Compression::fast());
                enc.write_all(&header).map_err(|e| ExportError::Io {
                    path: dest.to_owned(),
                    source: e,
                })?;
                write_z_slabs(&sources[0], &spec, &mut enc, dest, progress)?;
                enc.finish().map_err(|e| ExportError::Io {
                    path: dest.to_owned(),
                    source: e,
                })?;
            } else {
                out.out.write_all(&header).map_err(|e| out.io(e))?;
                write_z_slabs(&sources[0], &spec, &mut out.out, dest, progress)?;
            }
        }
        ImageFormat::Vti => {
            let s = spec.shape;
            let mut xml = String::new();
            xml.push_str("<?xml version=\"1.0\"?>\n");
            xml.push_str("<VTKFile type=\"ImageData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n");
            let extent = format!("0 {} 0 {} 0 {}", s[2] - 1, s[1] - 1, s[0] - 1);
            let _ = writeln!(xml,
                "  <ImageData WholeExtent=\"{extent}\" Origin=\"{} {} {}\" Spacing=\"{h} {h} {h}\">",
                spec.origin[0],
                spec.origin[1],
                spec.origin[2],
                h = spec.spacing
            );
            let _ = writeln!(xml, "    <Piece Extent=\"{extent}\">");
            let _ = writeln!(xml, "      <PointData Scalars=\"{}\">", fields[0].name());
            let mut offset = 0u64;
            for f in fields {
                let ty = match f.bytes() {
                    8 => "Float64",
                    4 => "Float32",
                    _ => "UInt8",
                };
                let _ = writeln!(xml,
                    "        <DataArray type=\"{ty}\" Name=\"{}\" format=\"appended\" offset=\"{offset}\"/>",
                    f.name()
                );
                offset += 8 + n * f.bytes() as u64;
            }
            xml.push_str("      </PointData>\n    </Piece>\n  </ImageData>\n  <AppendedData encoding=\"raw\">\n   _");
            out.out.write_all(xml.as_bytes()).map_err(|e| out.io(e))?;
            for (f, src) in fields.iter().zip(&sources) {
                let bytes = n * f.bytes() as u64;
                out.out
                    .write_all(&bytes.to_le_bytes())
                    .map_err(|e| out.io(e))?;
                write_z_slabs(src, &spec, &mut out.out, dest, progress)?;
            }
            out.out
                .write_all(b"\n  </AppendedData>\n</VTKFile>\n")
                .map_err(|e| out.io(e))?;
        }
        ImageFormat::Dx => {
            let s = spec.shape;
            let o = spec.origin;
            let h = spec.spacing;
            let head = format!(
                "# {} of {} (harmap)\n\
                 object 1 class gridpositions counts {nx} {ny} {nz}\n\
                 origin {} {} {}\n\
                 delta {h} 0 0\ndelta 0 {h} 0\ndelta 0 0 {h}\n\
                 object 2 class gridconnections counts {nx} {ny} {nz}\n\
                 object 3 class array type double rank 0 items {n} data follows\n",
                fields[0].name(),
                run.root().display(),
                o[0],
                o[1],
                o[2],
                nx = s[2],
                ny = s[1],
                nz = s[0],
            );
            out.out.write_all(head.as_bytes()).map_err(|e| out.io(e))?;
            // x slowest: planes of constant x, as many as half the budget holds.
            let per_x = s[0] * s[1] * 40;
            let w = (mem.work_bytes() / 2 / per_x.max(1)).clamp(1, spec.chunk[2]);
            progress.start(&format!("export {}", fields[0].name()), s[2]);
            let mut col = 0;
            let mut x0 = 0;
            while x0 < s[2] {
                let wx = w.min(s[2] - x0);
                let vals = sources[0].x_slab_text(&spec, x0, wx)?;
                let mut buf = String::with_capacity(vals.len() * 14);
                for v in vals {
                    buf.push_str(&v);
                    col += 1;
                    buf.push(if col % 3 == 0 { '\n' } else { ' ' });
                }
                out.out.write_all(buf.as_bytes()).map_err(|e| out.io(e))?;
                x0 += wx;
                progress.advance(wx);
            }
            progress.finish();
            let tail = format!(
                "{}attribute \"dep\" string \"positions\"\n\
                 object \"{}\" class field\n\
                 component \"positions\" value 1\n\
                 component \"connections\" value 2\n\
                 component \"data\" value 3\n",
                if col % 3 == 0 { "" } else { "\n" },
                fields[0].name()
            );
            out.out.write_all(tail.as_bytes()).map_err(|e| out.io(e))?;
        }
    }
    out.commit()?;
    Ok(n)
}

fn write_z_slabs(
    src: &Source,
    spec: &GridSpec,
    w: &mut dyn Write,
    dest: &Path,
    progress: &dyn Progress,
) -> Result<(), crate::Error> {
    let nb = spec.blocks()[0];
    progress.start("export", nb);
    for bz in 0..nb {
        let bytes = src.z_slab(spec, bz)?;
        w.write_all(&bytes).map_err(|e| ExportError::Io {
            path: dest.to_owned(),
            source: e,
        })?;
        progress.advance(1);
    }
    progress.finish();
    Ok(())
}

/// The 352 bytes before the data: the NIfTI-1 header (nifti1.h) and an empty extension
/// flag. The affine maps voxel (i, j, k) to origin + spacing * (i, j, k), in both the
/// qform (identity rotation) and the sform.
fn nifti_header(spec: &GridSpec, f: Field, run: &RunDir) -> Vec<u8> {
    let mut h = vec![0u8; 352];
    let put_i16 =
        |h: &mut Vec<u8>, at: usize, v: i16| h[at..at + 2].copy_from_slice(&v.to_le_bytes());
    let put_f32 =
        |h: &mut Vec<u8>, at: usize, v: f32| h[at..at + 4].copy_from_slice(&v.to_le_bytes());
    h[0..4].copy_from_slice(&348i32.to_le_bytes());
    h[38] = b'r';
    let s = spec.shape;
    for (k, v) in [3, s[2], s[1], s[0], 1, 1, 1, 1].into_iter().enumerate() {
        put_i16(&mut h, 40 + 2 * k, v as i16);
    }
    let (datatype, bitpix) = match f.bytes() {
        8 => (64, 64),
        4 => (16, 32),
        _ => (2, 8),
    };
    put_i16(&mut h, 70, datatype);
    put_i16(&mut h, 72, bitpix);
    let sp = spec.spacing as f32;
    for (k, v) in [1.0, sp, sp, sp, 1.0, 1.0, 1.0, 1.0]
        .into_iter()
        .enumerate()
    {
        put_f32(&mut h, 76 + 4 * k, v);
    }
    put_f32(&mut h, 108, 352.0); // vox_offset
    put_f32(&mut h, 112, 1.0); // scl_slope
    h[123] = match spec.unit.as_deref() {
        Some("m" | "meter") => 1,
        Some("mm" | "millimeter") => 2,
        Some("um" | "micron" | "micrometer") => 3,
        _ => 0,
    };
    let descrip = format!("harmap {} of {}", f.name(), run.root().display());
    let d = descrip.as_bytes();
    let len = d.len().min(79);
    h[148..148 + len].copy_from_slice(&d[..len]);
    put_i16(&mut h, 252, 1); // qform_code: scanner
    put_i16(&mut h, 254, 1); // sform_code: scanner
    let o = spec.origin;
    put_f32(&mut h, 268, o[0] as f32);
    put_f32(&mut h, 272, o[1] as f32);
    put_f32(&mut h, 276, o[2] as f32);
    for (row, &o_row) in o.iter().enumerate() {
        for col in 0..3 {
            let v = if row == col { sp } else { 0.0 };
            put_f32(&mut h, 280 + 16 * row + 4 * col, v);
        }
        put_f32(&mut h, 280 + 16 * row + 12, o_row as f32);
    }
    let name = f.name().as_bytes();
    h[328..328 + name.len()].copy_from_slice(name);
    h[344..348].copy_from_slice(b"n+1\0");
    h
}

/// Copy the image groups of `fields` (OME-Zarr 0.5, as stored in the run) into a new
/// Zarr v3 group at `dest`, checking each one's metadata first. Built under a temporary
/// name and renamed when whole. Returns the number of images.
pub fn export_ome_zarr(run: &RunDir, fields: &[Field], dest: &Path) -> Result<u64, crate::Error> {
    let spec = run.grid()?;
    for &f in fields {
        Source::open(run, f)?;
        let meta = run.root().join(f.name()).join("zarr.json");
        let doc: serde_json::Value = std::fs::read(&meta)
            .ok()
            .and_then(|b| serde_json::from_slice(&b).ok())
            .unwrap_or_default();
        let ome = doc.pointer("/attributes/ome").cloned().unwrap_or_default();
        if ome != crate::run::ome_multiscales(f.name(), &spec) {
            return Err(ExportError::Unavailable(format!(
                "{}: the OME-Zarr metadata is not the one harmap writes for this grid",
                meta.display()
            ))
            .into());
        }
    }
    let io = |p: &Path| {
        let p = p.to_owned();
        move |e: std::io::Error| ExportError::Io { path: p, source: e }
    };
    let name = dest
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dest.with_file_name(format!(".{name}.partial-{}", std::process::id()));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(io(&tmp))?;
    }
    std::fs::create_dir_all(&tmp).map_err(io(&tmp))?;
    let result = (|| -> Result<(), crate::Error> {
        let doc = serde_json::json!({
            "zarr_format": 3,
            "node_type": "group",
            "attributes": {"harmap_export": {
                "run": run.root().display().to_string(),
                "images": fields.iter().map(|f| f.name()).collect::<Vec<_>>(),
                "grid": spec,
            }}
        });
        std::fs::write(
            tmp.join("zarr.json"),
            serde_json::to_string_pretty(&doc).expect("json"),
        )
        .map_err(io(&tmp))?;
        for f in fields {
            copy_tree(&run.root().join(f.name()), &tmp.join(f.name()))?;
        }
        if dest.exists() {
            std::fs::remove_dir_all(dest).map_err(io(dest))?;
        }
        std::fs::rename(&tmp, dest).map_err(io(dest))?;
        Ok(())
    })();
    if result.is_err() {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    result?;
    Ok(fields.len() as u64)
}

fn copy_tree(from: &Path, to: &Path) -> Result<(), ExportError> {
    let io = |p: &Path| {
        let p = p.to_owned();
        move |e: std::io::Error| ExportError::Io { path: p, source: e }
    };
    std::fs::create_dir_all(to).map_err(io(to))?;
    for e in std::fs::read_dir(from).map_err(io(from))? {
        let e = e.map_err(io(from))?;
        let dest = to.join(e.file_name());
        if e.file_type().map_err(io(&e.path()))?.is_dir() {
            copy_tree(&e.path(), &dest)?;
        } else {
            std::fs::copy(e.path(), &dest).map_err(io(&dest))?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn g_formats_like_printf() {
        assert_eq!(g(0.5, 8), "0.5");
        assert_eq!(g(1.0, 12), "1");
        assert_eq!(g(0.999_999_999_87, 12), "0.99999999987");
        assert_eq!(g(-2.5e-9, 8), "-2.5000000e-9");
        assert_eq!(g(f64::NAN, 8), "nan");
        assert_eq!(g(123_456.0, 8), "123456");
    }
}
