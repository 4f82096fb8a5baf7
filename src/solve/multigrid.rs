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

use std::path::PathBuf;

use super::boxops::{correction_energy, prolong, prolong_add, restrict, BoxView};
use super::flat::Flat;
use super::stencil::optimal_omega;
use crate::grid::{Block, BlockStore, FlatStore, GridError, GridSpec, MmapStore, Scalar};
use crate::math::{volume, Idx3};
use crate::parallel::map_bounded;
use crate::voxelize::labels::INTERIOR;

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

/// Where the stores of a level live.
pub trait StoreMaker {
    /// A new store of `T` for `spec`, filled with `fill`, named `name` for scratch files;
    /// `in_memory` chooses the backend.
    fn make<T: Scalar>(
        &self,
        name: &str,
        spec: &GridSpec,
        in_memory: bool,
        fill: T,
    ) -> Result<Box<dyn BlockStore<T>>, GridError>;
}

/// Stores in memory, or in memory-mapped files under a directory.
pub struct Scratch {
    /// Directory of the scratch files.
    pub dir: PathBuf,
}

impl StoreMaker for Scratch {
    fn make<T: Scalar>(
        &self,
        name: &str,
        spec: &GridSpec,
        in_memory: bool,
        fill: T,
    ) -> Result<Box<dyn BlockStore<T>>, GridError> {
        if in_memory {
            Ok(Box::new(FlatStore::new(spec.clone(), fill)))
        } else {
            let s = MmapStore::create(&self.dir.join(format!("{name}.bin")), spec.clone())?;
            // A new scratch file reads as all-zero bytes.
            if fill != T::read_le(&vec![0u8; T::SIZE]) {
                crate::grid::fill_with(&s, 1, |_| fill)?;
            }
            Ok(Box::new(s))
        }
    }
}

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
    /// For a level held as arrays: the runs of unknowns and the passes' buffers.
    pub flat: super::flat::Cache,
}

/// The shape of the level below `shape`: nodes at even fine indices.
#[must_use]
pub fn coarse_shape(shape: Idx3) -> Idx3 {
    shape.map(|n| (n - 1) / 2 + 1)
}

/// The specs of the coarse levels below `fine` (chunk: half the fine chunk, at least
/// 16), down to one whose longest axis is at most `coarsest` voxels.
#[must_use]
pub fn coarse_specs(fine: &GridSpec, coarsest: u64) -> Vec<GridSpec> {
    let mut out = Vec::new();
    let mut s = fine.clone();
    while s.shape.iter().copied().max().unwrap_or(0) > coarsest.max(3)
        || (out.is_empty() && s.shape.iter().all(|&n| n >= 5))
    {
        let shape = coarse_shape(s.shape);
        let chunk = [0, 1, 2].map(|a| (fine.chunk[a] / 2).max(16).min(shape[a]));
        s = GridSpec {
            shape,
            origin: s.origin,
            spacing: s.spacing * 2.0,
            chunk,
            unit: s.unit.clone(),
        };
        out.push(s.clone());
    }
    out
}

