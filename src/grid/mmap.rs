//! Memory-mapped chunk file: uncompressed scratch storage for intermediate grids.
//!
//! Layout: one file, block `n` (C order) at byte `n * chunk_volume * size_of::<T>()`,
//! each block stored at full chunk size, C order inside. A block is accessed through a
//! window mapped for that access and unmapped right after, so the pages of the file
//! never accumulate in the resident set: what is resident is what a worker holds.

use std::fs::{File, OpenOptions};
use std::path::{Path, PathBuf};

use memmap2::MmapOptions;

use super::store::check_block;
use super::{Block, BlockStore, GridError, GridSpec, Scalar};
use crate::math::{volume, Idx3};

/// A grid in a memory-mapped scratch file. The file is zero-filled when created, so
/// unwritten blocks read as the all-zero value of `T`.
pub struct MmapStore<T> {
    spec: GridSpec,
    file: File,
    path: PathBuf,
    _t: std::marker::PhantomData<T>,
}

impl<T: Scalar> MmapStore<T> {
    /// Create (or truncate) the scratch file at `path`, sparse and zero-filled.
    pub fn create(path: &Path, spec: GridSpec) -> Result<Self, GridError> {
        let io = |source| GridError::Io {
            path: path.to_owned(),
            source,
        };
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(path)
            .map_err(io)?;
        let bytes = spec.num_blocks() * volume(spec.chunk) * T::SIZE as u64;
        file.set_len(bytes).map_err(io)?;
        Ok(Self {
            spec,
            file,
            path: path.to_owned(),
            _t: std::marker::PhantomData,
        })
    }

    fn chunk_bytes(&self) -> u64 {
        volume(self.spec.chunk) * T::SIZE as u64
    }

    fn io(&self, source: std::io::Error) -> GridError {
        GridError::Io {
            path: self.path.clone(),
            source,
        }
    }

    fn window_opts(&self, b: Idx3) -> MmapOptions {
        let offset = self.spec.block_linear(b) * self.chunk_bytes();
        let mut opts = MmapOptions::new();
        opts.offset(offset).len(self.chunk_bytes() as usize);
        opts
    }

    /// Map block `b` read-only for the duration of one access.
    fn window(&self, b: Idx3) -> Result<memmap2::Mmap, GridError> {
        // SAFETY: the file is private to this store; blocks are disjoint byte ranges and
        // the concurrency rule of `BlockStore` forbids writing a block while it is read.
        unsafe { self.window_opts(b).map(&self.file) }.map_err(|e| self.io(e))
    }

    /// Map bytes `[first, first + len)` of block `b` read-only for one access.
    fn window_range(&self, b: Idx3, first: usize, len: usize) -> Result<memmap2::Mmap, GridError> {
        let offset = self.spec.block_linear(b) * self.chunk_bytes() + first as u64;
        // SAFETY: as in `window`.
        unsafe { MmapOptions::new().offset(offset).len(len).map(&self.file) }
            .map_err(|e| self.io(e))
    }

    /// Map block `b` writable for the duration of one access.
    fn window_mut(&self, b: Idx3) -> Result<memmap2::MmapMut, GridError> {
        // SAFETY: as in `window`; only one worker writes a block at a time.
        unsafe { self.window_opts(b).map_mut(&self.file) }.map_err(|e| self.io(e))
    }
}

impl<T: Scalar> BlockStore<T> for MmapStore<T> {
    fn spec(&self) -> &GridSpec {
        &self.spec
    }

    fn read_block(&self, b: Idx3) -> Result<Vec<T>, GridError> {
        check_block::<T>(&self.spec, b, None)?;
        let shape = self.spec.block_shape(b).map(|c| c as usize);
        let c = self.spec.chunk.map(|c| c as usize);
        let map = self.window(b)?;
        let mut out = Vec::with_capacity(shape[0] * shape[1] * shape[2]);
        for z in 0..shape[0] {
            for y in 0..shape[1] {
                let o = ((z * c[1] + y) * c[2]) * T::SIZE;
                out.extend(
                    map[o..o + shape[2] * T::SIZE]
                        .chunks_exact(T::SIZE)
                        .map(T::read_le),
                );
            }
        }
        Ok(out)
    }

    fn write_block(&self, b: Idx3, data: &[T]) -> Result<(), GridError> {
        check_block(&self.spec, b, Some(data))?;
        let shape = self.spec.block_shape(b).map(|c| c as usize);
        let c = self.spec.chunk.map(|c| c as usize);
        let mut map = self.window_mut(b)?;
        for z in 0..shape[0] {
            for y in 0..shape[1] {
                let o = ((z * c[1] + y) * c[2]) * T::SIZE;
                let src = &data[(z * shape[1] + y) * shape[2]..][..shape[2]];
                for (dst, v) in map[o..o + shape[2] * T::SIZE]
                    .chunks_exact_mut(T::SIZE)
                    .zip(src)
                {
                    v.write_le(dst);
                }
            }
        }
        Ok(())
    }

    fn read_region(
        &self,
        origin: [i64; 3],
        shape: [usize; 3],
        outside: T,
    ) -> Result<Block<T>, GridError> {
        // Map only the byte range of each block that holds the overlapping rows.
        let spec = &self.spec;
        let mut out = Block::filled(origin, shape, outside);
        let c = spec.chunk.map(|c| c as i64);
        for b in spec.blocks_overlapping(origin, shape) {
            let bs = spec.block_start(b).map(|v| v as i64);
            let lo = [0, 1, 2].map(|a| origin[a].max(bs[a]));
            let hi = [0, 1, 2].map(|a| {
                (origin[a] + shape[a] as i64)
                    .min(bs[a] + c[a])
                    .min(spec.shape[a] as i64)
            });
            let at = |z: i64, y: i64, x: i64| {
                ((((z - bs[0]) * c[1] + (y - bs[1])) * c[2]) + (x - bs[2])) as usize * T::SIZE
            };
            let first = at(lo[0], lo[1], lo[2]);
            let end = at(hi[0] - 1, hi[1] - 1, hi[2]);
            let map = self.window_range(b, first, end - first)?;
            let n = (hi[2] - lo[2]) as usize;
            for z in lo[0]..hi[0] {
                for y in lo[1]..hi[1] {
                    let o = at(z, y, lo[2]) - first;
                    let d = out.offset(
                        (z - origin[0]) as usize,
                        (y - origin[1]) as usize,
                        (lo[2] - origin[2]) as usize,
                    );
                    for (dst, src) in out.data[d..d + n]
                        .iter_mut()
                        .zip(map[o..o + n * T::SIZE].chunks_exact(T::SIZE))
                    {
                        *dst = T::read_le(src);
                    }
                }
            }
        }
        Ok(out)
    }
}
