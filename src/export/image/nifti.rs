//! NIfTI-1 single file (`.nii`, or `.nii.gz` gzip-compressed): the header of nifti1.h
//! (348 bytes, then a 4-byte extension flag, data at byte 352, x fastest), with the
//! affine that puts each voxel at its world position. The header's `descrip` starts with
//! `harmap `, which marks the file as harmap's own export.
// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

use std::io::Write;
use std::path::Path;

use super::source::{write_z_slabs, Source};
use super::Field;
use crate::export::{ExportError, Staged};
use crate::grid::GridSpec;
use crate::progress::Progress;
use crate::run::RunDir;

/// Write `field` of `run` (opened as `src`) to `out`, gzip-compressed when `dest` ends in
/// `.gz`.
pub(super) fn write(
    out: &mut Staged,
    run: &RunDir,
    spec: &GridSpec,
    field: Field,
    src: &Source,
    dest: &Path,
    progress: &dyn Progress,
) -> Result<(), crate::Error> {
    let gz = dest.extension().is_some_and(|e| e == "gz");
    let header = nifti_header(spec, field, run);
    if gz {
        let mut enc = flate2::write::GzEncoder::new(&mut out.out, flate2::Compression::fast());
        enc.write_all(&header).map_err(|e| ExportError::Io {
            path: dest.to_owned(),
            source: e,
        })?;
        write_z_slabs(src, spec, &mut enc, dest, progress)?;
        enc.finish().map_err(|e| ExportError::Io {
            path: dest.to_owned(),
            source: e,
        })?;
    } else {
        out.out.write_all(&header).map_err(|e| out.io(e))?;
        write_z_slabs(src, spec, &mut out.out, dest, progress)?;
    }
    Ok(())
}

/// The 352 bytes before the data: the NIfTI-1 header (nifti1.h) and an empty extension
/// flag. The affine maps voxel (i, j, k) to origin + spacing * (i, j, k), in both the
/// qform (identity rotation) and the sform.
pub(super) fn nifti_header(spec: &GridSpec, f: Field, run: &RunDir) -> Vec<u8> {
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

/// Whether the file at `path` is a NIfTI-1 file harmap wrote (gzip-compressed or not):
/// its `descrip` starts with `harmap ` and its magic is `n+1`.
pub(super) fn is_own(path: &Path) -> bool {
    use std::io::Read;
    let Ok(f) = std::fs::File::open(path) else {
        return false;
    };
    let mut raw = std::io::BufReader::new(f);
    let mut magic = [0u8; 2];
    if raw.read_exact(&mut magic).is_err() {
        return false;
    }
    let mut h = vec![0u8; 352];
    let rest = std::io::Cursor::new(magic).chain(raw);
    let ok = if magic == [0x1f, 0x8b] {
        flate2::read::GzDecoder::new(rest)
            .read_exact(&mut h)
            .is_ok()
    } else {
        rest.take(352).read_exact(&mut h).is_ok()
    };
    ok && h[148..155] == *b"harmap " && h[344..348] == *b"n+1\0"
}
