//! Zarr v3 backend (zarrs, filesystem store): the arrays users keep and exchange.
//!
//! Every array is written with `dimension_names` `[z, y, x]` and portable codecs only
//! (bytes, optionally zstd), so zarr-python, tensorstore and napari open it. Chunks equal
//! to the fill value are not written: a missing chunk means "fill", never "not computed".
//! zarrs would run codecs on rayon's pool; our own loops are parallel over blocks, so
//! every call here caps zarrs' concurrency to 1.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use zarrs::array::codec::ZstdCodec;
use zarrs::array::{Array, ArrayBuilder, ArrayBytes, CodecOptions, FillValue};
use zarrs::filesystem::FilesystemStore;

use super::store::check_block;
use super::{BlockStore, GridError, GridSpec, MappedBlock, Scalar};
use crate::math::{volume, Idx3};

/// Compression of a stored array.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Compression {
    /// Raw little-endian bytes (fast; for fields that barely compress).
    None,
    /// zstd at the given level (for labels and exported copies).
    Zstd(i32),
}

/// A 3-D Zarr v3 array on the filesystem, accessed block by block.
pub struct ZarrStore<T> {
    spec: GridSpec,
    array: Array<FilesystemStore>,
    fill: T,
    path: String,
    options: CodecOptions,
    /// Chunks are stored as the values' bytes in memory order ([`BlockStore::map_block`]).
    raw: bool,
    /// The array's data type is T's ([`Scalar::ZARR_DTYPE`]); reads and writes check it.
    typed: bool,
}

fn zerr(path: &str, e: impl std::fmt::Display) -> GridError {
    GridError::Zarr {
        path: path.to_owned(),
        message: e.to_string(),
    }
}

/// Open the filesystem store rooted at `root`.
pub fn fs_store(root: &Path) -> Result<Arc<FilesystemStore>, GridError> {
    FilesystemStore::new(root)
        .map(Arc::new)
        .map_err(|e| GridError::Io {
            path: PathBuf::from(root),
            source: std::io::Error::other(e.to_string()),
        })
}

impl<T: Scalar> ZarrStore<T> {
    /// Create the array at `path` (e.g. `/labels/0`) inside the store rooted at `root`
    /// and write its metadata. `attributes` go into the array's `zarr.json`.
    pub fn create(
        root: &Path,
        path: &str,
        spec: GridSpec,
        fill: T,
        compression: Compression,
        attributes: serde_json::Map<String, serde_json::Value>,
    ) -> Result<Self, GridError> {
        let store = fs_store(root)?;
        let mut builder = ArrayBuilder::new(
            spec.shape.to_vec(),
            spec.chunk.to_vec(),
            T::ZARR_DTYPE,
            fill_value(fill),
        );
        builder
            .dimension_names(Some(["z", "y", "x"]))
            .attributes(attributes);
        if let Compression::Zstd(level) = compression {
            builder.bytes_to_bytes_codecs(vec![Arc::new(ZstdCodec::new(level, false))]);
        }
        let array = builder.build(store, path).map_err(|e| zerr(path, e))?;
        array.store_metadata().map_err(|e| zerr(path, e))?;
        Ok(Self::wrap(spec, array, fill, path))
    }

    /// Open an existing array. `spec` supplies the world placement (origin, spacing,
    /// unit); its shape must equal the array's and its chunk shape is replaced by the
    /// array's.
    pub fn open(root: &Path, path: &str, mut spec: GridSpec) -> Result<Self, GridError> {
        let store = fs_store(root)?;
        let array = Array::open(store, path).map_err(|e| zerr(path, e))?;
        if array.shape() != spec.shape {
            return Err(zerr(
                path,
                format!(
                    "shape {:?} differs from the grid {:?}",
                    array.shape(),
                    spec.shape
                ),
            ));
        }
        let chunk = array.chunk_shape(&[0, 0, 0]).map_err(|e| zerr(path, e))?;
        spec.chunk = [chunk[0].get(), chunk[1].get(), chunk[2].get()];
        let fill_bytes = array.fill_value().as_ne_bytes().to_vec();
        if fill_bytes.len() != T::SIZE {
            return Err(zerr(path, format!("data type is not {}", T::ZARR_DTYPE)));
        }
        let fill = T::read_le(&fill_bytes);
        Ok(Self::wrap(spec, array, fill, path))
    }

    fn wrap(spec: GridSpec, array: Array<FilesystemStore>, fill: T, path: &str) -> Self {
        let mut options = CodecOptions::default();
        options.set_concurrent_target(1);
        let raw = raw_chunks::<T>(&array);
        let typed = dtype_name(&array).as_deref() == Some(T::ZARR_DTYPE);
        Self {
            spec,
            array,
            fill,
            path: path.to_owned(),
            options,
            raw,
            typed,
        }
    }

