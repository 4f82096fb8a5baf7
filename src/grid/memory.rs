//! In-memory backend: one owned vector per block. For tests and small grids.

use std::sync::RwLock;

use super::store::{block_in_box, check_block, RowInspector};
use super::{copy_overlap, to_usize, Block, BlockStore, GridError, GridSpec, Scalar};
use crate::math::{volume, Idx3};

/// A grid held in memory, block by block.
pub struct MemStore<T> {
    spec: GridSpec,
    fill: T,
    blocks: Vec<RwLock<Option<Vec<T>>>>,
}

impl<T: Scalar> MemStore<T> {
    /// An empty grid; unwritten blocks read as `fill`.
    #[must_use]
    pub fn new(spec: GridSpec, fill: T) -> Self {
        let n = spec.num_blocks() as usize;
        Self {
            spec,
            fill,
            blocks: (0..n).map(|_| RwLock::new(None)).collect(),
        }
    }
}

impl<T: Scalar> BlockStore<T> for MemStore<T> {
    fn spec(&self) -> &GridSpec {
        &self.spec
    }

    fn read_block(&self, b: Idx3) -> Result<Vec<T>, GridError> {
        check_block::<T>(&self.spec, b, None)?;
        let slot = self.blocks[self.spec.block_linear(b) as usize]
            .read()
            .expect("lock");
        Ok(match &*slot {
            Some(v) => v.clone(),
            None => vec![self.fill; volume(self.spec.block_shape(b)) as usize],
        })
    }

    fn write_block(&self, b: Idx3, data: &[T]) -> Result<(), GridError> {
        check_block(&self.spec, b, Some(data))?;
        let mut slot = self.blocks[self.spec.block_linear(b) as usize]
            .write()
            .expect("lock");
        // Overwrite in place: no allocation churn for stores rewritten every pass.
        match &mut *slot {
            Some(v) => v.copy_from_slice(data),
            None => *slot = Some(data.to_vec()),
        }
        Ok(())
    }

    fn write_block_from(
        &self,
        b: Idx3,
        src: &Block<T>,
        mut inspect: Option<RowInspector<'_, T>>,
    ) -> Result<(), GridError> {
        check_block::<T>(&self.spec, b, None)?;
        let (lo, shape) = block_in_box(&self.spec, b, src);
        let mut slot = self.blocks[self.spec.block_linear(b) as usize]
            .write()
            .expect("lock");
        let dst = slot.get_or_insert_with(|| vec![self.fill; shape.iter().product()]);
        // Row by row from the box into the block, under its write lock.
        for z in 0..shape[0] {
            for y in 0..shape[1] {
                let r = z * shape[1] + y;
                let o = src.offset(lo[0] + z, lo[1] + y, lo[2]);
                let new = &src.data[o..o + shape[2]];
                let old = &mut dst[r * shape[2]..(r + 1) * shape[2]];
                if let Some(f) = inspect.as_mut() {
                    f(r, old, new);
                }
                old.copy_from_slice(new);
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
        // Copy only the overlapping rows of each block, under its read lock.
        let spec = &self.spec;
        let mut out = Block::filled(origin, shape, outside);
        for b in spec.blocks_overlapping(origin, shape) {
            let slot = self.blocks[spec.block_linear(b) as usize]
                .read()
                .expect("lock");
            let s = spec.block_start(b).map(|v| v as i64);
            match &*slot {
                Some(v) => copy_overlap(v, s, to_usize(spec.block_shape(b)), &mut out),
                None if self.fill != outside => {
                    let f = vec![self.fill; volume(spec.block_shape(b)) as usize];
                    copy_overlap(&f, s, to_usize(spec.block_shape(b)), &mut out);
                }
                None => {}
            }
        }
        Ok(out)
    }
}
