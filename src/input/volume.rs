//! Label volumes that are already voxelized: a Zarr v3 array, or raw bytes.
//! "Anything > 0 is inside." Read block by block, never whole.

use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

use super::{extension, InputError};
use crate::grid::{open_external_array, ExternalArray};

/// Element type of a raw volume.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum RawDtype {
    /// unsigned 8-bit
    U8,
    /// unsigned 16-bit, little endian
    U16,
    /// signed 16-bit, little endian
    I16,
    /// unsigned 32-bit, little endian
    U32,
    /// signed 32-bit, little endian
    I32,
    /// 32-bit float, little endian
    F32,
    /// 64-bit float, little endian
    F64,
}

impl RawDtype {
    /// Bytes per element.
    #[must_use]
    pub fn size(self) -> usize {
        match self {
            RawDtype::U8 => 1,
            RawDtype::U16 | RawDtype::I16 => 2,
            RawDtype::U32 | RawDtype::I32 | RawDtype::F32 => 4,
            RawDtype::F64 => 8,
        }
    }

    /// Whether the little-endian element in `b` is > 0.
    fn positive(self, b: &[u8]) -> bool {
        match self {
            RawDtype::U8 => b[0] > 0,
            RawDtype::U16 => u16::from_le_bytes([b[0], b[1]]) > 0,
            RawDtype::I16 => i16::from_le_bytes([b[0], b[1]]) > 0,
            RawDtype::U32 => u32::from_le_bytes(b[..4].try_into().expect("4 bytes")) > 0,
            RawDtype::I32 => i32::from_le_bytes(b[..4].try_into().expect("4 bytes")) > 0,
            RawDtype::F32 => f32::from_le_bytes(b[..4].try_into().expect("4 bytes")) > 0.0,
            RawDtype::F64 => f64::from_le_bytes(b[..8].try_into().expect("8 bytes")) > 0.0,
        }
    }
}

impl std::str::FromStr for RawDtype {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Ok(match s.to_ascii_lowercase().as_str() {
            "u8" | "uint8" => RawDtype::U8,
            "u16" | "uint16" => RawDtype::U16,
            "i16" | "int16" => RawDtype::I16,
            "u32" | "uint32" => RawDtype::U32,
            "i32" | "int32" => RawDtype::I32,
            "f32" | "float32" => RawDtype::F32,
            "f64" | "float64" => RawDtype::F64,
            _ => {
                return Err(format!(
                    "unknown dtype '{s}'; use u8, u16, i16, u32, i32, f32 or f64"
                ))
            }
        })
    }
}

/// Layout of a raw volume: C order `[z, y, x]`, little endian, no header.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RawSpec {
    /// Elements per axis `[z, y, x]`.
    pub shape: [u64; 3],
    /// Element type.
    pub dtype: RawDtype,
}

enum Source {
    Zarr(Box<ExternalArray>),
    Raw {
        file: File,
        dtype: RawDtype,
        /// The decompressed copy of a `.gz` input, deleted on drop.
        _tmp: Option<tempfile::NamedTempFile>,
    },
}

/// A voxelized solid to read box by box.
pub struct LabelVolume {
    path: PathBuf,
    shape: [u64; 3],
    source: Source,
}

impl std::fmt::Debug for LabelVolume {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LabelVolume")
            .field("path", &self.path)
            .field("shape", &self.shape)
            .finish_non_exhaustive()
    }
}

impl LabelVolume {
    /// Open a Zarr v3 array directory (the directory holding the array's `zarr.json`).
    pub fn open_zarr(path: &Path) -> Result<Self, InputError> {
        let bad = |m: String| InputError::invalid(path, m);
        if !path.join("zarr.json").is_file() {
            return Err(bad(
                "a directory input must be a Zarr v3 array (no zarr.json found in it)".into(),
            ));
        }
        let array = open_external_array(path).map_err(bad)?;
        let shape: [u64; 3] = array.shape().try_into().map_err(|_| {
            bad(format!(
                "a label volume must be 3-D [z, y, x]; this array has shape {:?}",
                array.shape()
            ))
        })?;
        if shape.contains(&0) {
            return Err(bad(format!("the array is empty (shape {shape:?})")));
        }
        Ok(Self {
            path: path.to_owned(),
            shape,
            source: Source::Zarr(Box::new(array)),
        })
    }

