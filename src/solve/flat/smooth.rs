//! Red-black sweeps of a whole array in place, parallel over slabs of z planes.

use rayon::prelude::*;

use super::runs::{row_of, slab_planes, Runs};
use crate::solve::cuts::CutArrays;
use crate::solve::stencil::defect_of;

/// One red-black half-sweep of `color` over the whole grid, in place. `f`: the
/// right-hand side (coarse levels).
///
/// The planes `1..nz-1` are cut into slabs, several per thread, relaxed in two rounds:
/// the even slabs, then the odd ones. A slab reads the planes next to it, which belong
/// to slabs of the other round (or are the grid's first and last planes), so a round
/// borrows its own slabs mutably and the others shared: no copies and no locks.
#[allow(clippy::many_single_char_names)] // grid axes (z, y, x) and stencil terms named as in the formulas
pub(super) fn half_sweep(
    u: &mut [f64],
    runs: &Runs,
    f: Option<&[f64]>,
    cut: Option<CutArrays<'_>>,
    shape: [usize; 3],
    color: usize,
    omega: f64,
) {
    let [nz, ny, nx] = shape;
    if nz < 3 || ny < 3 || nx < 3 {
        return;
    }
    let p = ny * nx;
    let w = omega / 6.0;
    let per = slab_planes(nz - 2);
    for round in 0..2 {
        // Piece 0 is plane 0, piece i (1 ..) slab i - 1 from plane 1 + (i - 1) per, the
        // last piece plane nz - 1.
        let (first, mut rest) = u.split_at_mut(p);
        let mut pieces = vec![first];
        while rest.len() > p {
            let (head, tail) = rest.split_at_mut(per.min(rest.len() / p - 1) * p);
            pieces.push(head);
            rest = tail;
        }
        pieces.push(rest);
        let last = pieces.len() - 1;
        let mut shared: Vec<Option<&[f64]>> = Vec::with_capacity(pieces.len());
        let mut work = Vec::new();
        for (i, piece) in pieces.into_iter().enumerate() {
            if i > 0 && i < last && (i - 1) % 2 == round {
                work.push((i, piece));
                shared.push(None);
            } else {
                shared.push(Some(piece));
            }
        }
        let shared = &shared;
        work.into_par_iter().for_each(|(i, part)| {
            let below = shared[i - 1].expect("the slabs next to a slab are in the other round");
            let above = shared[i + 1].expect("the slabs next to a slab are in the other round");
            let a = 1 + (i - 1) * per;
            let b = a + part.len() / p;
            for z in a..b {
                let k = z - a;
                let (before, after) = part.split_at_mut(k * p);
                let (cur, after) = after.split_at_mut(p);
                let prev: &[f64] = if k == 0 {
                    &below[below.len() - p..]
                } else {
                    &before[(k - 1) * p..k * p]
                };
                let next: &[f64] = if z + 1 == b { &above[..p] } else { &after[..p] };
                let fz = f.map(|f| &f[z * p..(z + 1) * p]);
                for &(y, x0, x1) in &runs.planes[z] {
                    let ((y, is_cut), x0, x1) = (row_of(y), x0 as usize, x1 as usize);
                    let r = y * nx..(y + 1) * nx;
                    let (lo, hi) = cur.split_at_mut(y * nx);
                    let (row, hi) = hi.split_at_mut(nx);
                    let rows = Rows {
                        ym: &lo[(y - 1) * nx..],
                        yp: &hi[..nx],
                        zm: &prev[r.clone()],
                        zp: &next[r.clone()],
                    };
                    if is_cut {
                        let cut = cut.expect("cut unknowns on a level with arms");
                        let at = (z * p + y * nx, [nx, p]);
                        rows.relax_cut(row, fz.map(|fz| &fz[r]), x0, z + y + color, omega, cut, at);
                    } else {
                        rows.relax(row, fz.map(|fz| &fz[r]), [x0, x1], z + y + color, w);
                    }
                }
            }
        });
    }
}

/// The rows around the row being relaxed: y - 1, y + 1, z - 1 and z + 1.
pub(super) struct Rows<'a> {
    ym: &'a [f64],
    yp: &'a [f64],
    zm: &'a [f64],
    zp: &'a [f64],
}