/// Bytes a coarse level of `spec` holds (mask, two generations, right-hand side).
#[must_use]
pub fn coarse_level_bytes(spec: &GridSpec) -> u64 {
    spec.num_voxels() * (1 + 3 * 8)
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

/// Restrict the defect of a smoothed fine box into the coarse block `b` of `c` (the
/// coarse block under the fine block `b`), and zero the coarse correction there.
fn restrict_block(view: &BoxView<'_>, c: &Level, b: Idx3) -> Result<(), GridError> {
    let cs = c.spec.block_start(b).map(|v| v as i64);
    let csh = c.spec.block_shape(b).map(|v| v as usize);
    let d_origin = cs.map(|v| 2 * v - 1);
    let d_shape = csh.map(|v| 2 * v + 1);
    let mut d = vec![0.0; d_shape.iter().product()];
    // Defects where the box has all six neighbours; elsewhere nothing is an unknown.
    let lo = [0, 1, 2].map(|a| d_origin[a].max(view.origin[a] + 1));
    let hi = [0, 1, 2]
        .map(|a| (d_origin[a] + d_shape[a] as i64).min(view.origin[a] + view.shape[a] as i64 - 1));
    if (0..3).all(|a| lo[a] < hi[a]) {
        let l = |a: usize, v: i64| (v - view.origin[a]) as usize;
        let sub = view.defects(
            [l(0, lo[0]), l(1, lo[1]), l(2, lo[2])],
            [l(0, hi[0]), l(1, hi[1]), l(2, hi[2])],
        );
        let n = [0, 1, 2].map(|a| (hi[a] - lo[a]) as usize);
        for z in 0..n[0] {
            for y in 0..n[1] {
                let dz = (lo[0] - d_origin[0]) as usize + z;
                let dy = (lo[1] - d_origin[1]) as usize + y;
                let o = (dz * d_shape[1] + dy) * d_shape[2] + (lo[2] - d_origin[2]) as usize;
                d[o..o + n[2]].copy_from_slice(&sub[(z * n[1] + y) * n[2]..][..n[2]]);
            }
        }
    }
    let cmask = c.mask.read_block(b)?;
    let rhs = restrict(&d, d_origin, d_shape, &cmask, cs, csh);
    c.f.as_ref()
        .expect("coarse levels have a right-hand side")
        .write_block(b, &rhs)?;
    c.u[0].write_block(b, &vec![0.0; rhs.len()])
}

/// The coarse nodes under a fine box, one more on each side.
fn coarse_cover(origin: [i64; 3], shape: [usize; 3]) -> ([i64; 3], [usize; 3]) {
    let clo = origin.map(|v| v.div_euclid(2));
    let chi = [0, 1, 2].map(|a| (origin[a] + shape[a] as i64 - 1).div_euclid(2) + 2);
    (clo, [0, 1, 2].map(|a| (chi[a] - clo[a]) as usize))
}

/// Block `b` in the local coordinates of a box of it whose first voxel is `origin`:
/// `[lo, hi)`.
fn block_within_box(spec: &GridSpec, b: Idx3, origin: [i64; 3]) -> ([usize; 3], [usize; 3]) {
    let bs = spec.block_start(b);
    let lo = [0, 1, 2].map(|a| (bs[a] as i64 - origin[a]) as usize);
    let hi = [0, 1, 2].map(|a| lo[a] + spec.block_shape(b)[a] as usize);
    (lo, hi)
}

/// The multigrid hierarchy.
pub struct Hierarchy {
    /// Level 0 is the finest.
    pub levels: Vec<Level>,
    /// Cycle parameters.
    pub cycle: CycleOptions,
    /// Blocks in flight per pass.
    pub workers: usize,
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
struct Boxed {
    u: Block<f64>,
    mask: Block<u8>,
    f: Option<Block<f64>>,
}

impl Boxed {
    fn view(&mut self) -> BoxView<'_> {
        BoxView {
            u: &mut self.u.data,
            mask: &self.mask.data,
            f: self.f.as_ref().map(|f| &f.data[..]),
            shape: self.u.shape,
            origin: self.u.origin,
        }
    }
}

impl Level {
    /// Read `u[src]`, the mask and f over the box `[origin, origin + shape)`; outside the
    /// grid u and f read 0 and nothing is an unknown.
    fn read_box(
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
        })
    }

    /// Pass 1 or 3 on one block: read `u[src]` over the haloed box, optionally add the
    /// interpolated correction of `coarse`, do `sweeps` sweeps, write the block to
    /// `u[dst]`; measure the residual of what was read or of what is written
    /// (`measure`); with `change`, also the largest change against the block's content
    /// in `u[dst]`.
    #[allow(clippy::too_many_arguments)]
    fn smooth_block(
        &self,
        b: Idx3,
        src: usize,
        dst: usize,
        sweeps: usize,
        omega: f64,
        coarse: Option<(&Level, f64)>,
        measure: Measure,
        change: Change,
        restrict_into: Option<&Level>,
    ) -> Result<PassStats, GridError> {
        let spec = &self.spec;
        let single = spec.num_blocks() == 1;
        // Restriction needs defects one voxel past the block, so values two past it; the
        // residual of the result needs values one past it.
        let extra = if restrict_into.is_some() {
            2
        } else {
            usize::from(measure == Measure::After)
        };
        let halo = if single {
            1
        } else {
            (2 * sweeps + extra).max(1) as u64
        };
        let (origin, shape, shrink) = box_of(spec, b, halo);
        let mut bx = self.read_box(src, origin, shape)?;
        let bs = spec.block_start(b);
        let bshape = spec.block_shape(b).map(|c| c as usize);
        let inner_lo = [0, 1, 2].map(|a| (bs[a] as i64 - origin[a]) as usize);
        let inner_hi = [0, 1, 2].map(|a| inner_lo[a] + bshape[a]);
        let mut st = PassStats::default();
        let before = (change == Change::Src).then(|| bx.u.crop(inner_lo, bshape));
        let mut view = bx.view();
        if measure == Measure::Before {
            (st.res_sq, st.count) = view.residual_sq(inner_lo, inner_hi);
        }
        if let Some((c, alpha)) = coarse {
            let (clo, cshape) = coarse_cover(origin, shape);
            let e = c.u[0].read_region(clo, cshape, 0.0)?;
            prolong_add(&mut view, &e.data, clo, cshape, alpha);
        }
        if single {
            // The whole level in one box: every sweep covers all of it.
            for _ in 0..sweeps {
                view.sweeps(1, [[false; 2]; 3], omega);
            }
        } else {
            view.sweeps(sweeps, shrink, omega);
        }
        if measure == Measure::After {
            (st.res_sq, st.count) = view.residual_sq(inner_lo, inner_hi);
        }
        if let Some(c) = restrict_into {
            restrict_block(&view, c, b)?;
        }
        // Row `r` of the block within the box (u and mask share the box's shape).
        let bsh = bx.u.shape;
        let interior = |r: usize| {
            let (z, y) = (inner_lo[0] + r / bshape[1], inner_lo[1] + r % bshape[1]);
            let o = (z * bsh[1] + y) * bsh[2] + inner_lo[2];
            o..o + bshape[2]
        };
        let mut max = 0.0f64;
        let mut measure_row = |r: usize, old: &[f64], new: &[f64]| {
            let m = &bx.mask.data[interior(r)];
            for ((o, n), &l) in old.iter().zip(new).zip(m) {
                if l == INTERIOR {
                    max = max.max((n - o).abs());
                }
            }
        };
        match (change, &before) {
            (Change::Dst, _) => self.u[dst].write_block_from(b, &bx.u, Some(&mut measure_row))?,
            (Change::Src, Some(before)) => {
                for (r, old) in before.chunks_exact(bshape[2]).enumerate() {
                    measure_row(r, old, &bx.u.data[interior(r)]);
                }
                self.u[dst].write_block_from(b, &bx.u, None)?;
            }
            _ => self.u[dst].write_block_from(b, &bx.u, None)?,
        }
        st.max_change = max;
        Ok(st)
    }

    /// A smoothing pass over every block, reduced in block order.
    #[allow(clippy::too_many_arguments)]
    fn smooth_pass(
        &self,
        src: usize,
        dst: usize,
        sweeps: usize,
        omega: f64,
        coarse: Option<(&Level, f64)>,
        measure: Measure,
        change: Change,
        restrict_into: Option<&Level>,
        workers: usize,
    ) -> Result<PassStats, GridError> {
        let parts = map_bounded(&self.spec.block_indices(), workers, |&b| {
            self.smooth_block(
                b,
                src,
                dst,
                sweeps,
                omega,
                coarse,
                measure,
                change,
                restrict_into,
            )
        })?;
        Ok(PassStats::reduce(parts))
    }

    /// The energy-minimizing length of the coarse correction: with `c = P e` the
    /// interpolated correction (on the unknowns) and `D` the defect of the smoothed
    /// state, `alpha = (D . c) / (c . A c)`.
    ///
    /// The numerator is taken on the coarse level: the restriction's weights are those
    /// of trilinear interpolation (`f = P^T D / 2`, see [`restrict`]) and `e` is 0 off
    /// the coarse unknowns, so `D . P e = 2 e . f` exactly, with no fine values read.
    /// The denominator needs only the fine mask and `c`.
    fn step_length(&self, coarse: &Level, workers: usize) -> Result<f64, GridError> {
        let cf = coarse
            .f
            .as_ref()
            .expect("coarse levels have a right-hand side");
        let nums = map_bounded(&coarse.spec.block_indices(), workers, |&cb| {
            let e = coarse.u[0].read_block(cb)?;
            let f = cf.read_block(cb)?;
            Ok::<_, GridError>(e.iter().zip(&f).map(|(a, b)| a * b).sum::<f64>())
        })?;
        let num = 2.0 * nums.into_iter().sum::<f64>();
        let den = if let (Some(f), Some(c)) = (Flat::of(self), Flat::of(coarse)) {
            f.correction_energy(&c)
        } else {
            let spec = &self.spec;
            let dens = map_bounded(&spec.block_indices(), workers, |&b| {
                let (origin, shape, _) = box_of(spec, b, 1);
                let mask = self.mask.read_region(origin, shape, 0)?;
                let (clo, cshape) = coarse_cover(origin, shape);
                let e = coarse.u[0].read_region(clo, cshape, 0.0)?;
                let (lo, hi) = block_within_box(spec, b, origin);
                let c = prolong(&e.data, clo, cshape, origin, shape);
                Ok(correction_energy(&mask.data, &c, shape, lo, hi))
            })?;
            dens.into_iter().sum::<f64>()
        };
        Ok(if den > 0.0 && num > 0.0 {
            (num / den).clamp(0.5, 4.0)
        } else {
            1.0
        })
    }

    /// Restrict the defect of `u[src]` into `coarse.f`, and zero `coarse.u[0]`.
    fn restrict_pass(&self, src: usize, coarse: &Level, workers: usize) -> Result<(), GridError> {
        let cf = coarse
            .f
            .as_ref()
            .expect("coarse levels have a right-hand side");
        map_bounded(&coarse.spec.block_indices(), workers, |&cb| {
            let cs = coarse.spec.block_start(cb).map(|c| c as i64);
            let csh = coarse.spec.block_shape(cb).map(|c| c as usize);
            let cmask = coarse.mask.read_block(cb)?;
            // Defects at fine nodes 2I - 1 ..= 2I + 1; u and mask one further out.
            let d_origin = cs.map(|c| 2 * c - 1);
            let d_shape = csh.map(|c| 2 * c + 1);
            let r_origin = d_origin.map(|c| c - 1);
            let r_shape = d_shape.map(|c| c + 2);
            let mut bx = self.read_box(src, r_origin, r_shape)?;
            let view = bx.view();
            let d = view.defects([1; 3], r_shape.map(|c| c - 1));
            let rhs = restrict(&d, d_origin, d_shape, &cmask, cs, csh);
            cf.write_block(cb, &rhs)?;
            coarse.u[0].write_block(cb, &vec![0.0; rhs.len()])
        })?;
        Ok(())
    }
}

