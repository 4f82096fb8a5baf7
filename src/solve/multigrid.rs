//! Geometric multigrid on the masked domain, out of core: every level is a set of block
//! stores (mask, two generations of u, right-hand side), in memory or in memory-mapped
//! scratch files as the budget decides, and every operation is a pass over the blocks of
//! one level, each read once with a halo.
//!
//! Levels are vertex-centered: coarse node `I` sits on fine node `2I` and is an unknown
//! when that fine node is one. The coarse operator is the 7-point stencil again (spacing
//! `2h`), restriction is full weighting of the defect, prolongation is trilinear, and the
//! smoother is red-black Gauss-Seidel. One V-cycle on a level costs three passes over it:
//!
//! 1. pre-smoothing: read each block of generation 0 with a halo of `2 nu1`, do `nu1`
//!    sweeps in the box (the valid region shrinks by one voxel a half-sweep), write the
//!    block to generation 1;
//! 2. restriction: for each coarse block, read the fine generation 1 over the box its
//!    full-weighting stencil needs, and write the coarse right-hand side (and a zero
//!    correction);
//! 3. correction and post-smoothing: read generation 1 with a halo, add the interpolated
//!    coarse correction, do `nu2` sweeps, write generation 0; on the finest level the
//!    pass also measures the residual of what it writes (one more voxel of halo), so the
//!    loop decides whether to stop without starting another cycle. The first cycle (and
//!    the first after a resume) measures its start in pass 1 instead.
//!
//! The coarsest level (a single block) is relaxed by many sweeps in memory. Every pass
//! writes only its own blocks and reduces per-block numbers in block order, so the result
//! is the same bytes for any thread count and budget.
//!
//! Files: [`super::level`] (a level and what its passes read), [`super::coarsen`]
//! (the coarse shapes and masks), [`super::smooth`] (smoothing passes),
//! [`super::transfer`] (restriction, correction length), [`super::flat`] (the same
//! passes on levels held as whole arrays); this file holds the cycle.

use std::path::PathBuf;

use super::blocks::BlockLoop;
use super::coarsen::{coarse_specs, coarsen_mask};
use super::flat::Flat;
use super::level::{Change, Level, Measure, PassStats};
use super::smooth::Smooth;
use super::stencil::optimal_omega;
use crate::grid::{scratch, BlockStore, GridError, GridSpec, Residence, Scalar};

/// Cycle parameters.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CycleOptions {
    /// Sweeps before the coarse-grid correction.
    pub pre: usize,
    /// Sweeps after it.
    pub post: usize,
    /// Coarsen while the level has more than this many voxels along its longest axis.
    pub coarsest: u64,
}

impl Default for CycleOptions {
    fn default() -> Self {
        Self {
            pre: 2,
            post: 2,
            coarsest: 12,
        }
    }
}

/// Where the stores of a level live: whole arrays in memory, or memory-mapped scratch
/// files in a directory (through [`crate::grid::scratch`]).
pub struct Scratch {
    /// Directory of the scratch files.
    pub dir: PathBuf,
}

impl Scratch {
    /// A new store of `T` for `spec` reading `fill`, named `name` for its scratch file;
    /// `in_memory` chooses a whole array over a file.
    pub fn make<T: Scalar>(
        &self,
        name: &str,
        spec: &GridSpec,
        in_memory: bool,
        fill: T,
    ) -> Result<Box<dyn BlockStore<T>>, GridError> {
        let file = self.dir.join(format!("{name}.bin"));
        let at = if in_memory {
            Residence::Array
        } else {
            Residence::File(&file)
        };
        scratch(spec, fill, at)
    }
}

/// The multigrid hierarchy.
pub struct Hierarchy<'d> {
    /// Level 0 is the finest.
    pub levels: Vec<Level>,
    /// Cycle parameters.
    pub cycle: CycleOptions,
    /// How passes visit blocks (workers, the decomposition).
    pub blocks: BlockLoop<'d>,
}

/// The widest halo the passes of a cycle read a level's fields with: smoothing reads
/// `2 sweeps` voxels past a block, plus two for a fused restriction.
#[must_use]
pub fn pass_halo(cycle: &CycleOptions) -> u64 {
    2 * cycle.pre.max(cycle.post).max(1) as u64 + 2
}

impl<'d> Hierarchy<'d> {
    /// Build the coarse levels under `fine` (whose mask and generations are given):
    /// their masks from the fine mask, stores from `maker`, in memory where
    /// `in_memory(level)` says so.
    pub fn build(
        fine: Level,
        cycle: CycleOptions,
        maker: &Scratch,
        in_memory: impl Fn(usize, &GridSpec) -> bool,
        blocks: BlockLoop<'d>,
    ) -> Result<Self, GridError> {
        let specs = coarse_specs(&fine.spec, cycle.coarsest);
        let halo = pass_halo(&cycle);
        let mut levels = vec![fine];
        for (k, spec) in specs.into_iter().enumerate() {
            let lvl = k + 1;
            let mem = in_memory(lvl, &spec);
            let mask = maker.make::<u8>(&format!("mask{lvl}"), &spec, mem, 0)?;
            let above = levels.last().expect("a finer level");
            coarsen_mask(above, &spec, &*mask, &format!("mask@{lvl}"), halo, &blocks)?;
            let u = [
                maker.make::<f64>(&format!("u{lvl}a"), &spec, mem, 0.0)?,
                maker.make::<f64>(&format!("u{lvl}b"), &spec, mem, 0.0)?,
            ];
            let f = Some(maker.make::<f64>(&format!("f{lvl}"), &spec, mem, 0.0)?);
            levels.push(Level {
                spec,
                mask,
                u,
                f,
                cuts: None,
                flat: super::flat::Cache::default(),
                depth: lvl,
                halo,
            });
        }
        Ok(Self {
            levels,
            cycle,
            blocks,
        })
    }

