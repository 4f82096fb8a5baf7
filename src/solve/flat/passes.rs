//! The pre- and post-smoothing passes of a V-cycle on a level held as arrays, with
//! the restriction and the correction they include.

use std::sync::atomic::Ordering;
use std::sync::RwLockReadGuard;

use rayon::prelude::*;

use super::prolong::prolong_add;
use super::restrict::restrict;
use super::runs::dims;
use super::smooth::sweeps;
use super::stats::{plane_stats, PlaneStats};
use super::Flat;
use crate::grid::Array;
use crate::solve::cuts::CutArrays;

/// The read guards of a level's arms and mask, for [`Flat::cut_arrays`].
type CutGuards<'a> = Option<(
    RwLockReadGuard<'a, Array<u64>>,
    RwLockReadGuard<'a, Array<u8>>,
)>;

impl Flat<'_> {
    /// The arms and the mask of a level with cuts, held for a pass.
    fn cut_guards(&self) -> CutGuards<'_> {
        self.arms.map(|a| (a.array(), self.mask.array()))
    }

    /// The cut unknowns' arrays from [`Flat::cut_guards`].
    fn cut_arrays<'g>(&self, g: &'g CutGuards<'_>) -> Option<CutArrays<'g>> {
        g.as_ref().map(|(arms, mask)| CutArrays {
            arms,
            mask,
            coarse: self.f.is_some(),
        })
    }

    /// Pre-smoothing: generation 1 = generation 0 after `n` sweeps; with `measure`, the
    /// residual of generation 0 first; then the restriction of the defect into
    /// `coarse` (its right-hand side, and a zero correction in its generation 0).
    #[must_use]
    pub(crate) fn pre(&self, n: usize, measure: bool, coarse: &Flat<'_>) -> PlaneStats {
        let st = self.pre_sweeps(n, measure);
        self.restrict_into(coarse);
        st
    }

    /// The sweeps of [`Flat::pre`] (and its residual), without the restriction: on MPI
    /// ranks generation 1's halo is exchanged between the two.
    #[must_use]
    pub(crate) fn pre_sweeps(&self, n: usize, measure: bool) -> PlaneStats {
        let shape = dims(self.spec);
        let f = self.f.map(|f| f.array());
        let f = f.as_deref().map(std::ops::Deref::deref);
        let guards = self.cut_guards();
        let cut = self.cut_arrays(&guards);
        let u0 = self.u[0].array();
        let st = plane_stats(
            self.spec,
            &u0,
            None,
            self.runs(),
            (f, cut),
            measure,
            &self.own(),
        );
        let mut u1 = self.u[1].array_mut();
        // Generation 1 holds the fixed values once it has been written whole.
        let fixed = self.cache.fixed_in_both.swap(true, Ordering::Relaxed);
        sweeps(
            &mut u1,
            Some((&u0, fixed)),
            self.runs(),
            (f, cut),
            shape,
            n,
            &self.compute(),
        );
        st
    }

    /// The restriction of [`Flat::pre`]: the defect of generation 1 into `coarse`'s
    /// right-hand side, and a zero correction in its generation 0 (on its own planes).
    pub fn restrict_into(&self, coarse: &Flat<'_>) {
        let shape = dims(self.spec);
        let f = self.f.map(|f| f.array());
        let f = f.as_deref().map(std::ops::Deref::deref);
        let guards = self.cut_guards();
        let cut = self.cut_arrays(&guards);
        let u1 = self.u[1].array();
        let cmask = coarse.mask.array();
        let mut cf = coarse
            .f
            .expect("coarse levels have a right-hand side")
            .array_mut();
        restrict(
            shape,
            &u1,
            self.runs(),
            (f, cut),
            dims(coarse.spec),
            &cmask,
            &mut cf,
            &self.cache.planes,
            coarse.own(),
        );
        let cp = coarse.spec.shape[1] as usize * coarse.spec.shape[2] as usize;
        let own = coarse.own();
        coarse.u[0].array_mut()[own.start * cp..own.end * cp]
            .par_iter_mut()
            .for_each(|v| *v = 0.0);
    }

    /// Correction and post-smoothing: generation 0 = generation 1 plus `alpha` times the
    /// interpolated correction of `coarse`, after `n` sweeps. Returns the largest change
    /// against generation 0's previous content (with `change`) and the residual of the
    /// result (with `measure`), on the planes this process owns.
    pub(crate) fn post(
        &self,
        n: usize,
        coarse: &Flat<'_>,
        alpha: f64,
        change: bool,
        measure: bool,
    ) -> PlaneStats {
        let shape = dims(self.spec);
        let f = self.f.map(|f| f.array());
        let f = f.as_deref().map(std::ops::Deref::deref);
        let guards = self.cut_guards();
        let cut = self.cut_arrays(&guards);
        let mut u1 = self.u[1].array_mut();
        {
            let e = coarse.u[0].array();
            prolong_add(
                shape,
                &mut u1,
                self.runs(),
                dims(coarse.spec),
                &e,
                alpha,
                &self.cache.prolong,
            );
        }
        sweeps(
            &mut u1,
            None,
            self.runs(),
            (f, cut),
            shape,
            n,
            &self.compute(),
        );
        let mut u0 = self.u[0].array_mut();
        // The result becomes generation 0; generation 1 keeps the old state, which the
        // next pre-smoothing overwrites.
        std::mem::swap(&mut *u0, &mut *u1);
        // The largest change against the old state and the residual of the new one, in
        // one pass.
        let old = change.then_some(&u1[..]);
        plane_stats(
            self.spec,
            &u0,
            old,
            self.runs(),
            (f, cut),
            measure,
            &self.own(),
        )
    }
}
