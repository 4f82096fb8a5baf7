//! The paper's iteration: every unknown becomes the mean of its six neighbours (one
//! Jacobi sweep per pass, ping-pong between the two generations), block by block with a
//! one-voxel halo.

use super::blocks::BlockLoop;
use super::boxops::BoxView;
use super::cuts::is_unknown;
use super::level::{Level, PassStats};
use crate::grid::{GridError, Reach};

/// One Jacobi iteration from `u[src]` into `u[dst]`, measuring the residual of the
/// source and the largest change (which is the largest |residual|).
pub fn jacobi_pass(
    l: &Level,
    src: usize,
    dst: usize,
    blocks: &BlockLoop<'_>,
) -> Result<PassStats, GridError> {
    let spec = &l.spec;
    let st = blocks.stats(spec, |b| {
        let mut u = l.u[src].read_block_halo(b, 1, 0.0)?;
        let mask = l.mask.read_block_halo(b, 1, 0)?;
        let cuts = match &l.cuts {
            Some(c) => Some(c.read_block_halo(b, 1, 0)?),
            None => None,
        };
        let shape = u.shape;
        let view = BoxView {
            u: &mut u.data,
            mask: &mask.data,
            f: None,
            cuts: cuts.as_ref().map(|c| &c.data[..]),
            shape,
            origin: u.origin,
        };
        let lo = [1; 3];
        let hi = shape.map(|c| c - 1);
        let d = view.steps(lo, hi);
        let inner = mask.crop(lo, spec.block_shape(b).map(|c| c as usize));
        let old = u.crop(lo, spec.block_shape(b).map(|c| c as usize));
        let mut st = PassStats::default();
        let new: Vec<f64> = old
            .iter()
            .zip(&d)
            .zip(&inner)
            .map(|((&o, &d), &m)| {
                if is_unknown(m) {
                    let r = d;
                    st.res_sq += r * r;
                    st.count += 1;
                    st.max_change = st.max_change.max(r.abs());
                    o + r
                } else {
                    o
                }
            })
            .collect();
        l.u[dst].write_block(b, &new)?;
        Ok(st)
    })?;
    blocks.exchange(&l.field(&format!("u{dst}")), &*l.u[dst], &Reach::Halo(1))?;
    Ok(st)
}
