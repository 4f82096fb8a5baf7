//! Full-weighting restriction of a whole array's defect into the coarse right-hand side.

use rayon::prelude::*;

use super::runs::{row_of, slab_planes, Runs};
use crate::parallel::Pool;
use crate::solve::cuts::{is_unknown, CutArrays};
use crate::solve::stencil::{defect_at, full_weighting};

/// The defect plane `z` (0 off the unknowns, and off the grid).
pub(super) fn defect_plane(
    u: &[f64],
    runs: &Runs,
    (f, cut): (Option<&[f64]>, Option<CutArrays<'_>>),
    shape: [usize; 3],
    z: i64,
    out: &mut [f64],
) {
    let [nz, ny, nx] = shape;
    out.fill(0.0);
    if z < 0 || z as usize >= nz {
        return;
    }
    let z = z as usize;
    let (sy, sz) = (nx, nx * ny);
    for &(y, x0, x1) in &runs.planes[z] {
        let ((y, is_cut), x0, x1) = (row_of(y), x0 as usize, x1 as usize);
        let row = (z * ny + y) * nx;
        if is_cut {
            let cut = cut.expect("cut unknowns on a level with arms");
            out[y * nx + x0] = cut.defect_in(u, f, row + x0, sy, sz).0;
            continue;
        }
        for x in x0..x1 {
            out[y * nx + x] = defect_at(u, f, row + x, sy, sz);
        }
    }
}

/// Full weighting of the defect of the fine level into the coarse right-hand side
/// (the same weights and order as [`crate::solve::boxops::restrict`]), and 0 off the coarse
/// unknowns. Parallel over slabs of coarse planes; within a slab, the fine defect
/// plane `2 zc + 1` of one coarse plane is the plane `2 zc' - 1` of the next, and is
/// kept rather than computed twice. Only the coarse planes `cplanes` are written.
#[allow(clippy::too_many_arguments)]
pub(super) fn restrict(
    fine: [usize; 3],
    u: &[f64],
    runs: &Runs,
    (f, cut): (Option<&[f64]>, Option<CutArrays<'_>>),
    coarse: [usize; 3],
    cmask: &[u8],
    cf: &mut [f64],
    planes: &Pool<Vec<f64>>,
    cplanes: std::ops::Range<usize>,
) {
    let [_, ny, nx] = fine;
    let [_, cny, cnx] = coarse;
    let (p, cp) = (ny * nx, cny * cnx);
    let per = slab_planes(cplanes.len());
    let first = cplanes.start;
    cf[cplanes.start * cp..cplanes.end * cp]
        .par_chunks_mut(per * cp)
        .enumerate()
        .for_each(|(slab, outs)| {
            planes.with(|d| {
                d.resize(3 * p, 0.0);
                // The fine plane held in d's last third.
                let mut last: Option<i64> = None;
                for (k, out) in outs.chunks_exact_mut(cp).enumerate() {
                    let zc = first + slab * per + k;
                    let cm = &cmask[zc * cp..(zc + 1) * cp];
                    if !cm.iter().any(|&m| is_unknown(m)) {
                        out.fill(0.0);
                        continue;
                    }
                    let z0 = 2 * zc as i64 - 1;
                    if last == Some(z0) {
                        d.copy_within(2 * p.., 0);
                    } else {
                        defect_plane(u, runs, (f, cut), fine, z0, &mut d[..p]);
                    }
                    defect_plane(u, runs, (f, cut), fine, z0 + 1, &mut d[p..2 * p]);
                    defect_plane(u, runs, (f, cut), fine, z0 + 2, &mut d[2 * p..]);
                    last = Some(z0 + 2);
                    for yc in 0..cny {
                        for xc in 0..cnx {
                            let o = yc * cnx + xc;
                            out[o] = if is_unknown(cm[o]) {
                                full_weighting(d, p + (2 * yc) * nx + 2 * xc, nx, p)
                            } else {
                                0.0
                            };
                        }
                    }
                }
            });
        });
}
