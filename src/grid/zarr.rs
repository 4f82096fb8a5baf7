//! Zarr v3 backend (zarrs, filesystem store): the arrays users keep and exchange.
//!
//! Every array is written with `dimension_names` `[z, y, x]` and portable codecs only
//! (bytes, optionally zstd, then crc32c), so zarr-python, tensorstore and napari open it.
//! zarrs would run codecs on rayon's pool; our own loops are parallel over blocks, so
//! every call here caps zarrs' concurrency to 1.
//!
//! Integrity: every chunk ends with its CRC32C (the `crc32c` codec), checked whenever it
//! is decoded, and once per chunk where a raw chunk is read in place
//! ([`BlockStore::map_block`]). Every chunk is written, those equal to the fill value
//! too, and when the last chunk of an array has been written once the array's
//! attribute `harmap_complete` becomes `true`: in such an array a missing chunk is an
//! error ([`GridError::Corrupt`]), never the fill value. Arrays without the attribute
//! (written by older versions, or not yet whole) read a missing chunk as the fill
//! value, as Zarr does.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

use zarrs::array::codec::{Crc32cCodec, ZstdCodec};
use zarrs::array::{Array, ArrayBuilder, ArrayBytes, ArrayError, CodecOptions, FillValue};
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
    /// Raw chunks end with their CRC32C.
    checksum: bool,
    /// The array is whole (attribute `harmap_complete`): a missing chunk is an error.
    complete: AtomicBool,
    /// The filesystem root of the store.
    root: PathBuf,
    /// Per chunk: written by this store at least once.
    written: Vec<AtomicBool>,
    /// How many chunks this store has written at least once.
    written_count: AtomicU64,
    /// Per chunk: its mapped bytes' checksum was checked (cleared when it is written).
    verified: Vec<AtomicBool>,
}