    /// The level under `k` when restriction can be done in the pre-smoothing pass of
    /// `k`: each fine block lies over exactly one coarse block.
    fn fused(&self, k: usize) -> Option<&Level> {
        if self.flat(k).is_some() {
            return Some(&self.levels[k + 1]);
        }
        let (f, c) = (&self.levels[k].spec, &self.levels.get(k + 1)?.spec);
        let single = f.num_blocks() == 1 && c.num_blocks() == 1;
        let aligned = f.blocks() == c.blocks() && (0..3).all(|a| c.chunk[a] * 2 == f.chunk[a]);
        (single || aligned).then(|| &self.levels[k + 1])
    }

    /// Levels `k` and `k + 1` as whole arrays, when both are held so and this process
    /// owns every block: their passes then run in place on the arrays
    /// ([`super::flat`]), with the same results.
    fn flat(&self, k: usize) -> Option<(Flat<'_>, Flat<'_>)> {
        if !self.blocks.owns_all() {
            return None;
        }
        let c = self.levels.get(k + 1)?;
        Some((self.levels[k].as_flat()?, c.as_flat()?))
    }

    /// The first pass of a V-cycle on the finest level: pre-smoothing from generation 0
    /// into 1, measuring the residual of generation 0 when `measure` (the first cycle,
    /// and the first after a resume; later cycles had it measured by the cycle before).
    pub fn pre_smooth_fine(&self, measure: bool) -> Result<PassStats, GridError> {
        let c = self.cycle;
        if let Some((f, coarse)) = self.flat(0) {
            let (res_sq, count) = f.pre(c.pre, measure, &coarse);
            return Ok(PassStats {
                res_sq,
                count,
                max_change: 0.0,
            });
        }
        let pass = Smooth {
            measure: if measure {
                Measure::Before
            } else {
                Measure::None
            },
            restrict_into: self.fused(0),
            ..Smooth::new(0, 1, c.pre)
        };
        self.levels[0].smooth_pass(&pass, &self.blocks)
    }

    /// The rest of the V-cycle: coarse-grid correction and post-smoothing back into
    /// generation 0. Returns the largest change of the whole cycle and the residual of
    /// the new state (so that the loop can decide before the next cycle's first pass).
    pub fn finish_cycle(&self) -> Result<(f64, PassStats), GridError> {
        self.correct_and_smooth(0)
    }

    fn correct_and_smooth(&self, k: usize) -> Result<(f64, PassStats), GridError> {
        let (lvl, coarse, blocks) = (&self.levels[k], &self.levels[k + 1], &self.blocks);
        if self.fused(k).is_none() {
            lvl.restrict_pass(1, coarse, blocks)?;
        }
        self.cycle_level(k + 1)?;
        let (change, measure) = if k == 0 {
            (Change::Dst, Measure::After)
        } else {
            (Change::None, Measure::None)
        };
        let alpha = lvl.step_length(coarse, blocks)?;
        if let Some((f, c)) = self.flat(k) {
            let (max_change, (res_sq, count)) = f.post(self.cycle.post, &c, alpha, k == 0, k == 0);
            let st = PassStats {
                res_sq,
                count,
                max_change,
            };
            return Ok((max_change, st));
        }
        let pass = Smooth {
            coarse: Some((coarse, alpha)),
            measure,
            change,
            ..Smooth::new(1, 0, self.cycle.post)
        };
        let post = lvl.smooth_pass(&pass, blocks)?;
        Ok((post.max_change, post))
    }

    /// A V-cycle on coarse level `k`, from its generation 0 (zero) back into it.
    fn cycle_level(&self, k: usize) -> Result<(), GridError> {
        let lvl = &self.levels[k];
        if k + 1 == self.levels.len() {
            // Coarsest (one block): relax it nearly to convergence, in place.
            let n = lvl.spec.shape.iter().copied().max().unwrap_or(2);
            let pass = Smooth {
                omega: optimal_omega(n as f64),
                ..Smooth::new(0, 0, (4 * n as usize).max(20))
            };
            lvl.smooth_pass(&pass, &self.blocks)?;
            return Ok(());
        }
        if let Some((f, c)) = self.flat(k) {
            f.pre(self.cycle.pre, false, &c);
            return self.correct_and_smooth(k).map(|_| ());
        }
        let pass = Smooth {
            restrict_into: self.fused(k),
            ..Smooth::new(0, 1, self.cycle.pre)
        };
        lvl.smooth_pass(&pass, &self.blocks)?;
        self.correct_and_smooth(k)?;
        Ok(())
    }
}
