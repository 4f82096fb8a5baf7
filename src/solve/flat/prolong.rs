//! Trilinear prolongation of the coarse correction onto a whole array, and the energy
//! `c . A c` of the interpolated correction (the step length's denominator).

use rayon::prelude::*;

use super::runs::{Columns, Runs};
use super::{dims, slab_planes, Flat};
use crate::parallel::Pool;
use crate::solve::stencil::energy_term;

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

impl Flat<'_> {
    /// `c . A c` of the interpolated correction `c = P e` of `coarse`: the sum of
    /// [`crate::solve::boxops::correction_energy`] over the blocks in block order, each summed
    /// plane by plane, with the same arithmetic. Parallel over slabs of planes; a slab
    /// keeps `c` (0 off the unknowns) on three planes and interpolates each coarse
    /// plane once.
    #[must_use]
    #[allow(clippy::many_single_char_names)] // grid axes (z, y, x) and stencil terms named as in the formulas
    pub fn correction_energy(&self, coarse: &Flat<'_>) -> f64 {
        let spec = self.spec;
        let [nz, ny, nx] = dims(spec);
        let p = ny * nx;
        let cols = Columns::of(spec);
        let e = coarse.u[0].array();
        let [_, cny, cnx] = dims(coarse.spec);
        let runs = self.runs();
        let plane_xy = |zc: usize, ex: &mut Vec<f64>, out: &mut Vec<f64>| {
            interpolate_xy(&e, [cny, cnx], [ny, nx], zc, ex, out);
        };
        let per = slab_planes(nz);
        // Per plane, the sum over each block column (by, bx) of the plane.
        let sums: Vec<Vec<Vec<f64>>> = (0..nz.div_ceil(per))
            .into_par_iter()
            .map(|slab| {
                let (z0, z1) = (slab * per, ((slab + 1) * per).min(nz));
                self.cache.energy.with(|(pair, ring)| {
                    pair.tag = [None; 2];
                    ring.resize_with(3, Vec::new);
                    // c on plane z, 0 off the unknowns (and on the grid's first and last
                    // planes, which hold none).
                    let masked = |z: usize, pair: &mut PlanePair, out: &mut Vec<f64>| {
                        out.clear();
                        out.resize(p, 0.0);
                        if z == 0 || z + 1 >= nz || runs.planes[z].is_empty() {
                            return;
                        }
                        let (a, b) = pair.planes_for(z, plane_xy);
                        for r in runs.ranges(z, nx) {
                            for (i, v) in r.clone().zip(&mut out[r]) {
                                *v = correction_at(a, b, z, i);
                            }
                        }
                    };
                    let mut out = Vec::with_capacity(z1 - z0);
                    let [prev, cur, next] = &mut ring[..] else {
                        unreachable!("three planes")
                    };
                    if z0 > 0 {
                        masked(z0 - 1, pair, prev);
                    } else {
                        prev.clear();
                        prev.resize(p, 0.0);
                    }
                    masked(z0, pair, cur);
                    for z in z0..z1 {
                        masked(z + 1, pair, next);
                        let (m, c, q) = (&*prev, &*cur, &*next);
                        let mut col = vec![0.0; cols.count];
                        for &(y, x0, x1) in &runs.planes[z] {
                            let (y, r) = (y as usize, y as usize * nx);
                            for (k, a, b) in cols.split(y, x0 as usize, x1 as usize) {
                                for i in r + a..r + b {
                                    let nb =
                                        c[i - 1] + c[i + 1] + c[i - nx] + c[i + nx] + m[i] + q[i];
                                    col[k] += energy_term(c[i], nb);
                                }
                            }
                        }
                        out.push(col);
                        // Planes z, z + 1 become the previous and current ones.
                        std::mem::swap(prev, cur);
                        std::mem::swap(cur, next);
                    }
                    out
                })
            })
            .collect();
        let sums: Vec<Vec<f64>> = sums.into_iter().flatten().collect();
        cols.total(spec, &sums)
    }
}
