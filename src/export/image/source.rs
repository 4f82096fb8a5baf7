//! One field of a run opened for reading whatever its stored type, read in slabs: planes
//! of constant z as little-endian bytes (NIfTI, VTI) or columns of constant x as text
//! (OpenDX).

use std::io::Write;
use std::path::Path;

use super::Field;
use crate::export::ExportError;
use crate::grid::{BlockStore, GridError, GridSpec};
use crate::progress::Progress;
use crate::run::RunDir;

/// One field opened for reading, whatever its type.
pub(super) enum Source {
    F64(crate::grid::ZarrStore<f64>),
    F32(crate::grid::ZarrStore<f32>),
    /// theta or psi of the exact map, stored in f64, exported in f32 like the upwind
    /// map's.
    F64AsF32(crate::grid::ZarrStore<f64>),
    U8(crate::grid::ZarrStore<u8>),
}

impl Source {
    pub(super) fn open(run: &RunDir, f: Field) -> Result<Self, crate::Error> {
        run.refuse_stale(f.stage())?;
        if run.require_stage(f.stage()).is_err() || !run.has_image(f.name()) {
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
    pub(super) fn z_slab(&self, spec: &GridSpec, bz: u64) -> Result<Vec<u8>, GridError> {
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
    pub(super) fn x_slab_text(
        &self,
        spec: &GridSpec,
        x0: u64,
        w: u64,
    ) -> Result<Vec<String>, GridError> {
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

/// Write every z slab of `src` to `w` in order (the data of NIfTI and VTI).
pub(super) fn write_z_slabs(
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
