//! The grid transfers of a V-cycle over blocks: full-weighting restriction of the
//! fine defect into the coarse right-hand side, and the length of the interpolated
//! coarse correction (the prolongation itself is added by the smoothing pass that
//! follows, [`super::smooth`]).

use super::blocks::BlockLoop;
use super::boxops::{correction_energy, prolong, restrict, BoxView};
use super::level::{block_within_box, box_of, coarse_cover, Level};
use crate::grid::GridError;
use crate::math::Idx3;

/// Restrict the defect of a smoothed fine box into the coarse block `b` of `c` (the
/// coarse block under the fine block `b`), and zero the coarse correction there.
#[allow(clippy::many_single_char_names)] // grid axes (z, y, x) and stencil terms named as in the formulas
pub(super) fn restrict_block(view: &BoxView<'_>, c: &Level, b: Idx3) -> Result<(), GridError> {
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

impl Level {
    /// The energy-minimizing length of the coarse correction: with `c = P e` the
    /// interpolated correction (on the unknowns) and `D` the defect of the smoothed
    /// state, `alpha = (D . c) / (c . A c)`.
    ///
    /// The numerator is taken on the coarse level: the restriction's weights are those
    /// of trilinear interpolation (`f = P^T D / 2`, see [`restrict`]) and `e` is 0 off
    /// the coarse unknowns, so `D . P e = 2 e . f` exactly, with no fine values read.
    /// The denominator needs only the fine mask and `c`.
    pub fn step_length(&self, coarse: &Level, blocks: &BlockLoop<'_>) -> Result<f64, GridError> {
        let cf = coarse
            .f
            .as_ref()
            .expect("coarse levels have a right-hand side");
        let num = 2.0
            * blocks.sum(&coarse.spec, |cb| {
                let e = coarse.u[0].read_block(cb)?;
                let f = cf.read_block(cb)?;
                Ok(e.iter().zip(&f).map(|(a, b)| a * b).sum::<f64>())
            })?;
        let den = if let Some((f, c)) = self.flat_with(coarse, blocks) {
            match &self.slab {
                Some(s) => {
                    let parts = f.correction_energy_blocks(&c, s.layers.clone());
                    blocks.gather(&self.spec, parts)?.into_iter().sum()
                }
                None => f.correction_energy(&c),
            }
        } else {
            let spec = &self.spec;
            let occupied = self.occupied(blocks)?;
            blocks.sum(spec, |b| {
                // No unknowns, no energy.
                if occupied.is_some_and(|o| !o[spec.block_linear(b) as usize]) {
                    return Ok(0.0);
                }
                let (origin, shape, _) = box_of(spec, b, 1);
                let mask = self.mask.read_region(origin, shape, 0)?;
                let (clo, cshape) = coarse_cover(origin, shape);
                let e = coarse.u[0].read_region(clo, cshape, 0.0)?;
                let (lo, hi) = block_within_box(spec, b, origin);
                let c = prolong(&e.data, clo, cshape, origin, shape);
                Ok(correction_energy(&mask.data, &c, shape, lo, hi))
            })?
        };
        Ok(if den > 0.0 && num > 0.0 {
            (num / den).clamp(0.5, 4.0)
        } else {
            1.0
        })
    }

    /// Restrict the defect of `u[src]` into `coarse.f`, and zero `coarse.u[0]`.
    pub fn restrict_pass(
        &self,
        src: usize,
        coarse: &Level,
        blocks: &BlockLoop<'_>,
    ) -> Result<(), GridError> {
        let cf = coarse
            .f
            .as_ref()
            .expect("coarse levels have a right-hand side");
        blocks.each(&coarse.spec, |cb| {
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
        coarse.exchange_rhs(blocks)
    }

    /// After this coarse level's right-hand side and zero correction were written:
    /// exchange both.
    pub(super) fn exchange_rhs(&self, blocks: &BlockLoop<'_>) -> Result<(), GridError> {
        if let Some(f) = &self.f {
            blocks.exchange(&self.field("f"), &**f, &self.reach)?;
        }
        blocks.exchange(&self.field("u0"), &*self.u[0], &self.reach)
    }
}
