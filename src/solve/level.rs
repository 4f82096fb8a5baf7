//! One level of the multigrid hierarchy (the finest level alone for SOR and Jacobi):
//! its stores, the boxes its block passes read, the numbers a pass measures, and the
//! bytes it holds.
//!
//! Invariants: the mask marks the unknowns (`INTERIOR`) and no unknown lies on the
//! level's edge; generation 0 holds the level's state between cycles; the right-hand
//! side exists on coarse levels only; outside the grid u and f read 0 and nothing is
//! an unknown.

use super::boxops::BoxView;
use super::flat::{Cache, Flat};
use crate::grid::{Block, BlockStore, GridError, GridSpec, Reach};
use crate::math::{volume, Idx3};

/// One level: the mask (labels on the finest level), two generations of u, the
/// right-hand side (coarse levels).
pub struct Level {
    /// Shape and blocks.
    pub spec: GridSpec,
    /// Unknowns are `INTERIOR`.
    pub mask: Box<dyn BlockStore<u8>>,
    /// Generation 0 holds the level's state between cycles; 1 is the other.
    pub u: [Box<dyn BlockStore<f64>>; 2],
    /// `None` on the finest level (0).
    pub f: Option<Box<dyn BlockStore<f64>>>,
    /// The packed arms of the sub-voxel boundary ([`super::cuts`]): on every level of a
    /// run with cuts (the coarse levels' from [`super::coarsen::coarse_arms`]).
    pub cuts: Option<Box<dyn BlockStore<u64>>>,
    /// For a level held as arrays: the runs of unknowns and the passes' buffers.
    pub flat: Cache,
    /// 0 for the finest level, one more per coarsening (names the level's fields in
    /// halo exchanges).
    pub depth: usize,
    /// The widest halo any pass reads this level's fields with.
    pub halo: u64,
    /// What a halo exchange of the level's fields must make readable on each process:
    /// the `halo` around its blocks, and on a coarse level the planes under (over) its
    /// blocks of the levels next to it ([`super::multigrid::level_reach`]).
    pub reach: Reach,
    /// On MPI ranks, for a level held as one array: the planes this process computes
    /// and owns (its whole-array passes run on its slab alone). `None` in one process.
    pub slab: Option<Slab>,
}

/// The planes of a level's array that one MPI rank works on: `compute`, its slab and
/// the halo around it (the passes read and write there; what they leave in the halo
/// is overwritten by the next exchange), and `own`, its slab (the planes of the block
/// layers `layers`, whose values and sums are its part of the result).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Slab {
    /// Planes the passes run on.
    pub compute: std::ops::Range<usize>,
    /// Planes of the owned block layers.
    pub own: std::ops::Range<usize>,
    /// The owned block layers.
    pub layers: std::ops::Range<u64>,
}

impl Level {
    /// The name of the level's field `name` (`mask`, `u0`, `u1`, `f`) in halo
    /// exchanges: `name@depth`.
    #[must_use]
    pub fn field(&self, name: &str) -> String {
        format!("{name}@{}", self.depth)
    }

    /// The level's stores as whole arrays, when all of them offer the
    /// [`Contiguous`](crate::grid::Contiguous) capability: its passes then run in place
    /// on the arrays ([`super::flat`]), with the same results.
    #[must_use]
    pub fn as_flat(&self) -> Option<Flat<'_>> {
        Flat::of(
            &self.spec,
            self.mask.contiguous()?,
            [self.u[0].contiguous()?, self.u[1].contiguous()?],
            (
                match &self.f {
                    Some(f) => Some(f.contiguous()?),
                    None => None,
                },
                match &self.cuts {
                    Some(c) => Some(c.contiguous()?),
                    None => None,
                },
            ),
            &self.flat,
            self.slab.as_ref(),
        )
    }

    /// This level and `coarse` as whole arrays, when both are held so and the passes
    /// may run on them: in one process, or on MPI ranks where both have a [`Slab`].
    #[must_use]
    pub fn flat_with<'a>(
        &'a self,
        coarse: &'a Level,
        blocks: &super::blocks::BlockLoop<'_>,
    ) -> Option<(Flat<'a>, Flat<'a>)> {
        let on_slabs = self.slab.is_some() && coarse.slab.is_some();
        if !blocks.owns_all() && !on_slabs {
            return None;
        }
        Some((self.as_flat()?, coarse.as_flat()?))
    }
}