    /// An error unless the array holds values of T.
    fn check_type(&self) -> Result<(), GridError> {
        if self.typed {
            return Ok(());
        }
        Err(zerr(
            &self.path,
            format!(
                "data type is {}, not {}",
                dtype_name(&self.array).unwrap_or_else(|| "unknown".into()),
                T::ZARR_DTYPE
            ),
        ))
    }
}

/// The fill value `v` as zarrs takes it: the value's bytes (zarrs writes the metadata
/// from them as it does from a typed value, e.g. "NaN").
fn fill_value<T: Scalar>(v: T) -> FillValue {
    FillValue::new(bytemuck::bytes_of(&v).to_vec())
}

/// The Zarr v3 data type name of `array`.
fn dtype_name(array: &Array<FilesystemStore>) -> Option<String> {
    match array.metadata() {
        zarrs::metadata::ArrayMetadata::V3(m) => Some(m.data_type.name().to_owned()),
        zarrs::metadata::ArrayMetadata::V2(_) => None,
    }
}

/// Chunk `idx` of `array` decoded into values of T (whose data type the caller checked).
/// Through bytes, so T needs no zarrs trait: the element types stay plain ([`Scalar`]).
fn retrieve_values<T: Scalar>(
    array: &Array<FilesystemStore>,
    idx: &[u64],
    options: &CodecOptions,
    path: &str,
) -> Result<Vec<T>, GridError> {
    let bytes: ArrayBytes<'static> = array
        .retrieve_chunk_opt(idx, options)
        .map_err(|e| zerr(path, e))?;
    let raw = bytes.into_fixed().map_err(|e| zerr(path, e))?;
    if raw.len() % T::SIZE != 0 {
        return Err(zerr(path, "chunk bytes are not whole values"));
    }
    Ok(bytemuck::pod_collect_to_vec(&raw))
}

/// Store `data` (values of T, the array's data type) as chunk `idx` of `array`.
fn store_values<T: Scalar>(
    array: &Array<FilesystemStore>,
    idx: &[u64],
    data: &[T],
    options: &CodecOptions,
) -> Result<(), zarrs::array::ArrayError> {
    let bytes = ArrayBytes::new_flen(bytemuck::cast_slice::<T, u8>(data));
    array.store_chunk_opt(idx, bytes, options)
}

/// Whether `array` stores its chunks as the values' bytes in this machine's memory
/// order: a lone `bytes` codec, little-endian (or no endianness, for single bytes), on
/// a little-endian machine, without storage transformers, and T one of the plain
/// number types and the array's own data type (read as another, the bytes would be
/// taken for values of the wrong type, where decoding reports the mismatch).
fn raw_chunks<T: Scalar>(array: &Array<FilesystemStore>) -> bool {
    let zarrs::metadata::ArrayMetadata::V3(m) = array.metadata() else {
        return false;
    };
    let plain = matches!(
        T::ZARR_DTYPE,
        "uint8"
            | "int8"
            | "uint16"
            | "int16"
            | "uint32"
            | "int32"
            | "uint64"
            | "int64"
            | "float32"
            | "float64"
    );
    let little =
        |c: &zarrs::metadata::v3::MetadataV3| match c.configuration().and_then(|c| c.get("endian"))
        {
            Some(e) => e.as_str() == Some("little"),
            None => T::SIZE == 1,
        };
    cfg!(target_endian = "little")
        && plain
        && m.data_type.name() == T::ZARR_DTYPE
        && m.storage_transformers.is_empty()
        && m.codecs.len() == 1
        && m.codecs[0].name() == "bytes"
        && little(&m.codecs[0])
}

impl<T: Scalar> BlockStore<T> for ZarrStore<T> {
    fn spec(&self) -> &GridSpec {
        &self.spec
    }

    fn read_block(&self, b: Idx3) -> Result<Vec<T>, GridError> {
        check_block::<T>(&self.spec, b, None)?;
        self.check_type()?;
        let full: Vec<T> = retrieve_values(&self.array, &b, &self.options, &self.path)?;
        let shape = self.spec.block_shape(b);
        if shape == self.spec.chunk {
            return Ok(full);
        }
        let c = self.spec.chunk.map(|c| c as usize);
        let s = shape.map(|c| c as usize);
        let mut out = Vec::with_capacity(volume(shape) as usize);
        for z in 0..s[0] {
            for y in 0..s[1] {
                let o = (z * c[1] + y) * c[2];
                out.extend_from_slice(&full[o..o + s[2]]);
            }
        }
        Ok(out)
    }

    fn map_block(&self, b: Idx3) -> Option<Result<Arc<MappedBlock<T>>, GridError>> {
        if !self.raw {
            return None;
        }
        if let Err(e) = check_block::<T>(&self.spec, b, None) {
            return Some(Err(e));
        }
        if self.spec.block_shape(b) != self.spec.chunk {
            return None;
        }
        let path = self
            .array
            .storage()
            .key_to_fspath(&self.array.chunk_key(&b));
        // A chunk never written (the fill value), a file that cannot be opened or mapped
        // (a filesystem without mmap, too many maps) or of the wrong size: read_block
        // reads it, or reports what is wrong.
        let file = std::fs::File::open(&path).ok()?;
        // SAFETY: T is a plain number type and the array's own (raw_chunks checked it);
        // the run's lock keeps writers out while the map lives, and harmap writes a
        // chunk only into a staged image, never over one in use.
        unsafe { MappedBlock::map(&file, volume(self.spec.chunk) as usize) }
            .ok()
            .flatten()
            .map(|m| Ok(Arc::new(m)))
    }