    /// Open a raw volume of the given layout. A `.gz` file is decompressed once into a
    /// temporary file in the system temp directory, so that boxes can be
    /// read at random.
    pub fn open_raw(path: &Path, spec: &RawSpec) -> Result<Self, InputError> {
        let (_, gz) = extension(path);
        let (file, tmp) = if gz {
            // A private, unpredictably named file that is removed when dropped.
            let mut tmp = tempfile::NamedTempFile::new()
                .map_err(|e| InputError::io(&std::env::temp_dir(), e))?;
            let src = File::open(path).map_err(|e| InputError::io(path, e))?;
            let mut dec = flate2::read::MultiGzDecoder::new(std::io::BufReader::new(src));
            std::io::copy(&mut dec, tmp.as_file_mut())
                .map_err(|e| InputError::invalid(path, format!("cannot gunzip: {e}")))?;
            let file = tmp.reopen().map_err(|e| InputError::io(tmp.path(), e))?;
            (file, Some(tmp))
        } else {
            (File::open(path).map_err(|e| InputError::io(path, e))?, None)
        };
        let len = file.metadata().map_err(|e| InputError::io(path, e))?.len();
        let want = spec
            .shape
            .iter()
            .try_fold(spec.dtype.size() as u64, |acc, &n| acc.checked_mul(n))
            .unwrap_or(u64::MAX);
        if spec.shape.contains(&0) || len != want {
            return Err(InputError::invalid(
                path,
                format!(
                    "{len} bytes, but --raw-shape {:?} of {:?} needs {want}; check the shape (z,y,x) and dtype",
                    spec.shape, spec.dtype
                ),
            ));
        }
        Ok(Self {
            path: path.to_owned(),
            shape: spec.shape,
            source: Source::Raw {
                file,
                dtype: spec.dtype,
                _tmp: tmp,
            },
        })
    }

    /// Bytes of one decoded chunk of the source (a raw file is read row by row: 0).
    #[must_use]
    pub fn chunk_bytes(&self) -> u64 {
        match &self.source {
            Source::Zarr(a) => a.chunk_bytes(),
            Source::Raw { .. } => 0,
        }
    }

    /// Elements per axis `[z, y, x]`.
    #[must_use]
    pub fn shape(&self) -> [u64; 3] {
        self.shape
    }

    /// Whether each voxel of the box `[start, start + size)` is inside (> 0). The box
    /// must lie within the volume. C order.
    pub fn read_inside(&self, start: [u64; 3], size: [u64; 3]) -> Result<Vec<bool>, InputError> {
        let n = (size[0] * size[1] * size[2]) as usize;
        match &self.source {
            Source::Zarr(array) => {
                let raw = array
                    .read_box(start, size)
                    .map_err(|m| InputError::invalid(&self.path, m))?;
                let dt = array.data_type();
                let es = raw.len() / n.max(1);
                let dtype = zarr_dtype(dt.split_whitespace().next().unwrap_or(""), es).ok_or_else(
                    || {
                        InputError::invalid(
                            &self.path,
                            format!(
                                "unsupported label data type {dt}; use an integer or float type"
                            ),
                        )
                    },
                )?;
                Ok(raw.chunks_exact(es).map(|b| dtype.positive_ne(b)).collect())
            }
            Source::Raw { file, dtype, .. } => {
                let es = dtype.size();
                let mut out = Vec::with_capacity(n);
                let mut row = vec![0u8; size[2] as usize * es];
                for z in 0..size[0] {
                    for y in 0..size[1] {
                        let off = (((start[0] + z) * self.shape[1] + start[1] + y) * self.shape[2]
                            + start[2])
                            * es as u64;
                        file.read_exact_at(&mut row, off)
                            .map_err(|e| InputError::io(&self.path, e))?;
                        out.extend(row.chunks_exact(es).map(|b| dtype.positive(b)));
                    }
                }
                Ok(out)
            }
        }
    }
}

impl RawDtype {
    /// As [`RawDtype::positive`] but native endian (Zarr arrays are read as native-endian bytes).
    fn positive_ne(self, b: &[u8]) -> bool {
        if cfg!(target_endian = "little") {
            self.positive(b)
        } else {
            let mut r = b.to_vec();
            r.reverse();
            self.positive(&r)
        }
    }
}

fn zarr_dtype(name: &str, size: usize) -> Option<RawDtype> {
    let n = name.to_ascii_lowercase();
    Some(match (n.as_str(), size) {
        ("uint8" | "bool", 1) => RawDtype::U8,
        ("uint16", 2) => RawDtype::U16,
        ("int16", 2) => RawDtype::I16,
        ("uint32", 4) => RawDtype::U32,
        ("int32", 4) => RawDtype::I32,
        ("float32", 4) => RawDtype::F32,
        ("float64", 8) => RawDtype::F64,
        _ => return None,
    })
}
