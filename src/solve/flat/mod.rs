//! The multigrid passes for levels held in memory as whole arrays
//! ([`Contiguous`] stores): the
//! same operations as the block passes of [`super::multigrid`], done in place on the
//! arrays, with no box copies and no halo recomputation.
//!
//! Every value is computed with the same arithmetic in the same order as in the block
//! passes (red-black sweeps do not depend on the order within a color; the residual and
//! c.Ac are summed per block, plane by plane, blocks in block order; restriction and
//! prolongation are per node), so
//! a level in memory and a level in scratch files give the same bytes. The tests that
//! compare budgets check it.
//!
//! A half-sweep is parallel over slabs of z planes: a node of one color reads only
//! nodes of the other color, which the half-sweep does not change. The even slabs go
//! first, then the odd ones, so a slab borrows the planes next to it from slabs that
//! are not being written. The other passes run over slabs of whole planes too, with
//! buffers lent per task from pools that live with the level.
//!
//! On a level with cuts ([`crate::solve::cuts`]) each cut unknown is a run of one,
//! marked, among the runs; the passes relax it, and take its defect, with the point
//! kernel the block passes use ([`crate::solve::cuts::CutArrays`]).
//!
//! Files: [`runs`] (the unknowns as runs along x, the block columns of the sums),
//! `smooth` (red-black sweeps in place), `stats` (residual and largest change),
//! `restrict` (full weighting of the defect), `prolong` (trilinear correction),
//! `energy` (the correction's energy), `passes` (a V-cycle's pre- and post-smoothing passes of a level).

mod energy;
mod passes;
mod prolong;
mod restrict;
pub mod runs;
mod smooth;
mod stats;
pub(crate) use stats::PlaneStats;

use std::sync::atomic::{AtomicBool, Ordering};

use crate::grid::{Contiguous, GridSpec};
use crate::parallel::Pool;
use crate::solve::level::Slab;

use prolong::PlanePair;
use runs::{dims, Runs};

/// What the whole-array passes of a level keep between passes: the runs of its
/// unknowns (built on first use), whether both generations hold the fixed values, and
/// buffers lent to the passes' tasks (at most [`PASS_PLANES`] planes per thread in all;
/// the memory plan counts them, see [`pass_bytes`]).
#[derive(Default)]
pub struct Cache {
    runs: std::sync::OnceLock<Runs>,
    planes: Pool<Vec<f64>>,
    prolong: Pool<PlanePair>,
    energy: Pool<(PlanePair, Vec<Vec<f64>>)>,
    /// Per block of the level: whether it holds an unknown (for the block passes,
    /// which skip the others once `synced`).
    occupied: std::sync::OnceLock<Vec<bool>>,
    /// On the blocks without unknowns both generations are equal: set by a block pass
    /// from one generation into the other over every block; cleared by
    /// [`Cache::state_replaced`].
    synced: AtomicBool,
    /// Both generations hold the fixed values: set by the first pre-smoothing, which
    /// writes generation 1 whole (post-smoothing swaps the two); cleared by
    /// [`Cache::state_replaced`].
    fixed_in_both: AtomicBool,
}

/// Planes of f64 a thread's buffers hold in the pools of one level: restriction 3,
/// prolongation 2.5, c.Ac 5.5 (each rounded up in the sum).
pub const PASS_PLANES: u64 = 12;

/// Bytes the whole-array passes of a level of `spec` keep with `threads` threads: the
/// pools' planes, and the runs of unknowns (counted at two runs per row, and with
/// `cuts` a run for each cut unknown, counted at one voxel in eight: about one in a
/// hundred is cut on the finest level of a mesh or molecule, more on coarser levels).
#[must_use]
pub fn pass_bytes(spec: &GridSpec, threads: usize, cuts: bool) -> u64 {
    let [nz, ny, nx] = spec.shape;
    let cut_runs = if cuts { spec.num_voxels() / 8 * 12 } else { 0 };
    threads as u64 * PASS_PLANES * ny * nx * 8 + 2 * nz * ny * 12 + cut_runs
}

