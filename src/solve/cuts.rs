//! The sub-voxel boundary: the Shortley-Weller stencil at the unknowns next to the
//! boundary, from the arm fractions of the run's `cuts` array
//! ([`crate::voxelize::cuts`]).
//!
//! Where a run has `cuts` (mesh inputs), the finest level's mask is derived from the
//! labels and the arms: every solid voxel outside the center ball is an unknown (the
//! boundary voxels too: their centers lie inside the surface, so phi < 1 there), marked
//! [`CUT`] when an arm of it is cut, else `INTERIOR`. Along each axis the equation at a
//! cut unknown is the 1-D second difference with unequal arms (Shortley and Weller
//! 1938; Gibou, Fedkiw, Cheng and Kang 2002, section 3):
//!
//! `2 / (h_l + h_r) * ((u_r - u) / h_r - (u - u_l) / h_l)`, in voxels,
//!
//! with the Dirichlet value placed at the crossing: u = 0 (phi = 1) on the surface,
//! u = 1 (phi = 0) on the center ball's sphere. An arm that is not cut has length 1 and
//! reads the neighbour. Summed over the axes this is `b + sum_k c_k u_k - diag u`
//! ([`Coef`]); without cuts it is the 7-point defect `sum u_k - 6 u`. Every coefficient
//! is positive and `diag >= sum_k c_k`, so the matrix is still an M-matrix and the
//! discrete maximum principle holds (u between 0 and 1, phi monotone along the
//! streamlines' way down). The voxelizer clamps arms at 1/1023 voxel, which bounds
//! the diagonal (at most about 2000 times the usual 6).
//!
//! The coarse levels see the same boundary ([`super::coarsen::coarse_arms`]): coarse
//! node `I` sits on fine node `2I`, and its arm along an axis ends where the fine arms
//! from `2I` or from `2I ± 1` end (half their length, or half plus a half), or at a
//! fine node between them that is fixed. Their equation is the same Shortley-Weller
//! stencil in coarse units, for a correction that is 0 on the boundary
//! ([`Coef::coarse`]), so the coarse-grid correction knows where the boundary is
//! instead of seeing the staircase of the coarsened mask. Label volumes have no `cuts`,
//! and their solve is the staircase on every level.

// The stencil's terms are named as in the formula (u, b, c, k, t, w).
#![allow(clippy::many_single_char_names)]

use crate::voxelize::cuts::arm;
use crate::voxelize::labels::{CENTER, INTERIOR};

/// Mask value of the finest level for an unknown with a cut arm (never a label).
pub const CUT: u8 = 8;

/// Whether mask value `m` is an unknown of the solve.
#[inline]
#[must_use]
pub fn is_unknown(m: u8) -> bool {
    m == INTERIOR || m == CUT
}

/// The mask value of a voxel of label `label` whose packed arms are `p`, in a run with
/// cuts: solid voxels outside the center ball are unknowns.
#[inline]
#[must_use]
pub fn fine_mask(label: u8, p: u64) -> u8 {
    use crate::voxelize::labels::BOUNDARY;
    match label {
        BOUNDARY | INTERIOR if p != 0 => CUT,
        BOUNDARY | INTERIOR => INTERIOR,
        l => l,
    }
}

/// The equation at a cut unknown: `diag u = b + sum_k c_k u_k`, neighbours in the order
/// x-, x+, y-, y+, z-, z+ (`c_k = 0` on a cut arm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Coef {
    /// Weights of the neighbours' values.
    pub c: [f64; 6],
    /// The boundary values' part.
    pub b: f64,
    /// The diagonal.
    pub diag: f64,
}

impl Coef {
    /// The coefficients of packed arms `p`, with the neighbours' mask values `nb` (a cut
    /// arm to the center ball ends at u = 1, any other at u = 0).
    #[must_use]
    pub fn of(p: u64, nb: [u8; 6]) -> Self {
        let mut c = [0.0; 6];
        let (mut b, mut diag) = (0.0, 0.0);
        for a in 0..3 {
            let (kl, kr) = (2 * a, 2 * a + 1);
            let t = [kl, kr].map(|k| {
                let t = arm(p, k);
                if t > 0.0 {
                    t
                } else {
                    1.0
                }
            });
            let w = 2.0 / (t[0] + t[1]);
            for (j, k) in [kl, kr].into_iter().enumerate() {
                let g = w / t[j];
                diag += g;
                if arm(p, k) > 0.0 {
                    if nb[k] == CENTER {
                        b += g;
                    }
                } else {
                    c[k] = g;
                }
            }
        }
        Self { c, b, diag }
    }

