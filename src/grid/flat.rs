//! In-memory backend as one array: the whole grid in C order. Block access copies rows;
//! kernels that work on the whole grid (the in-memory levels of the multigrid solver)
//! take the array itself through the [`Contiguous`] capability and so skip the copies
//! that block-by-block passes need.

use std::sync::{RwLock, RwLockReadGuard, RwLockWriteGuard};

use super::store::check_block;
use super::{copy_overlap, to_usize, Block, BlockStore, Contiguous, GridError, GridSpec, Scalar};
use crate::math::{volume, Idx3};

/// A grid held in memory as one C-order array.
pub struct FlatStore<T> {
    spec: GridSpec,
    data: RwLock<Array<T>>,
}

/// Arrays of at least this many bytes that start as zeros are pages of their own
/// ([`Array`]).
const OWN_PAGES_FROM: usize = 1 << 20;

/// The values of a [`FlatStore`]: a slice of the grid's voxel count. Large arrays that
/// start as zeros are anonymous pages of their own, which stay unallocated until
/// written, whatever the allocator held before: a heap chunk handed out again is
/// cleared whole (calloc), so a process that had freed memory (rank 0 after it
/// voxelized) made every page of such an array resident, where an MPI rank that
/// writes only its slab of a coarse multigrid level needs about half of them.
pub struct Array<T> {
    inner: Inner<T>,
}

enum Inner<T> {
    Heap(Vec<T>),
    Pages(memmap2::MmapMut, usize),
}

impl<T: Scalar> Array<T> {
    /// `n` values `fill`.
    fn filled(n: usize, fill: T) -> Self {
        let bytes = n * std::mem::size_of::<T>();
        let zero = bytemuck::bytes_of(&fill).iter().all(|&b| b == 0);
        if zero && bytes >= OWN_PAGES_FROM {
            // Zero pages, page-aligned (so aligned for any Scalar); if the system
            // refuses the mapping the heap serves instead.
            if let Ok(m) = memmap2::MmapMut::map_anon(bytes) {
                return Self {
                    inner: Inner::Pages(m, n),
                };
            }
        }
        Self {
            inner: Inner::Heap(vec![fill; n]),
        }
    }
}

impl<T: Scalar> std::ops::Deref for Array<T> {
    type Target = [T];

    fn deref(&self) -> &[T] {
        match &self.inner {
            Inner::Heap(v) => v,
            Inner::Pages(m, n) => &bytemuck::cast_slice(&m[..])[..*n],
        }
    }
}

impl<T: Scalar> std::ops::DerefMut for Array<T> {
    fn deref_mut(&mut self) -> &mut [T] {
        match &mut self.inner {
            Inner::Heap(v) => v,
            Inner::Pages(m, n) => &mut bytemuck::cast_slice_mut(&mut m[..])[..*n],
        }
    }
}

impl<T: Scalar> FlatStore<T> {
    /// A grid filled with `fill`.
    #[must_use]
    pub fn new(spec: GridSpec, fill: T) -> Self {
        let n = spec.num_voxels() as usize;
        Self {
            spec,
            data: RwLock::new(Array::filled(n, fill)),
        }
    }

    /// The array, for reading.
    pub fn read(&self) -> RwLockReadGuard<'_, Array<T>> {
        self.data.read().expect("lock")
    }

    /// The array, for writing.
    pub fn write(&self) -> RwLockWriteGuard<'_, Array<T>> {
        self.data.write().expect("lock")
    }

    /// Offset of the first voxel of each row of block `b`, and the row length.
    fn rows(&self, b: Idx3) -> (Vec<usize>, usize) {
        let s = self.spec.block_start(b).map(|c| c as usize);
        let sh = self.spec.block_shape(b).map(|c| c as usize);
        let [_, ny, nx] = self.spec.shape.map(|c| c as usize);
        let mut out = Vec::with_capacity(sh[0] * sh[1]);
        for z in s[0]..s[0] + sh[0] {
            for y in s[1]..s[1] + sh[1] {
                out.push((z * ny + y) * nx + s[2]);
            }
        }
        (out, sh[2])
    }
}

impl<T: Scalar> BlockStore<T> for FlatStore<T> {
    fn spec(&self) -> &GridSpec {
        &self.spec
    }

    fn read_block(&self, b: Idx3) -> Result<Vec<T>, GridError> {
        check_block::<T>(&self.spec, b, None)?;
        let (rows, n) = self.rows(b);
        let d = self.read();
        let mut out = Vec::with_capacity(volume(self.spec.block_shape(b)) as usize);
        for o in rows {
            out.extend_from_slice(&d[o..o + n]);
        }
        Ok(out)
    }

    fn write_block(&self, b: Idx3, data: &[T]) -> Result<(), GridError> {
        check_block(&self.spec, b, Some(data))?;
        let (rows, n) = self.rows(b);
        let mut d = self.write();
        for (o, src) in rows.into_iter().zip(data.chunks_exact(n)) {
            d[o..o + n].copy_from_slice(src);
        }
        Ok(())
    }

    fn write_planes(&self, b: Idx3, z: std::ops::Range<u64>, data: &[T]) -> Result<(), GridError> {
        // Those planes' rows alone: the rest of the block's pages stay untouched (on MPI
        // ranks, the array of a level is touched only around the rank's slab).
        let sh = self.spec.block_shape(b).map(|c| c as usize);
        let (z0, z1) = (z.start as usize, z.end as usize);
        if z1 > sh[0] || z0 > z1 || data.len() != (z1 - z0) * sh[1] * sh[2] {
            return Err(GridError::BlockSize {
                block: b,
                expected: z1.min(sh[0]).saturating_sub(z0) * sh[1] * sh[2],
                got: data.len(),
            });
        }
        let (rows, n) = self.rows(b);
        let mut d = self.write();
        let rows = &rows[z0 * sh[1]..z1 * sh[1]];
        for (&o, src) in rows.iter().zip(data.chunks_exact(n)) {
            d[o..o + n].copy_from_slice(src);
        }
        Ok(())
    }

    fn read_region(
        &self,
        origin: [i64; 3],
        shape: [usize; 3],
        outside: T,
    ) -> Result<Block<T>, GridError> {
        // The array is one block covering the grid.
        let mut out = Block::filled(origin, shape, outside);
        let d = self.read();
        copy_overlap(&d, [0; 3], to_usize(self.spec.shape), &mut out);
        Ok(out)
    }

    fn contiguous(&self) -> Option<&dyn Contiguous<T>> {
        Some(self)
    }
}

impl<T: Scalar> Contiguous<T> for FlatStore<T> {
    fn array(&self) -> RwLockReadGuard<'_, Array<T>> {
        self.read()
    }

    fn array_mut(&self) -> RwLockWriteGuard<'_, Array<T>> {
        self.write()
    }
}