/// The attribute that marks an array whose every chunk was written.
pub const COMPLETE_ATTRIBUTE: &str = "harmap_complete";

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
        builder.bytes_to_bytes_codecs(match compression {
            Compression::Zstd(level) => vec![
                Arc::new(ZstdCodec::new(level, false)),
                Arc::new(Crc32cCodec::new()),
            ],
            Compression::None => vec![Arc::new(Crc32cCodec::new())],
        });
        let array = builder.build(store, path).map_err(|e| zerr(path, e))?;
        array.store_metadata().map_err(|e| zerr(path, e))?;
        let me = Self::wrap(root, spec, array, fill, path, false);
        if me.written.is_empty() {
            me.mark_complete()?;
        }
        Ok(me)
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
        let complete = array.attributes().get(COMPLETE_ATTRIBUTE) == Some(&true.into());
        Ok(Self::wrap(root, spec, array, fill, path, complete))
    }

    fn wrap(
        root: &Path,
        spec: GridSpec,
        array: Array<FilesystemStore>,
        fill: T,
        path: &str,
        complete: bool,
    ) -> Self {
        let mut options = CodecOptions::default();
        options.set_concurrent_target(1);
        // Chunks equal to the fill value are written too, so that a missing chunk of a
        // whole array is seen as missing.
        options.set_store_empty_chunks(true);
        let (raw, checksum) = raw_chunks::<T>(&array).map_or((false, false), |c| (true, c));
        let n = spec.num_blocks() as usize;
        let typed = dtype_name(&array).as_deref() == Some(T::ZARR_DTYPE);
        Self {
            spec,
            array,
            fill,
            path: path.to_owned(),
            options,
            raw,
            typed,
            checksum,
            complete: AtomicBool::new(complete),
            root: root.to_owned(),
            written: (0..n).map(|_| AtomicBool::new(false)).collect(),
            written_count: AtomicU64::new(0),
            verified: (0..n).map(|_| AtomicBool::new(false)).collect(),
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

    /// Whether every chunk of the array has been written (attribute
    /// `harmap_complete`, read when opened, or set since by this store).
    pub fn is_complete(&self) -> bool {
        self.complete.load(Ordering::Acquire)
    }

    /// The file of chunk `b`.
    fn chunk_file(&self, b: &[u64]) -> PathBuf {
        self.array.storage().key_to_fspath(&self.array.chunk_key(b))
    }

    fn corrupt(&self, b: &[u64], what: impl Into<String>) -> GridError {
        GridError::Corrupt {
            path: self.path.clone(),
            chunk: b.to_vec(),
            file: self.chunk_file(b),
            what: what.into(),
        }
    }

    /// A failed read of chunk `b`: a chunk that does not decode is damaged.
    fn read_error(&self, b: &[u64], e: ArrayError) -> GridError {
        match e {
            ArrayError::CodecError(c) => self.corrupt(b, format!("cannot be decoded: {c}")),
            ArrayError::UnexpectedChunkDecodedSize(..) | ArrayError::InvalidBytesInputSize(..) => {
                self.corrupt(b, format!("cannot be decoded: {e}"))
            }
            e => zerr(&self.path, format!("chunk {b:?}: {e}")),
        }
    }

    /// Record that chunk `b` was written; after the last one, mark the array whole.
    fn note_written(&self, b: Idx3) -> Result<(), GridError> {
        let k = self.spec.block_linear(b) as usize;
        self.verified[k].store(false, Ordering::Release);
        if !self.written[k].swap(true, Ordering::AcqRel)
            && self.written_count.fetch_add(1, Ordering::AcqRel) + 1 == self.written.len() as u64
            && !self.is_complete()
        {
            self.mark_complete()?;
        }
        Ok(())
    }

    /// Set the attribute `harmap_complete` in the array's `zarr.json` (written to a
    /// temporary name and renamed, so a reader sees the old or the new file).
    fn mark_complete(&self) -> Result<(), GridError> {
        mark_complete(&self.root, &self.path)?;
        self.complete.store(true, Ordering::Release);
        Ok(())
    }
}

/// Set the attribute `harmap_complete` of the array `path` under `root` (what a store
/// does after writing its last chunk; on MPI ranks, rank 0 once every rank has written
/// its chunks).
pub fn mark_complete(root: &Path, path: &str) -> Result<(), GridError> {
    let dir = root.join(path.trim_start_matches('/'));
    let file = dir.join("zarr.json");
    let io = |source| GridError::Io {
        path: file.clone(),
        source,
    };
    let text = std::fs::read_to_string(&file).map_err(io)?;
    let mut doc: serde_json::Value = serde_json::from_str(&text).map_err(|e| zerr(path, e))?;
    let Some(obj) = doc.as_object_mut() else {
        return Err(zerr(path, "zarr.json is not an object"));
    };
    let attrs = obj
        .entry("attributes")
        .or_insert_with(|| serde_json::Value::Object(serde_json::Map::new()));
    if let Some(a) = attrs.as_object_mut() {
        a.insert(COMPLETE_ATTRIBUTE.into(), true.into());
    }
    let tmp = dir.join(format!(".zarr.json.partial-{}", std::process::id()));
    let bytes = serde_json::to_vec_pretty(&doc).expect("json");
    std::fs::write(&tmp, bytes)
        .and_then(|()| std::fs::rename(&tmp, &file))
        .map_err(|e| {
            let _ = std::fs::remove_file(&tmp);
            io(e)
        })?;
    Ok(())
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

/// Chunk `idx` of `array` decoded into values of T (whose data type the caller checked),
/// or None where the chunk was never written; `on_err` says what a failed read means.
/// Through bytes, so T needs no zarrs trait: the element types stay plain ([`Scalar`]).
fn retrieve_values<T: Scalar>(
    array: &Array<FilesystemStore>,
    idx: &[u64],
    options: &CodecOptions,
    path: &str,
    on_err: impl FnOnce(ArrayError) -> GridError,
) -> Result<Option<Vec<T>>, GridError> {
    let bytes: Option<ArrayBytes<'static>> = array
        .retrieve_chunk_if_exists_opt(idx, options)
        .map_err(on_err)?;
    let Some(bytes) = bytes else {
        return Ok(None);
    };
    let raw = bytes.into_fixed().map_err(|e| zerr(path, e))?;
    if raw.len() % T::SIZE != 0 {
        return Err(zerr(path, "chunk bytes are not whole values"));
    }
    Ok(Some(bytemuck::pod_collect_to_vec(&raw)))
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
/// order: a `bytes` codec, little-endian (or no endianness, for single bytes), alone or
/// followed by `crc32c` (then `Some(true)`), on a little-endian machine, without storage
/// transformers, and T one of the plain number types and the array's own data type
/// (read as another, the bytes would be taken for values of the wrong type, where
/// decoding reports the mismatch). None where chunks must be decoded.
fn raw_chunks<T: Scalar>(array: &Array<FilesystemStore>) -> Option<bool> {
    let zarrs::metadata::ArrayMetadata::V3(m) = array.metadata() else {
        return None;
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
    let checksum = m.codecs.len() == 2 && m.codecs[1].name() == "crc32c";
    let ok = cfg!(target_endian = "little")
        && plain
        && m.data_type.name() == T::ZARR_DTYPE
        && m.storage_transformers.is_empty()
        && (m.codecs.len() == 1 || checksum)
        && m.codecs[0].name() == "bytes"
        && little(&m.codecs[0]);
    ok.then_some(checksum)
}

impl<T: Scalar> BlockStore<T> for ZarrStore<T> {
    fn spec(&self) -> &GridSpec {
        &self.spec
    }

    fn read_block(&self, b: Idx3) -> Result<Vec<T>, GridError> {
        check_block::<T>(&self.spec, b, None)?;
        self.check_type()?;
        let full = match retrieve_values::<T>(&self.array, &b, &self.options, &self.path, |e| {
            self.read_error(&b, e)
        })? {
            Some(v) => v,
            None if self.is_complete() => {
                return Err(
                    self.corrupt(&b, "missing, although every chunk of the array was written")
                )
            }
            None => vec![self.fill; volume(self.spec.chunk) as usize],
        };
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
        let path = self.chunk_file(&b);
        // A chunk never written (the fill value), a file that cannot be opened or mapped
        // (a filesystem without mmap, too many maps) or of the wrong size: read_block
        // reads it, or reports what is wrong.
        let file = std::fs::File::open(&path).ok()?;
        let k = self.spec.block_linear(b) as usize;
        // The checksum is checked once per chunk, not at every read of it: a chunk is
        // only rewritten through this store, which clears the mark.
        let check = self.checksum && !self.verified[k].load(Ordering::Acquire);
        // SAFETY: T is a plain number type and the array's own (raw_chunks checked it);
        // the run's lock keeps writers out while the map lives, and harmap writes a
        // chunk only into a staged image, never over one in use.
        match unsafe {
            MappedBlock::map(
                &file,
                volume(self.spec.chunk) as usize,
                self.checksum,
                check,
            )
        } {
            Ok(Some(m)) => {
                if check {
                    self.verified[k].store(true, Ordering::Release);
                }
                Some(Ok(Arc::new(m)))
            }
            Err(e) if e.kind() == std::io::ErrorKind::InvalidData => {
                Some(Err(self.corrupt(&b, e.to_string())))
            }
            _ => None,
        }
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
        res.map_err(|e| zerr(&self.path, format!("chunk {b:?}: {e}")))?;
        self.note_written(b)
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
        .bytes_to_bytes_codecs(vec![
            Arc::new(ZstdCodec::new(3, false)),
            Arc::new(Crc32cCodec::new()),
        ]);
    let mut array = builder.build(store, path).map_err(|e| zerr(path, e))?;
    array.store_metadata().map_err(|e| zerr(path, e))?;
    let mut options = CodecOptions::default();
    options.set_store_empty_chunks(true);
    let per = (TABLE_CHUNK_ROWS * width) as usize;
    for (c, part) in data.chunks(per).enumerate() {
        let mut full = part.to_vec();
        full.resize(per, fill);
        let idx: Vec<u64> = if cols == 0 {
            vec![c as u64]
        } else {
            vec![c as u64, 0]
        };
        store_values(&array, &idx, &full, &options).map_err(|e| zerr(path, e))?;
    }
    // Written last: a table cut short by a kill is not taken for a whole one.
    array
        .attributes_mut()
        .insert(COMPLETE_ATTRIBUTE.into(), true.into());
    array.store_metadata().map_err(|e| zerr(path, e))?;
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
    let complete = array.attributes().get(COMPLETE_ATTRIBUTE) == Some(&true.into());
    let fill_bytes = array.fill_value().as_ne_bytes().to_vec();
    if fill_bytes.len() != T::SIZE {
        return Err(zerr(path, format!("data type is not {}", T::ZARR_DTYPE)));
    }
    let array_fill = T::read_le(&fill_bytes);
    let mut out: Vec<T> = Vec::with_capacity((rows * width) as usize);
    let mut c = 0u64;
    while c * chunk_rows < rows {
        let idx: Vec<u64> = if shape.len() == 1 {
            vec![c]
        } else {
            vec![c, 0]
        };
        let corrupt = |what: String| GridError::Corrupt {
            path: path.to_owned(),
            chunk: idx.clone(),
            file: array.storage().key_to_fspath(&array.chunk_key(&idx)),
            what,
        };
        let got = retrieve_values::<T>(&array, &idx, &CodecOptions::default(), path, |e| match e {
            ArrayError::CodecError(e) => corrupt(format!("cannot be decoded: {e}")),
            e => zerr(path, format!("chunk {idx:?}: {e}")),
        });
        let v: Vec<T> = match got {
            Ok(Some(v)) => v,
            Ok(None) if complete => {
                return Err(corrupt(
                    "missing, although every chunk of the table was written".into(),
                ))
            }
            Ok(None) => vec![array_fill; (chunk_rows * width) as usize],
            Err(e) => return Err(e),
        };
        let take = ((rows - c * chunk_rows).min(chunk_rows) * width) as usize;
        out.extend_from_slice(&v[..take]);
        c += 1;
    }
    Ok((shape, out))
}