    /// The coefficients of a coarse level's packed arms `p`, whose neighbours are
    /// unknowns where `unknown` says so: a coarse level holds a correction, 0 at the
    /// crossings, so there is no boundary part, and a cut arm reads its neighbour only
    /// when that is fixed (it holds 0 then, except in full multigrid's coarse phase,
    /// where it holds the problem's value there: the value at the crossing, nearly).
    #[must_use]
    pub fn coarse(p: u64, unknown: [bool; 6]) -> Self {
        let mut k = Self::of(p, [INTERIOR; 6]);
        for (a, &unknown) in unknown.iter().enumerate() {
            let t = arm(p, a);
            if t > 0.0 && !unknown {
                // The other arm along the same axis.
                let o = arm(p, a ^ 1);
                let o = if o > 0.0 { o } else { 1.0 };
                k.c[a] = 2.0 / (t + o) / t;
            }
        }
        k.b = 0.0;
        k
    }

    /// The coefficients at offset `i` of C-order arrays with strides `sy`, `sz`.
    #[inline]
    #[must_use]
    pub fn at(cuts: &[u64], mask: &[u8], i: usize, sy: usize, sz: usize) -> Self {
        let nb = [i - 1, i + 1, i - sy, i + sy, i - sz, i + sz].map(|j| mask[j]);
        Self::of(cuts[i], nb)
    }

    /// The coefficients of the packed arms `p` of the voxel at offset `h` of a haloed
    /// mask with strides `sy`, `sz`.
    #[must_use]
    pub fn at_haloed(p: &u64, mask: &[u8], h: usize, sy: usize, sz: usize) -> Self {
        let nb = [h - 1, h + 1, h - sy, h + sy, h - sz, h + sz].map(|j| mask[j]);
        Self::of(*p, nb)
    }

    /// The defect `b + sum_k c_k u_k - diag u` with the neighbours' values `nb`.
    #[inline]
    #[must_use]
    pub fn defect(&self, nb: [f64; 6], u: f64) -> f64 {
        let mut s = self.b;
        for (c, v) in self.c.iter().zip(nb) {
            s += c * v;
        }
        s - self.diag * u
    }
}

/// A level's arms and mask (a box of them, or whole arrays), for the equation at its
/// cut unknowns: [`Coef::of`] on the finest level, [`Coef::coarse`] with the
/// right-hand side on a coarse level (`coarse`). The block passes and the whole-array
/// passes both call it, so both do the same arithmetic.
#[derive(Clone, Copy)]
pub struct CutArrays<'a> {
    /// The packed arms.
    pub arms: &'a [u64],
    /// The mask.
    pub mask: &'a [u8],
    /// A coarse level: a correction with a right-hand side.
    pub coarse: bool,
}

impl CutArrays<'_> {
    /// The defect and the diagonal at the cut unknown at offset `i` (strides `sy`,
    /// `sz`), whose neighbours hold `nb` (x-, x+, y-, y+, z-, z+) and itself `u`, with
    /// the right-hand side `f` (coarse levels).
    #[inline]
    #[must_use]
    pub fn defect(
        &self,
        i: usize,
        sy: usize,
        sz: usize,
        nb: [f64; 6],
        u: f64,
        f: f64,
    ) -> (f64, f64) {
        let at = [i - 1, i + 1, i - sy, i + sy, i - sz, i + sz];
        if self.coarse {
            let k = Coef::coarse(self.arms[i], at.map(|j| is_unknown(self.mask[j])));
            (f + k.defect(nb, u), k.diag)
        } else {
            let k = Coef::of(self.arms[i], at.map(|j| self.mask[j]));
            (k.defect(nb, u), k.diag)
        }
    }

    /// [`CutArrays::defect`] with the neighbours read from the whole array `u`.
    #[inline]
    #[must_use]
    pub fn defect_in(
        &self,
        u: &[f64],
        f: Option<&[f64]>,
        i: usize,
        sy: usize,
        sz: usize,
    ) -> (f64, f64) {
        let nb = [i - 1, i + 1, i - sy, i + sy, i - sz, i + sz].map(|j| u[j]);
        self.defect(i, sy, sz, nb, u[i], f.map_or(0.0, |f| f[i]))
    }
}

