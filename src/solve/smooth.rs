//! Smoothing passes over the blocks of a level: red-black Gauss-Seidel (or SOR) sweeps
//! of each block read with a halo wide enough for all of them (temporal blocking: the
//! valid region shrinks by one voxel a half-sweep), optionally after adding the
//! interpolated coarse correction, optionally measuring the residual and the largest
//! change, optionally restricting the smoothed defect into the coarse level on the way.

use super::blocks::BlockLoop;
use super::boxops::prolong_add;
use super::cuts::is_unknown;
use super::level::{box_of, coarse_cover, Change, Level, Measure, PassStats};
use super::transfer::restrict_block;
use crate::grid::GridError;
use crate::math::Idx3;

/// One smoothing pass: from generation `src` into `dst` of a level.
#[derive(Clone, Copy)]
pub struct Smooth<'a> {
    /// Generation read.
    pub src: usize,
    /// Generation written (may be `src` for a level in one block).
    pub dst: usize,
    /// Red-black sweeps.
    pub sweeps: usize,
    /// Over-relaxation factor (1: Gauss-Seidel).
    pub omega: f64,
    /// Add `alpha` times the interpolated correction of this coarse level first.
    pub coarse: Option<(&'a Level, f64)>,
    /// Which residual to measure.
    pub measure: Measure,
    /// Which largest change to measure.
    pub change: Change,
    /// Restrict the smoothed defect into this coarse level (each fine block over one
    /// coarse block).
    pub restrict_into: Option<&'a Level>,
}

impl Smooth<'_> {
    /// `sweeps` Gauss-Seidel sweeps from `src` into `dst`, measuring nothing.
    #[must_use]
    pub fn new(src: usize, dst: usize, sweeps: usize) -> Self {
        Smooth {
            src,
            dst,
            sweeps,
            omega: 1.0,
            coarse: None,
            measure: Measure::None,
            change: Change::None,
            restrict_into: None,
        }
    }
}

impl Level {
    /// Pass 1 or 3 on one block: read `u[src]` over the haloed box, optionally add the
    /// interpolated correction of `coarse`, do `sweeps` sweeps, write the block to
    /// `u[dst]`; measure the residual of what was read or of what is written
    /// (`measure`); with `change`, also the largest change against the block's content
    /// in `u[dst]`.
    fn smooth_block(&self, b: Idx3, pass: &Smooth<'_>) -> Result<PassStats, GridError> {
        let Smooth {
            src,
            dst,
            sweeps,
            omega,
            coarse,
            measure,
            change,
            restrict_into,
        } = *pass;
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
                if is_unknown(l) {
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

    /// A smoothing pass over the owned blocks, reduced in block order; then the fields
    /// it wrote are exchanged.
    pub fn smooth_pass(
        &self,
        pass: &Smooth<'_>,
        blocks: &BlockLoop<'_>,
    ) -> Result<PassStats, GridError> {
        // A block without unknowns is copied unchanged, so once both generations agree
        // on such blocks the pass need not visit them (the fused restriction's coarse
        // block under it has no unknowns either: its right-hand side and correction
        // are zero).
        let occupied = self.occupied(blocks)?;
        let skip = occupied.filter(|_| self.flat.synced() && pass.src != pass.dst);
        let st = blocks.stats(&self.spec, |b| {
            if skip.is_some_and(|o| !o[self.spec.block_linear(b) as usize]) {
                if let Some(c) = pass.restrict_into {
                    c.zero_block(b)?;
                }
                return Ok(PassStats::default());
            }
            self.smooth_block(b, pass)
        })?;
        if occupied.is_some() && pass.src != pass.dst {
            self.flat.set_synced();
        }
        blocks.exchange(
            &self.field(&format!("u{}", pass.dst)),
            &*self.u[pass.dst],
            &self.reach,
        )?;
        if let Some(c) = pass.restrict_into {
            c.exchange_rhs(blocks)?;
        }
        Ok(st)
    }

    /// One red-black SOR sweep from `u[src]` into `u[dst]` in a single pass (a halo of
    /// two), measuring the residual of the source and the sweep's largest change.
    pub fn sor_pass(
        &self,
        src: usize,
        dst: usize,
        omega: f64,
        blocks: &BlockLoop<'_>,
    ) -> Result<PassStats, GridError> {
        let pass = Smooth {
            omega,
            measure: Measure::Before,
            change: Change::Src,
            ..Smooth::new(src, dst, 1)
        };
        self.smooth_pass(&pass, blocks)
    }
}