impl Hierarchy {
    /// Build the coarse levels under `fine` (whose mask and generations are given):
    /// their masks from the fine mask, stores from `maker`, in memory where
    /// `in_memory(level)` says so.
    pub fn build(
        fine: Level,
        cycle: CycleOptions,
        maker: &impl StoreMaker,
        in_memory: impl Fn(usize, &GridSpec) -> bool,
        workers: usize,
    ) -> Result<Self, GridError> {
        let specs = coarse_specs(&fine.spec, cycle.coarsest);
        let mut levels = vec![fine];
        for (k, spec) in specs.into_iter().enumerate() {
            let lvl = k + 1;
            let mem = in_memory(lvl, &spec);
            let mask = maker.make::<u8>(&format!("mask{lvl}"), &spec, mem, 0)?;
            let above = levels.last().expect("a finer level");
            map_bounded(&spec.block_indices(), workers, |&cb| {
                let cs = spec.block_start(cb).map(|c| 2 * c as i64);
                let csh = spec.block_shape(cb).map(|c| c as usize);
                let fine = above.mask.read_region(cs, csh.map(|c| 2 * c - 1), 0)?;
                let mut m = Vec::with_capacity(csh.iter().product());
                for z in 0..csh[0] {
                    for y in 0..csh[1] {
                        for x in 0..csh[2] {
                            let v = fine.data[fine.offset(2 * z, 2 * y, 2 * x)];
                            // Nodes on the level's edge stay fixed, so every unknown
                            // has its six neighbours inside the grid.
                            let g = [z, y, x].map(|c| c as u64);
                            let edge = (0..3).any(|a| {
                                let c = spec.block_start(cb)[a] + g[a];
                                c == 0 || c + 1 >= spec.shape[a]
                            });
                            m.push(if v == INTERIOR && !edge { INTERIOR } else { 0 });
                        }
                    }
                }
                mask.write_block(cb, &m)
            })?;
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
                flat: super::flat::Cache::default(),
            });
        }
        Ok(Self {
            levels,
            cycle,
            workers,
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

    /// Levels `k` and `k + 1` as whole arrays, when both are held so: their passes then
    /// run in place on the arrays ([`super::flat`]), with the same results.
    fn flat(&self, k: usize) -> Option<(Flat<'_>, Flat<'_>)> {
        let c = self.levels.get(k + 1)?;
        Some((Flat::of(&self.levels[k])?, Flat::of(c)?))
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
        let r = self.fused(0);
        let m = if measure {
            Measure::Before
        } else {
            Measure::None
        };
        self.levels[0].smooth_pass(0, 1, c.pre, 1.0, None, m, Change::None, r, self.workers)
    }

    /// The rest of the V-cycle: coarse-grid correction and post-smoothing back into
    /// generation 0. Returns the largest change of the whole cycle and the residual of
    /// the new state (so that the loop can decide before the next cycle's first pass).
    pub fn finish_cycle(&self) -> Result<(f64, PassStats), GridError> {
        self.correct_and_smooth(0)
    }

    fn correct_and_smooth(&self, k: usize) -> Result<(f64, PassStats), GridError> {
        let (lvl, coarse, w) = (&self.levels[k], &self.levels[k + 1], self.workers);
        if self.fused(k).is_none() {
            lvl.restrict_pass(1, coarse, w)?;
        }
        self.cycle_level(k + 1)?;
        let (change, measure) = if k == 0 {
            (Change::Dst, Measure::After)
        } else {
            (Change::None, Measure::None)
        };
        let alpha = lvl.step_length(coarse, w)?;
        if let Some((f, c)) = self.flat(k) {
            let (max_change, (res_sq, count)) = f.post(self.cycle.post, &c, alpha, k == 0, k == 0);
            let st = PassStats {
                res_sq,
                count,
                max_change,
            };
            return Ok((max_change, st));
        }
        let post = lvl.smooth_pass(
            1,
            0,
            self.cycle.post,
            1.0,
            Some((coarse, alpha)),
            measure,
            change,
            None,
            w,
        )?;
        Ok((post.max_change, post))
    }

    /// A V-cycle on coarse level `k`, from its generation 0 (zero) back into it.
    fn cycle_level(&self, k: usize) -> Result<(), GridError> {
        let lvl = &self.levels[k];
        let w = self.workers;
        if k + 1 == self.levels.len() {
            // Coarsest (one block): relax it nearly to convergence, in place.
            let n = lvl.spec.shape.iter().copied().max().unwrap_or(2);
            let sweeps = (4 * n as usize).max(20);
            let omega = optimal_omega(n as f64);
            lvl.smooth_pass(
                0,
                0,
                sweeps,
                omega,
                None,
                Measure::None,
                Change::None,
                None,
                w,
            )?;
            return Ok(());
        }
        if let Some((f, c)) = self.flat(k) {
            f.pre(self.cycle.pre, false, &c);
            return self.correct_and_smooth(k).map(|_| ());
        }
        let r = self.fused(k);
        lvl.smooth_pass(
            0,
            1,
            self.cycle.pre,
            1.0,
            None,
            Measure::None,
            Change::None,
            r,
            w,
        )?;
        self.correct_and_smooth(k)?;
        Ok(())
    }
}

impl Level {
    /// One red-black SOR sweep from `u[src]` into `u[dst]` in a single pass (a halo of
    /// two), measuring the residual of the source and the sweep's largest change.
    pub fn sor_pass(
        &self,
        src: usize,
        dst: usize,
        omega: f64,
        workers: usize,
    ) -> Result<PassStats, GridError> {
        self.smooth_pass(
            src,
            dst,
            1,
            omega,
            None,
            Measure::Before,
            Change::Src,
            None,
            workers,
        )
    }
}
