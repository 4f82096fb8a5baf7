//! The block-access trait every stage reads and writes grids through.
//!
//! Stages never import `zarrs` or `memmap2`: they see a [`BlockStore`]. Three backends
//! implement it: [`ZarrStore`](super::ZarrStore) (what users keep),
//! [`FileStore`](super::FileStore) (uncompressed scratch) and
//! [`MemStore`](super::MemStore) (tests and small grids).
//!
//! **Concurrency rule: no two workers may write the same block at the same time.** Reads
//! of blocks that nobody writes during the read are always safe.

use std::sync::Arc;

use super::{copy_overlap, to_usize, Block, GridSpec};
use crate::math::Idx3;

/// Element types a grid may hold: plain numbers ([`bytemuck::Pod`]: every bit pattern
/// is a value, no padding), so stored bytes may be read as values without a check. The
/// trait is sealed: the backends and the Zarr data type names cover exactly these types.
pub trait Scalar:
    bytemuck::Pod + Send + Sync + PartialEq + std::fmt::Debug + sealed::Sealed + 'static
{
    /// The Zarr v3 data type name.
    const ZARR_DTYPE: &'static str;
    /// Size in bytes.
    const SIZE: usize = std::mem::size_of::<Self>();
    /// Write `self` as little-endian bytes into `out` (length [`Self::SIZE`]).
    fn write_le(self, out: &mut [u8]);
    /// Read from little-endian bytes.
    fn read_le(b: &[u8]) -> Self;
    /// `v` converted as Rust's `as` does (rounded for floats, saturated for integers).
    fn from_f64(v: f64) -> Self;
}

mod sealed {
    /// Only this crate implements [`super::Scalar`].
    pub trait Sealed {}
}

macro_rules! scalar {
    ($t:ty, $name:literal) => {
        impl sealed::Sealed for $t {}
        impl Scalar for $t {
            const ZARR_DTYPE: &'static str = $name;
            fn write_le(self, out: &mut [u8]) {
                out.copy_from_slice(&self.to_le_bytes());
            }
            fn read_le(b: &[u8]) -> Self {
                <$t>::from_le_bytes(b.try_into().expect("slice of SIZE bytes"))
            }
            #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
            fn from_f64(v: f64) -> Self {
                v as $t
            }
        }
    };
}
scalar!(u8, "uint8");
scalar!(u16, "uint16");
scalar!(u32, "uint32");
scalar!(u64, "uint64");
scalar!(i32, "int32");
scalar!(f32, "float32");
scalar!(f64, "float64");

/// Errors of grid storage.
#[derive(Debug, thiserror::Error)]
pub enum GridError {
    /// A filesystem operation failed.
    #[error("{path}: {source}")]
    Io {
        /// The file or directory.
        path: std::path::PathBuf,
        /// What the OS said.
        source: std::io::Error,
    },
    /// zarrs failed to read or write an array.
    #[error("zarr array {path}: {message}")]
    Zarr {
        /// The array path.
        path: String,
        /// What zarrs said.
        message: String,
    },
    /// Data of the wrong size was handed to a write.
    #[error("block {block:?}: expected {expected} values, got {got}")]
    BlockSize {
        /// The block index.
        block: Idx3,
        /// Values the block holds.
        expected: usize,
        /// Values handed in.
        got: usize,
    },
    /// A block index outside the grid.
    #[error("block {block:?} is outside the block grid {blocks:?}")]
    BlockIndex {
        /// The block index.
        block: Idx3,
        /// Blocks per axis.
        blocks: Idx3,
    },
    /// Grids that must share their shape and blocks do not.
    #[error("grids do not match: {0}")]
    Mismatch(String),
    /// A message between MPI ranks cannot be sent as asked (too large for one MPI
    /// message, or the ranks disagree about what they exchange).
    #[error("MPI ranks: {0}")]
    Ranks(String),
    /// The grid's blocks cannot be shared out over MPI ranks the way asked (blocks too
    /// large for one message, or block layers that do not line up across multigrid
    /// levels). Fix: what the message says (other `--chunk`, more ranks or one process).
    #[error("MPI ranks: {0}")]
    RankLayout(String),
    /// A chunk does not hold what harmap wrote: its checksum differs, it is cut short,
    /// or it is missing from an array whose every chunk was written. Fix: run the stage
    /// that wrote the array again (the run's files were changed or damaged on disk).
    #[error(
        "zarr array {path}, chunk {chunk:?} ({file}): {what}; the file was changed or damaged after harmap wrote it: run the stage that writes {path} again"
    )]
    Corrupt {
        /// The array path (`/phi/0`).
        path: String,
        /// The chunk's index.
        chunk: Vec<u64>,
        /// The chunk's file.
        file: std::path::PathBuf,
        /// What is wrong.
        what: String,
    },
    /// The memory budget cannot hold what a stage needs.
    #[error(
        "memory budget {budget} is too small: {what} needs {needed}; use --mem {suggest} or more"
    )]
    Budget {
        /// The budget, human readable.
        budget: String,
        /// What did not fit.
        what: String,
        /// Bytes needed, human readable.
        needed: String,
        /// A budget that would do.
        suggest: String,
    },
}

