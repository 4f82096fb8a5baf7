//! How the passes of the solve visit blocks: the blocks of a level this process owns
//! ([`Decomposition::owned`]), at most `workers` of them in flight, their per-block
//! numbers gathered over all processes and added in block order, and the halo exchange
//! after a pass has written a field that the next pass reads with a halo.
//!
//! With [`Whole`] (one process) every block is owned, the gather and the exchange do
//! nothing, and a pass is the plain parallel loop over all blocks it always was: the
//! same values, summed in the same order.

use super::level::PassStats;
use crate::grid::{Decomposition, GridError, GridSpec, Whole};
use crate::math::Idx3;
use crate::parallel::map_bounded;

/// The block loop of the solve's passes.
#[derive(Clone, Copy, Debug)]
pub struct BlockLoop<'d> {
    /// Blocks in flight at once (the memory plan's worker count).
    pub workers: usize,
    /// Which blocks this process owns, and the halo exchange.
    pub decomp: &'d dyn Decomposition,
}

impl BlockLoop<'static> {
    /// One process owning every block.
    #[must_use]
    pub fn whole(workers: usize) -> Self {
        Self {
            workers,
            decomp: &Whole,
        }
    }
}

impl BlockLoop<'_> {
    /// Whether this process owns every block (then kernels over whole arrays may run).
    #[must_use]
    pub fn owns_all(&self) -> bool {
        self.decomp.parts() == 1
    }

    /// `f` on every owned block of `spec`, results in block order.
    pub fn map<R: Send>(
        &self,
        spec: &GridSpec,
        f: impl Fn(Idx3) -> Result<R, GridError> + Sync + Send,
    ) -> Result<Vec<(Idx3, R)>, GridError> {
        let owned = self.decomp.owned(spec);
        let r = map_bounded(&owned, self.workers, |&b| f(b))?;
        Ok(owned.into_iter().zip(r).collect())
    }

    /// `f` on every owned block of `spec`, for its effect.
    pub fn each(
        &self,
        spec: &GridSpec,
        f: impl Fn(Idx3) -> Result<(), GridError> + Sync + Send,
    ) -> Result<(), GridError> {
        map_bounded(&self.decomp.owned(spec), self.workers, |&b| f(b))?;
        Ok(())
    }

    /// Per-block values of the owned blocks completed with every other process's:
    /// one entry per block of `spec`, in block order ([`Decomposition::reduce_in_block_order`]).
    pub fn gather(
        &self,
        spec: &GridSpec,
        parts: impl IntoIterator<Item = (Idx3, f64)>,
    ) -> Result<Vec<f64>, GridError> {
        let mut all = vec![0.0; spec.num_blocks() as usize];
        for (b, v) in parts {
            all[spec.block_linear(b) as usize] = v;
        }
        self.decomp.reduce_in_block_order(spec, &mut all)?;
        Ok(all)
    }

    /// The sum over all blocks of `f`'s per-block values, added in block order.
    pub fn sum(
        &self,
        spec: &GridSpec,
        f: impl Fn(Idx3) -> Result<f64, GridError> + Sync + Send,
    ) -> Result<f64, GridError> {
        let parts = self.map(spec, f)?;
        Ok(self.gather(spec, parts)?.into_iter().sum())
    }

    /// A pass's numbers over all blocks: the residual sums and counts added in block
    /// order, the largest change.
    pub fn stats(
        &self,
        spec: &GridSpec,
        f: impl Fn(Idx3) -> Result<PassStats, GridError> + Sync + Send,
    ) -> Result<PassStats, GridError> {
        let parts = self.map(spec, f)?;
        let res = self.gather(spec, parts.iter().map(|(b, p)| (*b, p.res_sq)))?;
        // Counts are below 2^53: exact as f64.
        let count = self.gather(spec, parts.iter().map(|(b, p)| (*b, p.count as f64)))?;
        let max = self.gather(spec, parts.iter().map(|(b, p)| (*b, p.max_change)))?;
        Ok(PassStats::reduce(
            res.into_iter()
                .zip(count)
                .zip(max)
                .map(|((res_sq, count), max_change)| PassStats {
                    res_sq,
                    count: count as u64,
                    max_change,
                })
                .collect(),
        ))
    }

    /// Make the blocks of `field` that other processes wrote readable here within
    /// `halo` voxels of the owned blocks ([`Decomposition::exchange`]).
    pub fn exchange(&self, field: &str, halo: u64) -> Result<(), GridError> {
        self.decomp.exchange(field, halo)
    }
}