#[cfg(test)]
#[allow(clippy::float_cmp)] // quantized values and exact coefficients, compared exactly on purpose
mod tests {
    use super::*;
    use crate::voxelize::cuts::encode;
    use crate::voxelize::labels::LAYER1;

    #[test]
    fn uncut_arms_give_the_seven_point_stencil() {
        let k = Coef::of(0, [INTERIOR; 6]);
        assert_eq!(k.c, [1.0; 6]);
        assert_eq!((k.b, k.diag), (0.0, 6.0));
    }

    #[test]
    fn unequal_arms_are_exact_for_quadratics_and_keep_an_m_matrix() {
        // u = (x - 0.3)^2 / 2 along x, with the boundary at x = 0.4 (arm x+ of 0.4):
        // the 1-D second difference with unequal arms is exact for quadratics (u'' = 1).
        let p = encode([0.0, 0.4, 0.0, 0.0, 0.0, 0.0]);
        let k = Coef::of(
            p,
            [INTERIOR, LAYER1, INTERIOR, INTERIOR, INTERIOR, INTERIOR],
        );
        let q = |x: f64| (x - 0.3) * (x - 0.3) / 2.0;
        // The arm as stored (0.4 rounded to 1/1023).
        let t = arm(p, 1);
        assert!((t - 0.4).abs() < 0.5 / 1023.0);
        // The surface's value enters through b, which is for u = 0 there: add it.
        let w = 2.0 / (1.0 + t);
        let d = k.defect([q(-1.0), 0.0, 0.0, 0.0, 0.0, 0.0], q(0.0)) + w / t * q(t);
        // The y and z arms see u = 0 around a value q(0): they add -4 q(0).
        assert!((d + 4.0 * q(0.0) - 1.0).abs() < 1e-12, "{d}");
        let sum: f64 = k.c.iter().sum::<f64>() + w / t;
        assert!((k.diag - sum).abs() < 1e-12);
        assert_eq!(k.c[1], 0.0);
        // A cut arm to the center ball carries u = 1.
        let kc = Coef::of(
            p,
            [INTERIOR, CENTER, INTERIOR, INTERIOR, INTERIOR, INTERIOR],
        );
        assert!((kc.b - w / t).abs() < 1e-12);
        assert_eq!(fine_mask(crate::voxelize::labels::BOUNDARY, p), CUT);
        assert_eq!(fine_mask(INTERIOR, 0), INTERIOR);
        assert_eq!(fine_mask(CENTER, p), CENTER);
    }

    #[test]
    fn a_coarse_cut_arm_reads_a_fixed_neighbour_and_has_no_boundary_part() {
        let p = encode([0.0, 0.4, 0.25, 0.0, 0.0, 0.0]);
        let fine = Coef::of(
            p,
            [INTERIOR, CENTER, INTERIOR, INTERIOR, INTERIOR, INTERIOR],
        );
        // x+ cut towards a fixed node, y- cut towards an unknown (the line re-enters).
        let k = Coef::coarse(p, [true, false, true, true, true, true]);
        assert_eq!(k.b, 0.0);
        assert_eq!(k.diag, fine.diag);
        // Along x the other arm is not cut (length 1).
        let t = arm(p, 1);
        assert!((k.c[1] - 2.0 / (1.0 + t) / t).abs() < 1e-12, "{:?}", k.c);
        assert_eq!(k.c[2], 0.0);
        assert_eq!(
            [k.c[0], k.c[3], k.c[4], k.c[5]],
            [fine.c[0], fine.c[3], fine.c[4], fine.c[5]]
        );
        // With every fixed value 0 (a correction) it is the fine stencil without b.
        let nb = [0.3, 0.0, 0.7, 0.2, 0.1, 0.5];
        let homogeneous = Coef { b: 0.0, ..fine };
        assert!((k.defect(nb, 0.4) - homogeneous.defect(nb, 0.4)).abs() < 1e-12);
    }
}