impl Cache {
    /// Generation 0 was written whole from outside the passes (initialized, or read
    /// from a checkpoint): the next pre-smoothing writes generation 1 whole again.
    pub fn state_replaced(&self) {
        self.fixed_in_both.store(false, Ordering::Relaxed);
        self.synced.store(false, Ordering::Relaxed);
    }

    /// Whether both generations are equal on the blocks without unknowns.
    pub(crate) fn synced(&self) -> bool {
        self.synced.load(Ordering::Relaxed)
    }

    /// A block pass from one generation into the other visited every block.
    pub(crate) fn set_synced(&self) {
        self.synced.store(true, Ordering::Relaxed);
    }

    /// Per block, whether it holds an unknown: `make` builds it on first use.
    pub(crate) fn occupied(
        &self,
        make: impl FnOnce() -> Result<Vec<bool>, crate::grid::GridError>,
    ) -> Result<&[bool], crate::grid::GridError> {
        if let Some(o) = self.occupied.get() {
            return Ok(o);
        }
        let o = make()?;
        Ok(self.occupied.get_or_init(|| o))
    }

    /// The level's mask was rewritten: the runs of its unknowns are built again on
    /// next use, and the next pre-smoothing writes generation 1 whole.
    pub fn mask_replaced(&mut self) {
        self.runs = std::sync::OnceLock::new();
        self.occupied = std::sync::OnceLock::new();
        self.state_replaced();
    }
}

/// A level held as whole arrays.
pub struct Flat<'a> {
    /// Shape and blocks.
    pub spec: &'a GridSpec,
    /// Unknowns are `INTERIOR` and `CUT`.
    pub mask: &'a dyn Contiguous<u8>,
    /// The two generations.
    pub u: [&'a dyn Contiguous<f64>; 2],
    /// The right-hand side (coarse levels).
    pub f: Option<&'a dyn Contiguous<f64>>,
    /// The packed arms, on a level with cuts ([`crate::solve::cuts`]).
    pub arms: Option<&'a dyn Contiguous<u64>>,
    /// The runs of the unknowns and the passes' buffers.
    pub cache: &'a Cache,
    /// On MPI ranks, the planes this process computes and owns; `None`: all of them.
    pub slab: Option<&'a Slab>,
}

impl<'a> Flat<'a> {
    /// A level's stores as arrays; builds the runs of its unknowns on first use.
    #[must_use]
    pub fn of(
        spec: &'a GridSpec,
        mask: &'a dyn Contiguous<u8>,
        u: [&'a dyn Contiguous<f64>; 2],
        (f, arms): (
            Option<&'a dyn Contiguous<f64>>,
            Option<&'a dyn Contiguous<u64>>,
        ),
        cache: &'a Cache,
        slab: Option<&'a Slab>,
    ) -> Option<Self> {
        cache
            .runs
            .get_or_init(|| Runs::of_planes(&mask.array(), dims(spec), slab.map(|s| &s.compute)));
        Some(Flat {
            spec,
            mask,
            u,
            f,
            arms,
            cache,
            slab,
        })
    }

    /// The planes the passes run on: all of them, or on a rank its slab with the halo.
    pub(super) fn compute(&self) -> std::ops::Range<usize> {
        match self.slab {
            Some(s) => s.compute.clone(),
            None => 0..dims(self.spec)[0],
        }
    }

    /// The planes whose values this process writes as its own: all, or its slab.
    pub(super) fn own(&self) -> std::ops::Range<usize> {
        match self.slab {
            Some(s) => s.own.clone(),
            None => 0..dims(self.spec)[0],
        }
    }

    pub(super) fn runs(&self) -> &Runs {
        self.cache
            .runs
            .get()
            .expect("Flat::of builds the runs of the level")
    }
}