/// A grid held as one C-order array `[z, y, x]` in memory: kernels over the whole grid
/// take the array itself, skipping the copies of block-by-block access
/// ([`BlockStore::contiguous`]). The guards follow the reader-writer rule: many readers
/// or one writer; a kernel that holds one store's write guard must not ask for it
/// again.
pub trait Contiguous<T>: Send + Sync {
    /// The array, for reading.
    fn array(&self) -> std::sync::RwLockReadGuard<'_, super::flat::Array<T>>;
    /// The array, for writing.
    fn array_mut(&self) -> std::sync::RwLockWriteGuard<'_, super::flat::Array<T>>;
}

/// Called by [`BlockStore::write_block_from`] with each row's index in the block, the
/// values it held and the values written over them.
pub type RowInspector<'a, T> = &'a mut dyn FnMut(usize, &[T], &[T]);

/// Block access to a chunked grid of `T`.
pub trait BlockStore<T: Scalar>: Send + Sync {
    /// The grid and its block shape.
    fn spec(&self) -> &GridSpec;

    /// Read block `b` (its true extent; edge blocks are smaller than a chunk). Blocks
    /// never written read as the store's fill value.
    fn read_block(&self, b: Idx3) -> Result<Vec<T>, GridError>;

    /// Write block `b`; `data` has the block's true extent.
    fn write_block(&self, b: Idx3, data: &[T]) -> Result<(), GridError>;

    /// Write block `b` from the box `src`, which must cover it. With `inspect`, every row
    /// of the block is shown first, as its index in the block (`z * ny + y`), the values
    /// it held and the values written over them, so a caller can measure a change
    /// without reading the block separately.
    fn write_block_from(
        &self,
        b: Idx3,
        src: &Block<T>,
        inspect: Option<RowInspector<'_, T>>,
    ) -> Result<(), GridError> {
        let spec = self.spec();
        let (lo, shape) = block_in_box(spec, b, src);
        let data = src.crop(lo, shape);
        if let Some(f) = inspect {
            let old = self.read_block(b)?;
            for (r, (o, n)) in old
                .chunks_exact(shape[2])
                .zip(data.chunks_exact(shape[2]))
                .enumerate()
            {
                f(r, o, n);
            }
        }
        self.write_block(b, &data)
    }

    /// Write the planes `z` (along z, counted within the block) of block `b` from
    /// `data` (those planes in C order), the rest of the block as it was. The default
    /// reads and writes the whole block; a store in memory may keep only the planes it
    /// was given of a block never written whole (a halo received from another process).
    fn write_planes(&self, b: Idx3, z: std::ops::Range<u64>, data: &[T]) -> Result<(), GridError> {
        let sh = self.spec().block_shape(b);
        let plane = (sh[1] * sh[2]) as usize;
        let (z0, z1) = (z.start as usize, z.end as usize);
        if z1 > sh[0] as usize || z0 > z1 || data.len() != (z1 - z0) * plane {
            return Err(GridError::BlockSize {
                block: b,
                expected: z1.min(sh[0] as usize).saturating_sub(z0) * plane,
                got: data.len(),
            });
        }
        let mut block = self.read_block(b)?;
        block[z0 * plane..z1 * plane].copy_from_slice(data);
        self.write_block(b, &block)
    }

    /// Read the box `[origin, origin + shape)` in grid coordinates. Voxels outside the
    /// grid take `outside`. The default assembles it from whole blocks; backends that can
    /// read sub-blocks cheaply override it.
    fn read_region(
        &self,
        origin: [i64; 3],
        shape: [usize; 3],
        outside: T,
    ) -> Result<Block<T>, GridError> {
        let spec = self.spec();
        let mut out = Block::filled(origin, shape, outside);
        for b in spec.blocks_overlapping(origin, shape) {
            let s = spec.block_start(b).map(|c| c as i64);
            let bs = to_usize(spec.block_shape(b));
            // A mapped block is read where it overlaps only (a halo takes a few layers of
            // its neighbours, not their whole chunks).
            match self.map_block(b) {
                Some(m) => copy_overlap(&m?, s, bs, &mut out),
                None => copy_overlap(&self.read_block(b)?, s, bs, &mut out),
            }
        }
        Ok(out)
    }

    /// Capability: the whole grid as one C-order array in memory ([`Contiguous`]), for
    /// kernels that work on the whole grid in place. None (the default) for stores that
    /// hold it any other way; callers then go block by block.
    fn contiguous(&self) -> Option<&dyn Contiguous<T>> {
        None
    }

    /// Block `b` as its stored bytes mapped into memory, where the store keeps them as
    /// they are in memory (uncompressed, little-endian on a little-endian machine, the
    /// block's own shape): reading it then costs neither a decode nor a copy, and the
    /// pages come from the page cache instead of being faulted in fresh. None where the
    /// block must be read with [`BlockStore::read_block`] (compressed, an edge block, a
    /// chunk never written). Shared, so a store may keep its maps and hand them out.
    fn map_block(&self, _b: Idx3) -> Option<Result<Arc<MappedBlock<T>>, GridError>> {
        None
    }