/// Bytes a coarse level of `spec` holds (mask, two generations, right-hand side, and
/// with `cuts` the packed arms).
#[must_use]
pub fn coarse_level_bytes(spec: &GridSpec, cuts: bool) -> u64 {
    spec.num_voxels() * (1 + 3 * 8 + if cuts { 8 } else { 0 })
}

/// Bytes one worker holds in the largest pass over a level whose blocks are `chunk`:
/// a block with a halo of `halo` of u, mask and f, plus copies made on the way.
#[must_use]
pub fn worker_bytes(chunk: Idx3, halo: u64) -> u64 {
    let boxed = volume(chunk.map(|c| c + 2 * halo));
    // Restriction reads the fine box under a coarse block: (2c + 3)^3 with u, mask and
    // defects; smoothing reads the haloed block of u, mask, f and writes one block.
    let restrict_box = volume(chunk.map(|c| c + 3));
    (boxed * (8 + 1 + 8) + volume(chunk) * 16).max(restrict_box * (8 + 1 + 8 + 8))
}

/// Which state's residual a smoothing pass measures.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Measure {
    /// None.
    None,
    /// What the pass read.
    Before,
    /// What it writes (the box is read one voxel wider for it).
    After,
}

/// Which largest change a smoothing pass measures.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Change {
    /// None.
    None,
    /// Against what the pass read (one sweep's change).
    Src,
    /// Against what the destination held before (a whole cycle's change).
    Dst,
}

/// The coarse nodes under a fine box, one more on each side.
pub(super) fn coarse_cover(origin: [i64; 3], shape: [usize; 3]) -> ([i64; 3], [usize; 3]) {
    let clo = origin.map(|v| v.div_euclid(2));
    let chi = [0, 1, 2].map(|a| (origin[a] + shape[a] as i64 - 1).div_euclid(2) + 2);
    (clo, [0, 1, 2].map(|a| (chi[a] - clo[a]) as usize))
}

/// Block `b` in the local coordinates of a box of it whose first voxel is `origin`:
/// `[lo, hi)`.
pub(super) fn block_within_box(
    spec: &GridSpec,
    b: Idx3,
    origin: [i64; 3],
) -> ([usize; 3], [usize; 3]) {
    let bs = spec.block_start(b);
    let lo = [0, 1, 2].map(|a| (bs[a] as i64 - origin[a]) as usize);
    let hi = [0, 1, 2].map(|a| lo[a] + spec.block_shape(b)[a] as usize);
    (lo, hi)
}

/// What one pass over the finest level measured.
#[derive(Clone, Copy, Debug, Default)]
pub struct PassStats {
    /// Sum of squared residuals (of the input) over the unknowns.
    pub res_sq: f64,
    /// Unknowns.
    pub count: u64,
    /// Largest |new - old| against generation 0's previous content.
    pub max_change: f64,
}

impl PassStats {
    /// Combine per-block numbers in block order (the same sums for any thread count).
    #[must_use]
    pub fn reduce(parts: Vec<PassStats>) -> PassStats {
        parts
            .into_iter()
            .fold(PassStats::default(), |a, p| PassStats {
                res_sq: a.res_sq + p.res_sq,
                count: a.count + p.count,
                max_change: a.max_change.max(p.max_change),
            })
    }
}

