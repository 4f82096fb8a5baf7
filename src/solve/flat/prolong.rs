//! Trilinear prolongation of the coarse correction onto a whole array.

use rayon::prelude::*;

use super::runs::{slab_planes, Runs};
use crate::parallel::Pool;

/// Coarse planes interpolated in x and y onto the fine plane (see [`prolong_add`]),
/// two of them, tagged with the coarse plane each holds.
#[derive(Default)]
pub struct PlanePair {
    pub(super) tag: [Option<usize>; 2],
    pub(super) buf: [Vec<f64>; 2],
    pub(super) ex: Vec<f64>,
}

/// The interpolated correction at offset `i` of fine plane `z`, from the coarse planes
/// [`PlanePair::planes_for`] gives: the mean of the two for odd `z` (the z step of
/// [`crate::solve::boxops::prolong`]).
#[inline]
pub(super) fn correction_at(a: &[f64], b: &[f64], z: usize, i: usize) -> f64 {
    if z % 2 == 1 {
        0.5 * (a[i] + b[i])
    } else {
        a[i]
    }
}

impl PlanePair {
    /// The coarse planes (interpolated in x and y) that fine plane `z` takes its
    /// correction from: `z / 2`, and `z / 2 + 1` for odd `z` (for even `z`, the same
    /// plane twice); filled by `fill` unless held already.
    pub(super) fn planes_for(
        &mut self,
        z: usize,
        fill: impl Fn(usize, &mut Vec<f64>, &mut Vec<f64>) + Copy,
    ) -> (&[f64], &[f64]) {
        let zc = z / 2;
        let odd = z % 2 == 1;
        let ka = self.get(zc, odd.then_some(zc + 1), fill);
        let kb = if odd {
            self.get(zc + 1, Some(zc), fill)
        } else {
            ka
        };
        (&self.buf[ka], &self.buf[kb])
    }

    /// The slot holding coarse plane `zc`, filled by `fill` unless it is there already;
    /// the slot holding `keep` is not overwritten.
    pub(super) fn get(
        &mut self,
        zc: usize,
        keep: Option<usize>,
        fill: impl Fn(usize, &mut Vec<f64>, &mut Vec<f64>),
    ) -> usize {
        if let Some(k) = (0..2).find(|&k| self.tag[k] == Some(zc)) {
            return k;
        }
        let k = if keep.is_some() && self.tag[0] == keep {
            1
        } else if keep.is_some() && self.tag[1] == keep {
            0
        } else {
            // The older one.
            usize::from(self.tag[1] < self.tag[0])
        };
        fill(zc, &mut self.ex, &mut self.buf[k]);
        self.tag[k] = Some(zc);
        k
    }
}

/// The coarse plane `zc` of `e` (planes of `[cny, cnx]`) interpolated in x and then y
/// onto a fine plane of `[ny, nx]`, at the fine interior nodes (0 on the plane's edge),
/// into `out`; `ex` is scratch. The arithmetic of [`crate::solve::boxops::prolong`].
pub(super) fn interpolate_xy(
    e: &[f64],
    [cny, cnx]: [usize; 2],
    [ny, nx]: [usize; 2],
    zc: usize,
    ex: &mut Vec<f64>,
    out: &mut Vec<f64>,
) {
    ex.clear();
    ex.resize(cny * nx, 0.0);
    for yc in 0..cny {
        let src = &e[(zc * cny + yc) * cnx..][..cnx];
        for x in 1..nx - 1 {
            ex[yc * nx + x] = if x % 2 == 1 {
                0.5 * (src[x / 2] + src[x / 2 + 1])
            } else {
                src[x / 2]
            };
        }
    }
    out.clear();
    out.resize(ny * nx, 0.0);
    for y in 1..ny - 1 {
        let a = &ex[(y / 2) * nx..][..nx];
        let dst = &mut out[y * nx..][..nx];
        if y % 2 == 1 {
            let b = &ex[(y / 2 + 1) * nx..][..nx];
            for x in 1..nx - 1 {
                dst[x] = 0.5 * (a[x] + b[x]);
            }
        } else {
            dst[1..nx - 1].copy_from_slice(&a[1..nx - 1]);
        }
    }
}

/// `u += scale * P e` at the unknowns, `P` trilinear interpolation from the coarse
/// level, axis by axis in the order of [`crate::solve::boxops::prolong`] (x, then y, then z).
/// Parallel over slabs of fine planes; a slab interpolates each coarse plane it needs
/// in x and y once (a fine plane takes one or two of them, its neighbours share them).
#[allow(clippy::too_many_arguments)]
#[allow(clippy::many_single_char_names)] // grid axes (z, y, x) and stencil terms named as in the formulas
pub(super) fn prolong_add(
    fine: [usize; 3],
    u: &mut [f64],
    runs: &Runs,
    coarse: [usize; 3],
    e: &[f64],
    scale: f64,
    pool: &Pool<PlanePair>,
) {
    let [nz, ny, nx] = fine;
    let [_, cny, cnx] = coarse;
    let p = ny * nx;
    let plane_xy = |zc: usize, ex: &mut Vec<f64>, out: &mut Vec<f64>| {
        interpolate_xy(e, [cny, cnx], [ny, nx], zc, ex, out);
    };
    let per = slab_planes(nz);
    u.par_chunks_mut(per * p)
        .enumerate()
        .for_each(|(slab, planes)| {
            pool.with(|pair| {
                pair.tag = [None; 2];
                for (k, uz) in planes.chunks_exact_mut(p).enumerate() {
                    let z = slab * per + k;
                    if z == 0 || z + 1 >= nz || runs.planes[z].is_empty() {
                        continue;
                    }
                    let (a, b) = pair.planes_for(z, plane_xy);
                    for r in runs.ranges(z, nx) {
                        for (i, v) in r.clone().zip(&mut uz[r]) {
                            *v += scale * correction_at(a, b, z, i);
                        }
                    }
                }
            });
        });
}
