//! Geometric multigrid on the masked domain, out of core: every level is a set of block
//! stores (mask, two generations of u, right-hand side), in memory or in
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
//! Full multigrid (`--cycle fmg`, the default) first solves the problem itself on the
//! coarse levels: the fixed values of the starting state are injected down (coarse
//! node `I` takes fine node `2I`'s value, unknowns 0, right-hand side 0), the coarsest
//! level is relaxed to convergence, and on each level from coarse to fine the level
//! below's solution is interpolated up as the start (the correction pass with length 1
//! and no sweeps, onto the unknowns at 0) and [`FMG_CYCLES`] V-cycles improve it, the
//! levels under it holding corrections as usual. On the finest level the loop of
//! [`super::driver`] goes on with V-cycles, each a finest-level iteration as before, so
//! the residual history, checkpoints and resume are those of V-cycles; only the first
//! iteration (the coarse phase) differs, and a resume never repeats it. Afterwards the
//! coarse levels hold corrections again (their fixed values 0).
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
use super::cuts::is_unknown;
use super::flat::{Flat, PlaneStats};
use super::level::{Change, Level, Measure, PassStats, Slab};
use super::smooth::Smooth;
use super::stencil::optimal_omega;
use crate::grid::{
    layer_planes, scratch, BlockStore, Decomposition, GridError, GridSpec, Reach, Residence, Scalar,
};

/// How multigrid starts (`--cycle`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Cycle {
    /// Full multigrid: the coarse levels' solutions, each interpolated up as the next
    /// one's start, then V-cycles on the finest level (to `--rtol`, or with `--rtol 0`
    /// until the algebraic error is small against the discretization error).
    #[default]
    Fmg,
    /// V-cycles from the starting state until `--rtol`.
    V,
}

impl Cycle {
    /// The name on the command line and in the run's attributes.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Cycle::Fmg => "fmg",
            Cycle::V => "v",
        }
    }
}

/// Cycle parameters.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CycleOptions {
    /// Full multigrid or V-cycles.
    #[serde(default)]
    pub kind: Cycle,
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
            kind: Cycle::default(),
        }
    }
}

/// Where the stores of a level live: whole arrays in memory, or scratch
/// files in a directory (through [`crate::grid::scratch`]).
pub struct Scratch {
    /// Directory of the scratch files.
    pub dir: PathBuf,
}