/// The box of block `b` with a halo of `halo` (cut at the grid's edge): its first
/// voxel, its extent, and which faces lie inside the grid (their halo goes stale as
/// sweeps proceed).
pub(super) fn box_of(
    spec: &GridSpec,
    b: Idx3,
    halo: u64,
) -> ([i64; 3], [usize; 3], [[bool; 2]; 3]) {
    let s = spec.block_start(b);
    let e = [0, 1, 2].map(|a| s[a] + spec.block_shape(b)[a]);
    let lo = [0, 1, 2].map(|a| s[a].saturating_sub(halo));
    let hi = [0, 1, 2].map(|a| (e[a] + halo).min(spec.shape[a]));
    // Faces whose halo lies inside the grid go stale as sweeps proceed.
    let shrink = [0, 1, 2].map(|a| [lo[a] > 0, hi[a] < spec.shape[a]]);
    (
        lo.map(|c| c as i64),
        [0, 1, 2].map(|a| (hi[a] - lo[a]) as usize),
        shrink,
    )
}

/// A box of a level read into memory: u of one generation, the mask and f.
pub(super) struct Boxed {
    pub(super) u: Block<f64>,
    pub(super) mask: Block<u8>,
    pub(super) f: Option<Block<f64>>,
    pub(super) cuts: Option<Block<u64>>,
}

impl Boxed {
    pub(super) fn view(&mut self) -> BoxView<'_> {
        BoxView {
            u: &mut self.u.data,
            mask: &self.mask.data,
            f: self.f.as_ref().map(|f| &f.data[..]),
            cuts: self.cuts.as_ref().map(|c| &c.data[..]),
            shape: self.u.shape,
            origin: self.u.origin,
        }
    }
}

impl Level {
    /// Per block this process owns, whether it holds an unknown (built on first use,
    /// again after [`super::flat::Cache::mask_replaced`]; the others read false, and
    /// are never visited here). `None` for parts played one after another in one
    /// process (the tests' slabs), where passes visit every block: the record is per
    /// level, and the level would have it, and the `synced` state that goes with it,
    /// only for the first part's blocks.
    pub(super) fn occupied(
        &self,
        blocks: &super::blocks::BlockLoop<'_>,
    ) -> Result<Option<&[bool]>, GridError> {
        if !blocks.decomp.one_part_per_process() {
            return Ok(None);
        }
        self.flat
            .occupied(|| {
                let mut out = vec![false; self.spec.num_blocks() as usize];
                for (b, any) in blocks.map(&self.spec, |b| {
                    Ok(self
                        .mask
                        .read_block(b)?
                        .iter()
                        .any(|&m| super::cuts::is_unknown(m)))
                })? {
                    out[self.spec.block_linear(b) as usize] = any;
                }
                Ok(out)
            })
            .map(Some)
    }

    /// Zero the right-hand side and the correction of this (coarse) level's block `b`.
    pub(super) fn zero_block(&self, b: Idx3) -> Result<(), GridError> {
        let n = volume(self.spec.block_shape(b)) as usize;
        let zeros = vec![0.0; n];
        if let Some(f) = &self.f {
            f.write_block(b, &zeros)?;
        }
        self.u[0].write_block(b, &zeros)
    }

    /// Read `u[src]`, the mask and f over the box `[origin, origin + shape)`; outside the
    /// grid u and f read 0 and nothing is an unknown.
    pub(super) fn read_box(
        &self,
        src: usize,
        origin: [i64; 3],
        shape: [usize; 3],
    ) -> Result<Boxed, GridError> {
        Ok(Boxed {
            u: self.u[src].read_region(origin, shape, 0.0)?,
            mask: self.mask.read_region(origin, shape, 0)?,
            f: match &self.f {
                Some(f) => Some(f.read_region(origin, shape, 0.0)?),
                None => None,
            },
            cuts: match &self.cuts {
                Some(c) => Some(c.read_region(origin, shape, 0)?),
                None => None,
            },
        })
    }
}
