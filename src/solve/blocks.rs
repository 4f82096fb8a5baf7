//! How the passes of the solve visit blocks: the blocks of a level this process owns
//! ([`Decomposition::owned`]), at most `workers` of them in flight, their per-block
//! numbers gathered over all processes and added in block order, and the halo exchange
//! after a pass has written a field that the next pass reads with a halo.
//!
//! With [`Whole`] (one process) every block is owned, the gather and the exchange do
//! nothing, and a pass is the plain parallel loop over all blocks it always was: the
//! same values, summed in the same order.

use super::level::PassStats;
use crate::grid::{BlockStore, Decomposition, Field, GridError, GridSpec, Reach, Scalar, Whole};
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
        self.reduce_stats(spec, &parts)
    }

    /// Per-block numbers of the owned blocks (`parts`) completed with every other
    /// process's and combined: the residual sums and counts added in block order, the
    /// largest change.
    pub fn reduce_stats(
        &self,
        spec: &GridSpec,
        parts: &[(Idx3, PassStats)],
    ) -> Result<PassStats, GridError> {
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
    /// the planes `reach` gives this process ([`Decomposition::exchange`]).
    pub fn exchange<T: Scalar>(
        &self,
        field: &str,
        data: &dyn BlockStore<T>,
        reach: &Reach,
    ) -> Result<(), GridError> {
        self.decomp.exchange(field, &Field(data), reach)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::{fill_with, scratch, Residence, Slabs};
    use crate::solve::dirichlet::initial_u;
    use crate::solve::flat::Cache;
    use crate::solve::jacobi::jacobi_pass;
    use crate::solve::level::{Change, Level, Measure};
    use crate::solve::smooth::Smooth;
    use crate::voxelize::labels::{BOUNDARY, CENTER, EXTERIOR, INTERIOR};

    /// A ball of radius 8 (its shell the boundary, the middle voxel the center) in a
    /// grid of 3 x 3 x 3 blocks, u started from the fixed values and a wavy guess.
    fn ball() -> Level {
        let spec = GridSpec {
            shape: [22, 19, 21],
            origin: [0.0; 3],
            spacing: 1.0,
            chunk: [8, 8, 8],
            unit: None,
        };
        let label = |[z, y, x]: Idx3| {
            let d = [z as f64 - 11.0, y as f64 - 9.0, x as f64 - 10.0];
            let r = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            match r {
                r if r < 0.5 => CENTER,
                r if r < 7.0 => INTERIOR,
                r if r < 8.0 => BOUNDARY,
                _ => EXTERIOR,
            }
        };
        let mask = scratch(&spec, 0u8, Residence::Blocks).unwrap();
        fill_with(&*mask, 1, label).unwrap();
        let u0 = scratch(&spec, 0.0, Residence::Blocks).unwrap();
        fill_with(&*u0, 1, |v| match label(v) {
            INTERIOR => 0.5 + 0.3 * ((v[0] * 7 + v[1] * 3 + v[2]) as f64).sin(),
            l => initial_u(l, 1e-4),
        })
        .unwrap();
        Level {
            u: [u0, scratch(&spec, 0.0, Residence::Blocks).unwrap()],
            spec,
            mask,
            f: None,
            cuts: None,
            flat: Cache::default(),
            depth: 0,
            halo: 6,
            reach: Reach::Halo(6),
            slab: None,
        }
    }

    fn bits(l: &Level, g: usize) -> Vec<u64> {
        let shape = l.spec.shape.map(|c| c as usize);
        let all = l.u[g].read_region([0; 3], shape, 0.0).unwrap();
        all.data.iter().map(|v| v.to_bits()).collect()
    }

    /// A pass run as three z slabs one after another writes each block once, from the
    /// same inputs, so the state is the same bytes as the pass over the whole grid; the
    /// slabs' counts add up to the whole's, and their residual sums nearly (each part
    /// sums its own blocks; the gather that would complete them is the decomposition's).
    #[test]
    fn a_pass_in_slabs_one_after_another_equals_the_whole_pass() {
        type Pass = fn(&Level, &BlockLoop<'_>) -> PassStats;
        let jacobi: Pass = |l, bl| jacobi_pass(l, 0, 1, bl).unwrap();
        let smooth: Pass = |l, bl| {
            let pass = Smooth {
                measure: Measure::Before,
                change: Change::Src,
                ..Smooth::new(0, 1, 2)
            };
            l.smooth_pass(&pass, bl).unwrap()
        };
        for pass in [jacobi, smooth] {
            let whole = ball();
            let all = pass(&whole, &BlockLoop::whole(2));
            assert!(all.count > 1000 && all.res_sq > 0.0 && all.max_change > 0.0);
            let split = ball();
            let mut parts = Vec::new();
            for part in 0..3 {
                let d = Slabs { part, parts: 3 };
                let bl = BlockLoop {
                    workers: 2,
                    decomp: &d,
                };
                parts.push(pass(&split, &bl));
                // Blocks of the slabs still to come are untouched.
                for b in split.spec.block_indices() {
                    let untouched = split.u[1].read_block(b).unwrap().iter().all(|&v| v == 0.0);
                    assert_eq!(
                        untouched,
                        b[0] > part as u64,
                        "block {b:?} after part {part}"
                    );
                }
            }
            assert_eq!(bits(&split, 1), bits(&whole, 1));
            assert_eq!(parts.iter().map(|p| p.count).sum::<u64>(), all.count);
            let res: f64 = parts.iter().map(|p| p.res_sq).sum();
            // Sums of the same positive terms in another grouping: rounding only.
            assert!(
                (res / all.res_sq - 1.0).abs() < 1e-12,
                "{res} vs {}",
                all.res_sq
            );
            let max = parts.iter().map(|p| p.max_change).fold(0.0, f64::max);
            assert_eq!(max.to_bits(), all.max_change.to_bits());
        }
    }
}