impl Rows<'_> {
    /// Relax the voxels of the run `x0..x1` of `row` whose `(z + y + x) % 2` is the
    /// color: `parity` is `z + y + color`.
    #[inline]
    pub(super) fn relax(
        &self,
        row: &mut [f64],
        f: Option<&[f64]>,
        [x0, x1]: [usize; 2],
        parity: usize,
        w: f64,
    ) {
        let first = x0 + (parity + x0) % 2;
        // Two calls, so that the row without a right-hand side is its own loop.
        match f {
            None => self.sweep(row, None, first, x1, w),
            Some(f) => self.sweep(row, Some(f), first, x1, w),
        }
    }

    /// Relax the cut unknown at `x` of `row` if `(z + y + x) % 2` is the color
    /// (`parity` is `z + y + color`): `u += omega defect / diag`, the arithmetic of
    /// [`crate::solve::boxops::BoxView::half_sweep`]. `at`: the row's offset in the
    /// level's arrays and their strides `[sy, sz]`.
    #[inline]
    #[allow(clippy::too_many_arguments)]
    pub(super) fn relax_cut(
        &self,
        row: &mut [f64],
        f: Option<&[f64]>,
        x: usize,
        parity: usize,
        omega: f64,
        cut: CutArrays<'_>,
        (start, [sy, sz]): (usize, [usize; 2]),
    ) {
        if !(parity + x).is_multiple_of(2) {
            return;
        }
        let nb = [
            row[x - 1],
            row[x + 1],
            self.ym[x],
            self.yp[x],
            self.zm[x],
            self.zp[x],
        ];
        let fx = f.map_or(0.0, |f| f[x]);
        let (d, g) = cut.defect(start + x, sy, sz, nb, row[x], fx);
        row[x] += omega * d / g;
    }

    /// Relax `row` at `first, first + 2, ...` below `end` (all unknowns): the
    /// arithmetic of [`crate::solve::boxops::BoxView::half_sweep`], term by term.
    #[inline]
    pub(super) fn sweep(
        &self,
        row: &mut [f64],
        f: Option<&[f64]>,
        first: usize,
        end: usize,
        w: f64,
    ) {
        let n = row.len();
        let (ym, yp, zm, zp) = (&self.ym[..n], &self.yp[..n], &self.zm[..n], &self.zp[..n]);
        for x in (first..end).step_by(2) {
            let nb = row[x - 1] + row[x + 1] + ym[x] + yp[x] + zm[x] + zp[x];
            let d = w * defect_of(f.map_or(0.0, |f| f[x]), nb, row[x]);
            row[x] += d;
        }
    }
}