    fn write_block(&self, b: Idx3, data: &[T]) -> Result<(), GridError> {
        check_block(&self.spec, b, Some(data))?;
        self.check_type()?;
        let shape = self.spec.block_shape(b);
        let res = if shape == self.spec.chunk {
            store_values(&self.array, &b, data, &self.options)
        } else {
            // zarrs stores whole chunks: pad edge blocks with the fill value.
            let c = self.spec.chunk.map(|c| c as usize);
            let s = shape.map(|c| c as usize);
            let mut full = vec![self.fill; c[0] * c[1] * c[2]];
            for z in 0..s[0] {
                for y in 0..s[1] {
                    let o = (z * c[1] + y) * c[2];
                    full[o..o + s[2]].copy_from_slice(&data[(z * s[1] + y) * s[2]..][..s[2]]);
                }
            }
            store_values(&self.array, &b, &full, &self.options)
        };
        res.map_err(|e| zerr(&self.path, e))
    }
}

/// Rows per chunk of a table column.
const TABLE_CHUNK_ROWS: u64 = 1 << 16;

/// Write a table column: the Zarr v3 array `path` of shape `[rows]` (`cols == 0`) or
/// `[rows, cols]` (C order), chunked by rows, zstd-compressed, with dimension names
/// `["row"]` or `["row", "col"]`.
pub fn write_table<T: Scalar>(
    root: &Path,
    path: &str,
    cols: u64,
    data: &[T],
    fill: T,
) -> Result<(), GridError> {
    let width = cols.max(1);
    let rows = data.len() as u64 / width;
    assert_eq!(
        rows * width,
        data.len() as u64,
        "table data is not rows x cols"
    );
    let (shape, chunk, names) = if cols == 0 {
        (vec![rows], vec![TABLE_CHUNK_ROWS], vec!["row"])
    } else {
        (
            vec![rows, cols],
            vec![TABLE_CHUNK_ROWS, cols],
            vec!["row", "col"],
        )
    };
    let store = fs_store(root)?;
    let mut builder = ArrayBuilder::new(shape, chunk, T::ZARR_DTYPE, fill_value(fill));
    builder
        .dimension_names(Some(names))
        .bytes_to_bytes_codecs(vec![Arc::new(ZstdCodec::new(3, false))]);
    let array = builder.build(store, path).map_err(|e| zerr(path, e))?;
    array.store_metadata().map_err(|e| zerr(path, e))?;
    let per = (TABLE_CHUNK_ROWS * width) as usize;
    for (c, part) in data.chunks(per).enumerate() {
        let mut full = part.to_vec();
        full.resize(per, fill);
        let idx: Vec<u64> = if cols == 0 {
            vec![c as u64]
        } else {
            vec![c as u64, 0]
        };
        store_values(&array, &idx, &full, &CodecOptions::default()).map_err(|e| zerr(path, e))?;
    }
    Ok(())
}

/// Read a table column written by [`write_table`]: its shape and its values (C order).
pub fn read_table<T: Scalar>(root: &Path, path: &str) -> Result<(Vec<u64>, Vec<T>), GridError> {
    let store = fs_store(root)?;
    let array = Array::open(store, path).map_err(|e| zerr(path, e))?;
    if dtype_name(&array).as_deref() != Some(T::ZARR_DTYPE) {
        return Err(zerr(path, format!("data type is not {}", T::ZARR_DTYPE)));
    }
    let shape = array.shape().to_vec();
    if shape.is_empty() || shape.len() > 2 {
        return Err(zerr(
            path,
            format!("a table has 1 or 2 dimensions, not {}", shape.len()),
        ));
    }
    let rows = shape[0];
    let width = shape.get(1).copied().unwrap_or(1);
    let chunk_rows = array
        .chunk_shape(&vec![0; shape.len()])
        .map_err(|e| zerr(path, e))?[0]
        .get();
    let mut out: Vec<T> = Vec::with_capacity((rows * width) as usize);
    let mut c = 0u64;
    while c * chunk_rows < rows {
        let idx: Vec<u64> = if shape.len() == 1 {
            vec![c]
        } else {
            vec![c, 0]
        };
        let v: Vec<T> = retrieve_values(&array, &idx, &CodecOptions::default(), path)?;
        let take = ((rows - c * chunk_rows).min(chunk_rows) * width) as usize;
        out.extend_from_slice(&v[..take]);
        c += 1;
    }
    Ok((shape, out))
}