    /// Read block `b` with a halo of `halo` voxels on every side. Voxels of the halo that
    /// fall outside the grid take `outside`.
    fn read_block_halo(&self, b: Idx3, halo: usize, outside: T) -> Result<Block<T>, GridError> {
        let spec = self.spec();
        let start = spec.block_start(b);
        let shape = spec.block_shape(b);
        let h = halo as i64;
        self.read_region(
            start.map(|c| c as i64 - h),
            shape.map(|c| c as usize + 2 * halo),
            outside,
        )
    }
}

/// Where block `b` of `spec` sits in the box `bx` (its first voxel, local to the box),
/// and its extent. Panics when the box does not cover the block.
pub(crate) fn block_in_box<T>(spec: &GridSpec, b: Idx3, bx: &Block<T>) -> ([usize; 3], [usize; 3]) {
    let s = spec.block_start(b);
    let shape = spec.block_shape(b).map(|c| c as usize);
    let lo = [0, 1, 2].map(|a| {
        let l = s[a] as i64 - bx.origin[a];
        assert!(
            l >= 0 && l as usize + shape[a] <= bx.shape[a],
            "the box does not cover the block"
        );
        l as usize
    });
    (lo, shape)
}

pub(crate) fn check_block<T>(
    spec: &GridSpec,
    b: Idx3,
    data: Option<&[T]>,
) -> Result<(), GridError> {
    let nb = spec.blocks();
    if (0..3).any(|a| b[a] >= nb[a]) {
        return Err(GridError::BlockIndex {
            block: b,
            blocks: nb,
        });
    }
    if let Some(d) = data {
        let expected = crate::math::volume(spec.block_shape(b)) as usize;
        if d.len() != expected {
            return Err(GridError::BlockSize {
                block: b,
                expected,
                got: d.len(),
            });
        }
    }
    Ok(())
}

/// Write every block of `store` from `value(voxel)` (voxel `[z, y, x]`), with at most
/// `workers` blocks in flight.
pub fn fill_with<T: Scalar>(
    store: &dyn BlockStore<T>,
    workers: usize,
    value: impl Fn(Idx3) -> T + Sync + Send,
) -> Result<(), GridError> {
    let spec = store.spec();
    crate::parallel::map_bounded(&spec.block_indices(), workers, |&b| {
        let st = spec.block_start(b);
        let sh = spec.block_shape(b);
        let mut v = Vec::with_capacity(crate::math::volume(sh) as usize);
        for z in st[0]..st[0] + sh[0] {
            for y in st[1]..st[1] + sh[1] {
                for x in st[2]..st[2] + sh[2] {
                    v.push(value([z, y, x]));
                }
            }
        }
        store.write_block(b, &v)
    })?;
    Ok(())
}

/// A block's stored bytes mapped into memory, read as `[T]` ([`BlockStore::map_block`]).
pub struct MappedBlock<T> {
    map: memmap2::Mmap,
    /// The bytes of the values (the map may end with a checksum).
    data: usize,
    _t: std::marker::PhantomData<T>,
}

impl<T: Scalar> MappedBlock<T> {
    /// Map `file`, which must hold exactly `len` values of `T` in the machine's byte
    /// order, followed by their CRC32C (little-endian, as Zarr's `crc32c` codec writes
    /// it) when `checksum`; None when its size is not that (the caller reads it the slow
    /// way, which reports what is wrong). With `verify`, the checksum is checked here: one
    /// that differs is an error (`Err` of kind `InvalidData`).
    ///
    /// # Safety
    /// The file must not be truncated or written while mapped (the run directory's lock
    /// keeps other harmap processes out; a truncation by anything else would end the
    /// process with SIGBUS), and `T` must be a plain number type, for which every bit
    /// pattern is a value (a [`Scalar`] is [`bytemuck::Pod`]).
    pub(crate) unsafe fn map(
        file: &std::fs::File,
        len: usize,
        checksum: bool,
        verify: bool,
    ) -> std::io::Result<Option<Self>> {
        let data = len * T::SIZE;
        let total = data + if checksum { 4 } else { 0 };
        if file.metadata()?.len() != total as u64 || len == 0 {
            return Ok(None);
        }
        // SAFETY: as the caller promises; the length was checked just above.
        let map = unsafe { memmap2::Mmap::map(file)? };
        if map.len() != total || bytemuck::try_cast_slice::<u8, T>(&map[..data]).is_err() {
            return Ok(None);
        }
        if checksum && verify {
            let stored = u32::from_le_bytes(map[data..].try_into().expect("4 bytes"));
            let got = crc32c::crc32c(&map[..data]);
            if stored != got {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::InvalidData,
                    format!("checksum mismatch (stored {stored:#010x}, computed {got:#010x})"),
                ));
            }
        }
        Ok(Some(Self {
            map,
            data,
            _t: std::marker::PhantomData,
        }))
    }
}

impl<T: Scalar> std::ops::Deref for MappedBlock<T> {
    type Target = [T];

    fn deref(&self) -> &[T] {
        // Size and alignment were checked in `map`, and T is Pod.
        bytemuck::cast_slice(&self.map[..self.data])
    }
}
