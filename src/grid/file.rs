//! Chunk file: uncompressed scratch storage for intermediate grids.
//!
//! Layout: one file, block `n` (C order) at byte `n * chunk_volume * size_of::<T>()`,
//! each block stored at full chunk size, C order inside. A block is read and written
//! with one positioned read or write (pread, pwrite) through a buffer each thread
//! reuses, so the file's pages never enter the resident set (they stay in the page
//! cache) and no access pays for page faults or for mapping and unmapping a window:
//! at 512^3 with `--mem 256MiB` the solve took 43.5 s through mapped windows (51.8 s of
//! it system time), 24.7 s with pread and pwrite.

use std::fs::{File, OpenOptions};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

use super::store::check_block;
use super::{Block, BlockStore, GridError, GridSpec, Scalar};
use crate::math::{volume, Idx3};

/// A grid in a scratch file. The file is zero-filled when created, so
/// unwritten blocks read as the all-zero value of `T`.
pub struct FileStore<T> {
    spec: GridSpec,
    file: File,
    path: PathBuf,
    _t: std::marker::PhantomData<T>,
}

impl<T: Scalar> FileStore<T> {
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

    /// Block `b`'s shape, the chunk's, the block's first byte in the file and the bytes
    /// up to the end of its last row (an edge block's tail is not read or written).
    fn span(&self, b: Idx3) -> ([usize; 3], [usize; 3], u64, usize) {
        let shape = self.spec.block_shape(b).map(|c| c as usize);
        let c = self.spec.chunk.map(|c| c as usize);
        let offset = self.spec.block_linear(b) * self.chunk_bytes();
        let len = (((shape[0] - 1) * c[1] + shape[1] - 1) * c[2] + shape[2]) * T::SIZE;
        (shape, c, offset, len)
    }

    fn io(&self, source: std::io::Error) -> GridError {
        GridError::Io {
            path: self.path.clone(),
            source,
        }
    }
}

impl<T: Scalar> BlockStore<T> for FileStore<T> {
    fn spec(&self) -> &GridSpec {
        &self.spec
    }

    fn read_block(&self, b: Idx3) -> Result<Vec<T>, GridError> {
        check_block::<T>(&self.spec, b, None)?;
        let (shape, c, offset, len) = self.span(b);
        with_bytes(len, |buf| {
            self.file
                .read_exact_at(buf, offset)
                .map_err(|e| self.io(e))?;
            let mut out = Vec::with_capacity(shape[0] * shape[1] * shape[2]);
            for z in 0..shape[0] {
                for y in 0..shape[1] {
                    let o = ((z * c[1] + y) * c[2]) * T::SIZE;
                    out.extend(
                        buf[o..o + shape[2] * T::SIZE]
                            .chunks_exact(T::SIZE)
                            .map(T::read_le),
                    );
                }
            }
            Ok(out)
        })
    }

    fn write_block(&self, b: Idx3, data: &[T]) -> Result<(), GridError> {
        check_block(&self.spec, b, Some(data))?;
        let (shape, c, offset, len) = self.span(b);
        with_bytes(len, |buf| {
            // The gaps between an edge block's rows are never read; zeros, so that
            // the file's bytes depend on the values alone.
            if shape != c {
                buf.fill(0);
            }
            for z in 0..shape[0] {
                for y in 0..shape[1] {
                    let o = ((z * c[1] + y) * c[2]) * T::SIZE;
                    let src = &data[(z * shape[1] + y) * shape[2]..][..shape[2]];
                    for (dst, v) in buf[o..o + shape[2] * T::SIZE]
                        .chunks_exact_mut(T::SIZE)
                        .zip(src)
                    {
                        v.write_le(dst);
                    }
                }
            }
            self.file.write_all_at(buf, offset).map_err(|e| self.io(e))
        })
    }

    fn read_region(
        &self,
        origin: [i64; 3],
        shape: [usize; 3],
        outside: T,
    ) -> Result<Block<T>, GridError> {
        // Read only the byte range of each block that holds the overlapping rows.
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
            let offset = spec.block_linear(b) * self.chunk_bytes() + first as u64;
            with_bytes(end - first, |buf| -> Result<(), GridError> {
                self.file
                    .read_exact_at(buf, offset)
                    .map_err(|e| self.io(e))?;
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
                            .zip(buf[o..o + n * T::SIZE].chunks_exact(T::SIZE))
                        {
                            *dst = T::read_le(src);
                        }
                    }
                }
                Ok(())
            })?;
        }
        Ok(out)
    }
}

thread_local! {
    /// A thread's buffer for the bytes of one block, reused from access to access.
    static BYTES: std::cell::RefCell<Vec<u8>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Buffers larger than this are let go after each access instead of kept (blocks of
/// large chunks, which a thread seldom reads twice in a row).
const KEEP_BYTES: usize = 8 << 20;

/// `f` with this thread's byte buffer, at least `len` bytes long (its content is what
/// the last access left).
fn with_bytes<R>(len: usize, f: impl FnOnce(&mut [u8]) -> R) -> R {
    BYTES.with_borrow_mut(|buf| {
        if buf.len() < len {
            buf.resize(len, 0);
        }
        let r = f(&mut buf[..len]);
        if buf.len() > KEEP_BYTES {
            *buf = Vec::new();
        }
        r
    })
}
