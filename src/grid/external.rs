//! Zarr v3 arrays harmap did not write (a user's label volume), opened read-only
//! through the Zarr backend's store ([`fs_store`]): no completeness marker or
//! checksums are required, any data type is read as its native-endian bytes, and the
//! caller decides what the values mean.
//!
//! Errors are messages about the array, for the caller to attach to its path.

use std::path::Path;

use zarrs::array::{Array, ArrayBytes, ArraySubset, CodecOptions};
use zarrs::filesystem::FilesystemStore;

use super::{fs_store, GridError};

/// A Zarr v3 array opened read-only, of any data type (see
/// [`open_external_array`]).
pub struct ExternalArray {
    array: Array<FilesystemStore>,
}

/// Open the Zarr v3 array whose `zarr.json` is in the directory `dir`, read-only.
pub fn open_external_array(dir: &Path) -> Result<ExternalArray, String> {
    let store = fs_store(dir).map_err(|e| match e {
        GridError::Io { source, .. } => source.to_string(),
        e => e.to_string(),
    })?;
    let array =
        Array::open(store, "/").map_err(|e| format!("not a readable Zarr v3 array: {e}"))?;
    Ok(ExternalArray { array })
}

impl ExternalArray {
    /// Elements per axis.
    #[must_use]
    pub fn shape(&self) -> &[u64] {
        self.array.shape()
    }

    /// The Zarr data type's name as zarrs writes it (`uint8`, `float32`, ...).
    #[must_use]
    pub fn data_type(&self) -> String {
        self.array.data_type().to_string()
    }

    /// Bytes of one decoded chunk (0 where unknown; 8 bytes per element where the
    /// data type has no fixed size).
    #[must_use]
    pub fn chunk_bytes(&self) -> u64 {
        let a = &self.array;
        a.chunk_shape(&[0, 0, 0])
            .map_or(0, |c| c.iter().map(|n| n.get()).product::<u64>())
            .saturating_mul(a.data_type().fixed_size().unwrap_or(8) as u64)
    }

    /// The elements of the box `[start, start + size)` in C order, native-endian bytes.
    /// Reads on the calling thread only (our loops are parallel over blocks).
    pub fn read_box(&self, start: [u64; 3], size: [u64; 3]) -> Result<Vec<u8>, String> {
        let subset = ArraySubset::new_with_start_shape(start.to_vec(), size.to_vec())
            .map_err(|e| e.to_string())?;
        let mut options = CodecOptions::default();
        options.set_concurrent_target(1);
        let bytes: ArrayBytes<'static> = self
            .array
            .retrieve_array_subset_opt(&subset, &options)
            .map_err(|e| format!("reading {start:?}+{size:?}: {e}"))?;
        let raw = bytes.into_fixed().map_err(|e| e.to_string())?;
        Ok(raw.into_owned())
    }
}