impl Scratch {
    /// A new store of `T` for `spec` reading `fill`, named `name` for its scratch file;
    /// `in_memory` chooses a whole array over a file. On MPI ranks too a level in
    /// memory is one array, whose passes run on the rank's slab
    /// ([`super::level::Slab`]) and touch only its planes and those it receives: the
    /// rest stays unwritten, and an array of zeros gets pages of its own that are not
    /// resident until written ([`crate::grid::Array`]).
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

/// V-cycles on each coarse level in full multigrid, after the interpolated start.
pub const FMG_CYCLES: usize = 1;

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

/// What a halo exchange of coarse level `k`'s fields (`levels[k]`, 0 the finest) must
/// make readable on each part of `decomp`: the planes within `halo` of the part's slab
/// of the level (its own passes), the planes under its slab of level `k - 1` (the
/// prolongation into that slab's blocks, and their halo), and the planes over its slab
/// of level `k + 1` (the restriction and injection into those blocks). The slabs of
/// levels that do not nest need not line up, so a part may read well past its own
/// slab, or own no block of the level and still read some.
#[must_use]
pub fn level_reach(levels: &[GridSpec], k: usize, halo: u64, decomp: &dyn Decomposition) -> Reach {
    let slab = |s: &GridSpec, p: usize| layer_planes(s, &decomp.z_layers(p, s.blocks()));
    Reach::Planes(
        (0..decomp.parts())
            .map(|p| {
                let mut w = Vec::new();
                if let Some(r) = slab(&levels[k], p) {
                    w.push(r.start.saturating_sub(halo)..r.end + halo);
                }
                // Fine plane z lies over coarse z / 2; the prolongation reads a coarse
                // plane either side.
                if let Some(r) = k.checked_sub(1).and_then(|f| slab(&levels[f], p)) {
                    w.push(
                        (r.start.saturating_sub(halo) / 2).saturating_sub(2)
                            ..(r.end + halo).div_ceil(2) + 3,
                    );
                }
                if let Some(r) = levels.get(k + 1).and_then(|c| slab(c, p)) {
                    w.push((2 * r.start).saturating_sub(halo + 2)..2 * r.end + halo + 2);
                }
                w
            })
            .collect(),
    )
}

/// The reach of level `k`'s exchanges ([`level_reach`]), or in one process, and for
/// the finest level (whose blocks nest with the next level's), the pass halo alone.
#[must_use]
pub fn reach_of(levels: &[GridSpec], k: usize, halo: u64, decomp: &dyn Decomposition) -> Reach {
    if k == 0 || decomp.parts() == 1 {
        Reach::Halo(halo)
    } else {
        level_reach(levels, k, halo, decomp)
    }
}

/// The share of level `k`'s planes the most loaded part holds (its slab and the planes
/// it receives), at most 1; 1 in one process.
#[must_use]
pub fn held_share(levels: &[GridSpec], k: usize, halo: u64, decomp: &dyn Decomposition) -> f64 {
    if decomp.parts() == 1 {
        return 1.0;
    }
    let s = &levels[k];
    let reach = reach_of(levels, k, halo, decomp);
    let planes = (0..decomp.parts())
        .map(|p| {
            let own = decomp.z_layers(p, s.blocks());
            let wanted = reach.wanted(s, p, &own);
            wanted.iter().map(|r| r.end - r.start).sum::<u64>()
        })
        .max()
        .unwrap_or(0);
    planes as f64 / s.shape[0].max(1) as f64
}

/// The planes this part computes and owns of a level held as one array: the hull of
/// the planes it reads (`reach`, which holds its slab and the halo around it).
pub(super) fn slab_of(spec: &GridSpec, reach: &Reach, decomp: &dyn Decomposition) -> Slab {
    let layers = decomp.z_layers(decomp.part(), spec.blocks());
    let own = layer_planes(spec, &layers).map_or(0..0, |r| r.start as usize..r.end as usize);
    let wanted = reach.wanted(spec, decomp.part(), &layers);
    let compute = match (wanted.first(), wanted.last()) {
        (Some(a), Some(b)) => a.start as usize..b.end as usize,
        _ => own.clone(),
    };
    Slab {
        compute,
        own,
        layers,
    }
}

/// Whether each block of level `f` lies over exactly one block of the coarser level
/// `c` (one block each, or as many blocks of half the edge).
fn nests(f: &GridSpec, c: &GridSpec) -> bool {
    let single = f.num_blocks() == 1 && c.num_blocks() == 1;
    single || f.blocks() == c.blocks() && (0..3).all(|a| c.chunk[a] * 2 == f.chunk[a])
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
        // On ranks every pass reads other ranks' blocks only within its halo, and the
        // slabs of the finest level and the next cover the same planes only when their
        // block layers along z do.
        if let (false, Some(c)) = (blocks.owns_all(), specs.first()) {
            let (lf, lc) = (fine.spec.blocks()[0], c.blocks()[0]);
            if lf != lc || lf > 1 && c.chunk[0] * 2 != fine.spec.chunk[0] {
                return Err(GridError::RankLayout(format!(
                    "on MPI ranks the solve needs each block layer of the finest level (along z) to lie over one of the next level, and blocks {} voxels high make coarse blocks {} high; voxelize with --chunk 32 or more (even), or solve in one process",
                    fine.spec.chunk[0], c.chunk[0]
                )));
            }
        }
        let halo = pass_halo(&cycle);
        let all: Vec<GridSpec> = std::iter::once(fine.spec.clone())
            .chain(specs.iter().cloned())
            .collect();
        let mut levels = vec![fine];
        for (k, spec) in specs.into_iter().enumerate() {
            let lvl = k + 1;
            let mem = in_memory(lvl, &spec);
            let reach = reach_of(&all, lvl, halo, blocks.decomp);
            let slab = (mem && !blocks.owns_all()).then(|| slab_of(&spec, &reach, blocks.decomp));
            let mask = maker.make::<u8>(&format!("mask{lvl}"), &spec, mem, 0)?;
            let above = levels.last().expect("a finer level");
            // The sub-voxel boundary reaches every level.
            let cuts = match above.cuts {
                Some(_) => Some(maker.make::<u64>(&format!("cuts{lvl}"), &spec, mem, 0)?),
                None => None,
            };
            coarsen_mask(
                above,
                &spec,
                (&*mask, cuts.as_deref()),
                &format!("mask@{lvl}"),
                &reach,
                &blocks,
            )?;
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
                cuts,
                flat: super::flat::Cache::default(),
                depth: lvl,
                halo,
                reach,
                slab,
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
        nests(f, c).then(|| &self.levels[k + 1])
    }

    /// Levels `k` and `k + 1` as whole arrays, when both are held so: their passes then
    /// run in place on the arrays ([`super::flat`]), with the same results. On MPI
    /// ranks (both levels with a [`Slab`]) they run on the rank's slab, with halo
    /// exchanges after each pass as the block passes do.
    fn flat(&self, k: usize) -> Option<(Flat<'_>, Flat<'_>)> {
        self.levels[k].flat_with(self.levels.get(k + 1)?, &self.blocks)
    }

    /// The numbers a whole-array pass of level `k` measured: in one process its sums
    /// over the whole array; on MPI ranks each rank's blocks, completed with the
    /// others' and added in block order (the same numbers).
    fn plane_numbers(&self, k: usize, st: &PlaneStats) -> Result<PassStats, GridError> {
        let lvl = &self.levels[k];
        match &lvl.slab {
            None => {
                let (max_change, res_sq, count) = st.whole(&lvl.spec);
                Ok(PassStats {
                    res_sq,
                    count,
                    max_change,
                })
            }
            Some(s) => self
                .blocks
                .reduce_stats(&lvl.spec, &st.per_block(&lvl.spec, s.layers.clone())),
        }
    }

    /// The first pass of a V-cycle on the finest level: pre-smoothing from generation 0
    /// into 1, measuring the residual of generation 0 when `measure` (the first cycle,
    /// and the first after a resume; later cycles had it measured by the cycle before).
    pub fn pre_smooth_fine(&self, measure: bool) -> Result<PassStats, GridError> {
        self.pre_pass(0, self.cycle.pre, measure)
    }

    /// Pre-smoothing of level `k` from generation 0 into 1 by `sweeps` sweeps (0: a
    /// copy), with the restriction of the defect into level `k + 1` when it can be
    /// fused; with `measure`, the residual of generation 0.
    fn pre_pass(&self, k: usize, sweeps: usize, measure: bool) -> Result<PassStats, GridError> {
        if let Some((f, coarse)) = self.flat(k) {
            let st = if f.slab.is_some() {
                // On a rank: the sweeps, generation 1's halo, then the restriction
                // (which reads fine planes past the slab where the levels do not nest).
                let st = f.pre_sweeps(sweeps, measure);
                let lvl = &self.levels[k];
                self.blocks
                    .exchange(&lvl.field("u1"), &*lvl.u[1], &lvl.reach)?;
                f.restrict_into(&coarse);
                self.levels[k + 1].exchange_rhs(&self.blocks)?;
                st
            } else {
                f.pre(sweeps, measure, &coarse)
            };
            // Nothing measured, nothing to add up (and no messages on ranks).
            if !measure {
                return Ok(PassStats::default());
            }
            return self.plane_numbers(k, &st);
        }
        let pass = Smooth {
            measure: if measure {
                Measure::Before
            } else {
                Measure::None
            },
            restrict_into: self.fused(k),
            ..Smooth::new(0, 1, sweeps)
        };
        self.levels[k].smooth_pass(&pass, &self.blocks)
    }

    /// The rest of the V-cycle: coarse-grid correction and post-smoothing back into
    /// generation 0. Returns the largest change of the whole cycle and the residual of
    /// the new state (so that the loop can decide before the next cycle's first pass).
    pub fn finish_cycle(&self) -> Result<(f64, PassStats), GridError> {
        self.correct_and_smooth(0)
    }

    fn correct_and_smooth(&self, k: usize) -> Result<(f64, PassStats), GridError> {
        self.restrict_unfused(k)?;
        self.cycle_level(k + 1)?;
        self.post_pass(k, self.cycle.post)
    }

    /// The restriction of level `k`'s defect (generation 1) into level `k + 1`, when the
    /// pre-smoothing pass could not do it.
    fn restrict_unfused(&self, k: usize) -> Result<(), GridError> {
        if self.fused(k).is_none() {
            let (lvl, coarse) = (&self.levels[k], &self.levels[k + 1]);
            lvl.restrict_pass(1, coarse, &self.blocks)?;
        }
        Ok(())
    }

    /// Generation 0 of level `k` = generation 1 plus the interpolated correction of
    /// level `k + 1` (at its best step length), after `sweeps` sweeps. On the finest
    /// level, the largest change against generation 0's old content and the residual of
    /// the result are measured.
    fn post_pass(&self, k: usize, sweeps: usize) -> Result<(f64, PassStats), GridError> {
        self.post_pass_with(k, sweeps, None)
    }

    /// [`Self::post_pass`] with the correction's length `alpha` (`None`: the best).
    fn post_pass_with(
        &self,
        k: usize,
        sweeps: usize,
        alpha: Option<f64>,
    ) -> Result<(f64, PassStats), GridError> {
        let (lvl, coarse, blocks) = (&self.levels[k], &self.levels[k + 1], &self.blocks);
        let (change, measure) = if k == 0 {
            (Change::Dst, Measure::After)
        } else {
            (Change::None, Measure::None)
        };
        let alpha = match alpha {
            Some(a) => a,
            None => lvl.step_length(coarse, blocks)?,
        };
        if let Some((f, c)) = self.flat(k) {
            let st = f.post(sweeps, &c, alpha, k == 0, k == 0);
            if f.slab.is_some() {
                self.blocks
                    .exchange(&lvl.field("u0"), &*lvl.u[0], &lvl.reach)?;
            }
            if k > 0 {
                return Ok((0.0, PassStats::default()));
            }
            let st = self.plane_numbers(k, &st)?;
            return Ok((st.max_change, st));
        }
        let pass = Smooth {
            coarse: Some((coarse, alpha)),
            measure,
            change,
            ..Smooth::new(1, 0, sweeps)
        };
        let post = lvl.smooth_pass(&pass, blocks)?;
        Ok((post.max_change, post))
    }

    /// Full multigrid's coarse phase, from the starting state in generation 0 of the
    /// finest level (see the module docs). Returns the residual of the starting state,
    /// and the largest change and the residual of the result (in generation 0).
    pub fn fmg_start(&self) -> Result<(PassStats, f64, PassStats), GridError> {
        // The residual of the start, and generation 1 = generation 0 (the fused
        // restriction it may do is undone below).
        let start = self.pre_pass(0, 0, true)?;
        for k in 0..self.levels.len() - 1 {
            self.inject(k)?;
        }
        let last = self.levels.len() - 1;
        self.cycle_level(last)?;
        for k in (1..last).rev() {
            self.post_pass_with(k, 0, Some(1.0))?;
            // The levels below hold corrections from here on: their generation 1 must
            // not keep the fixed values injected into it.
            for l in &self.levels[k + 1..] {
                l.flat.state_replaced();
            }
            for _ in 0..FMG_CYCLES {
                self.cycle_level(k)?;
            }
        }
        let (change, after) = self.post_pass_with(0, 0, Some(1.0))?;
        // The coarse levels go back to holding corrections (zero on their fixed nodes,
        // which their next pre-smoothing copies whole).
        for l in &self.levels[1..] {
            l.flat.state_replaced();
        }
        Ok((start, change, after))
    }

    /// The problem on level `k + 1` from level `k`'s: the fixed values of generation 0
    /// at the nodes under them (injection; NaN outside the domain becomes 0), the
    /// unknowns 0, into both generations, and a zero right-hand side.
    fn inject(&self, k: usize) -> Result<(), GridError> {
        let (fine, coarse) = (&self.levels[k], &self.levels[k + 1]);
        let spec = &coarse.spec;
        let rhs = coarse
            .f
            .as_ref()
            .expect("coarse levels have a right-hand side");
        self.blocks.each(spec, |cb| {
            let cs = spec.block_start(cb).map(|c| 2 * c as i64);
            let csh = spec.block_shape(cb).map(|c| c as usize);
            let above = fine.u[0].read_region(cs, csh.map(|c| 2 * c - 1), 0.0)?;
            let mask = coarse.mask.read_block(cb)?;
            let mut out = Vec::with_capacity(mask.len());
            for z in 0..csh[0] {
                for y in 0..csh[1] {
                    for x in 0..csh[2] {
                        let v = above.data[above.offset(2 * z, 2 * y, 2 * x)];
                        let unknown = is_unknown(mask[out.len()]);
                        out.push(if unknown || v.is_nan() { 0.0 } else { v });
                    }
                }
            }
            coarse.u[0].write_block(cb, &out)?;
            coarse.u[1].write_block(cb, &out)?;
            rhs.write_block(cb, &vec![0.0; out.len()])
        })?;
        self.blocks
            .exchange(&coarse.field("u0"), &*coarse.u[0], &coarse.reach)?;
        self.blocks
            .exchange(&coarse.field("u1"), &*coarse.u[1], &coarse.reach)?;
        self.blocks
            .exchange(&coarse.field("f"), &**rhs, &coarse.reach)?;
        coarse.flat.state_replaced();
        Ok(())
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
        self.pre_pass(k, self.cycle.pre, false)?;
        self.correct_and_smooth(k)?;
        Ok(())
    }
}
