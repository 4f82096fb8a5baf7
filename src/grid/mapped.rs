//! A raw store read through memory maps of its chunks, kept while the wrapper lives: a
//! stage that reads the same blocks many times with halos (the upwind map) reads them in
//! place from the page cache, where copying the array into memory first costs a read of
//! every chunk and as much fresh memory, faulted in and zeroed by the kernel.

use std::sync::{Arc, OnceLock};

use super::{BlockStore, GridError, GridSpec, MappedBlock, Scalar};
use crate::math::Idx3;

/// `inner`'s blocks, each mapped once on first use and the map kept
/// ([`BlockStore::map_block`], which the default `read_region` reads through), and read
/// through `inner` where it does not map them. Read-only.
pub struct MappedStore<'a, T: Scalar> {
    inner: &'a dyn BlockStore<T>,
    /// Per block: its map, or None where `inner` does not map it.
    maps: Vec<OnceLock<Option<Arc<MappedBlock<T>>>>>,
}

impl<'a, T: Scalar> MappedStore<'a, T> {
    /// The wrapper if `inner` maps its first block (a raw store), else None.
    pub fn new(inner: &'a dyn BlockStore<T>) -> Option<Self> {
        inner.map_block([0, 0, 0])?.ok()?;
        let n = inner.spec().num_blocks() as usize;
        Some(Self {
            inner,
            maps: (0..n).map(|_| OnceLock::new()).collect(),
        })
    }

    fn mapped(&self, b: Idx3) -> Result<Option<Arc<MappedBlock<T>>>, GridError> {
        let k = self.inner.spec().block_linear(b) as usize;
        let Some(slot) = self.maps.get(k) else {
            // Off the grid: the inner store reports it.
            return Ok(None);
        };
        if let Some(m) = slot.get() {
            return Ok(m.clone());
        }
        let m = self.inner.map_block(b).transpose()?;
        Ok(slot.get_or_init(|| m).clone())
    }
}

impl<T: Scalar> BlockStore<T> for MappedStore<'_, T> {
    fn spec(&self) -> &GridSpec {
        self.inner.spec()
    }

    fn read_block(&self, b: Idx3) -> Result<Vec<T>, GridError> {
        match self.mapped(b)? {
            Some(m) => Ok(m.to_vec()),
            None => self.inner.read_block(b),
        }
    }

    fn write_block(&self, b: Idx3, _data: &[T]) -> Result<(), GridError> {
        Err(GridError::Mismatch(format!(
            "block {b:?}: a mapped store is read-only"
        )))
    }

    fn map_block(&self, b: Idx3) -> Option<Result<Arc<MappedBlock<T>>, GridError>> {
        self.mapped(b).transpose()
    }
}