/// `n` red-black sweeps (red, then black) of the whole grid, in place; with `src`, of
/// `src` into `u` (the first half-sweep reads `src` and writes the unknowns of `u`, and
/// the fixed voxels too unless `u` already holds them). Only the planes `planes` are
/// copied from `src` (the runs, too, lie in them).
#[allow(clippy::too_many_arguments)]
#[allow(clippy::many_single_char_names)] // the grid's u, f, n as in the formulas
pub(super) fn sweeps(
    u: &mut [f64],
    src: Option<(&[f64], bool)>,
    runs: &Runs,
    (f, cut): (Option<&[f64]>, Option<CutArrays<'_>>),
    shape: [usize; 3],
    n: usize,
    planes: &std::ops::Range<usize>,
) {
    for k in 0..n {
        match src {
            Some((src, fixed)) if k == 0 => {
                relax_from(u, src, fixed, runs, (f, cut), shape, 0, 1.0, planes);
            }
            _ => half_sweep(u, runs, f, cut, shape, 0, 1.0),
        }
        half_sweep(u, runs, f, cut, shape, 1, 1.0);
    }
    if n == 0 {
        if let Some((src, _)) = src {
            let p = shape[1] * shape[2];
            let r = planes.start * p..planes.end * p;
            u[r.clone()]
                .par_chunks_mut(1 << 16)
                .zip(src[r].par_chunks(1 << 16))
                .for_each(|(d, s)| d.copy_from_slice(s));
        }
    }
}

/// `u` = `src` after a half-sweep of `color`, in one pass: the unknowns of each plane
/// are copied and those of `color` relaxed with neighbours read from `src` (they are
/// of the other color, which the half-sweep leaves alone, so the values are those an
/// in-place half-sweep of the copy would read). The fixed voxels are the same in
/// every state: with `fixed`, `u` holds them already and only the unknowns are
/// written; otherwise whole planes are copied. Planes outside `planes` are left alone.
#[allow(clippy::too_many_arguments)]
#[allow(clippy::many_single_char_names)] // grid axes (z, y, x) and stencil terms named as in the formulas
pub(super) fn relax_from(
    u: &mut [f64],
    src: &[f64],
    fixed: bool,
    runs: &Runs,
    (f, cut): (Option<&[f64]>, Option<CutArrays<'_>>),
    shape: [usize; 3],
    color: usize,
    omega: f64,
    planes: &std::ops::Range<usize>,
) {
    let [nz, ny, nx] = shape;
    let p = ny * nx;
    let w = omega / 6.0;
    u.par_chunks_mut(p).enumerate().for_each(|(z, cur)| {
        if !planes.contains(&z) {
            return;
        }
        if !fixed {
            cur.copy_from_slice(&src[z * p..(z + 1) * p]);
        }
        if z == 0 || z + 1 >= nz {
            return;
        }
        let (prev, here, next) = (
            &src[(z - 1) * p..z * p],
            &src[z * p..(z + 1) * p],
            &src[(z + 1) * p..(z + 2) * p],
        );
        let fz = f.map(|f| &f[z * p..(z + 1) * p]);
        if fixed {
            // Every unknown of the plane first: a run reads its neighbours along x in
            // the copy, and the one past its end may be a cut unknown, a run of its own.
            for r in runs.ranges(z, nx) {
                cur[r.clone()].copy_from_slice(&here[r]);
            }
        }
        for &(y, x0, x1) in &runs.planes[z] {
            let ((y, is_cut), x0, x1) = (row_of(y), x0 as usize, x1 as usize);
            let r = y * nx..(y + 1) * nx;
            let rows = Rows {
                ym: &here[(y - 1) * nx..y * nx],
                yp: &here[(y + 1) * nx..(y + 2) * nx],
                zm: &prev[r.clone()],
                zp: &next[r.clone()],
            };
            let row = &mut cur[r.clone()];
            if is_cut {
                // Its neighbours along x in the copy hold the source's values (every
                // unknown of the plane was copied first).
                let cut = cut.expect("cut unknowns on a level with arms");
                let at = (z * p + y * nx, [nx, p]);
                rows.relax_cut(row, fz.map(|fz| &fz[r]), x0, z + y + color, omega, cut, at);
            } else {
                rows.relax(row, fz.map(|fz| &fz[r]), [x0, x1], z + y + color, w);
            }
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::boxops::BoxView;
    use crate::solve::cuts::{is_unknown, CUT};
    use crate::voxelize::cuts::encode;
    use crate::voxelize::labels::{CENTER, INTERIOR};

    /// Sweeps of a whole array with cut unknowns among the runs (next to them, at
    /// their ends) give the bytes of the block kernel's sweeps, on the finest level
    /// and on a coarse one (a right-hand side, the coarse coefficients); the first
    /// half-sweep read from a source copy too.
    #[test]
    #[allow(clippy::many_single_char_names)] // grid axes (z, y, x) as in the formulas
    fn whole_array_sweeps_with_cut_unknowns_equal_the_block_kernel() {
        let shape = [9usize, 10, 11];
        let [nz, ny, nx] = shape;
        let n = nz * ny * nx;
        let (mut mask, mut arms, mut u, mut f) =
            (vec![0u8; n], vec![0u64; n], vec![0.0; n], vec![0.0; n]);
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let i = (z * ny + y) * nx + x;
                    let h = (z * 7 + y * 13 + x * 5) % 17;
                    let edge = [z, y, x]
                        .iter()
                        .zip(shape)
                        .any(|(&c, s)| c == 0 || c + 1 == s);
                    u[i] = ((i * 37) % 101) as f64 / 101.0;
                    f[i] = ((i * 13) % 7) as f64 / 7.0 - 0.5;
                    mask[i] = match (edge, h) {
                        (true, _) => 0,
                        (false, 0) => CENTER,
                        (false, 1..=2) => 1,
                        (false, 3..=7) => {
                            let t = (h as f64) / 10.0;
                            arms[i] = encode([t, 0.0, 0.0, 1.0 - t, 0.3, 0.0]);
                            CUT
                        }
                        _ => INTERIOR,
                    };
                }
            }
        }
        let runs = Runs::of(&mask, shape);
        assert!(runs
            .planes
            .iter()
            .flatten()
            .any(|r| r.0 & super::super::runs::CUT_ROW != 0));
        for coarse in [false, true] {
            let fs = coarse.then_some(&f[..]);
            let cut = CutArrays {
                arms: &arms,
                mask: &mask,
                coarse,
            };
            // Two sweeps, the first half-sweep from a copy: into an array of zeros, and
            // into one that holds the fixed values already (its unknowns stale).
            let stale: Vec<f64> = u
                .iter()
                .zip(&mask)
                .map(|(&v, &m)| if is_unknown(m) { 9.0 } else { v })
                .collect();
            let mut b = u.clone();
            let mut view = BoxView {
                u: &mut b,
                mask: &mask,
                f: fs,
                cuts: Some(&arms),
                shape,
                origin: [0; 3],
            };
            view.sweeps(2, [[false; 2]; 3], 1.0);
            for (fixed, mut whole) in [(false, vec![0.0; n]), (true, stale)] {
                let src = Some((&u[..], fixed));
                sweeps(&mut whole, src, &runs, (fs, Some(cut)), shape, 2, &(0..nz));
                for (i, (a, b)) in whole.iter().zip(&b).enumerate() {
                    let at = format!("coarse {coarse}, fixed {fixed}, voxel {i}");
                    assert_eq!(a.to_bits(), b.to_bits(), "{at}");
                }
            }
        }
    }
}
