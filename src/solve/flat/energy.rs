//! The energy `c . A c` of the interpolated coarse correction on a whole array (the
//! denominator of the correction's length).

use rayon::prelude::*;

use super::prolong::{correction_at, interpolate_xy, PlanePair};
use super::runs::{dims, row_of, slab_planes, Columns};
use super::Flat;
use crate::math::Idx3;
use crate::solve::stencil::energy_term;

impl Flat<'_> {
    /// `c . A c` of the interpolated correction `c = P e` of `coarse`: the sum of
    /// [`crate::solve::boxops::correction_energy`] over the blocks in block order, each summed
    /// plane by plane, with the same arithmetic. Parallel over slabs of planes; a slab
    /// keeps `c` (0 off the unknowns) on three planes and interpolates each coarse
    /// plane once.
    #[must_use]
    #[allow(clippy::many_single_char_names)] // grid axes (z, y, x) and stencil terms named as in the formulas
    pub fn correction_energy(&self, coarse: &Flat<'_>) -> f64 {
        Columns::of(self.spec).total(self.spec, &self.energy_planes(coarse))
    }

    /// [`Flat::correction_energy`] of each block of the block layers `layers` (on an
    /// MPI rank, the ones it owns), in block order: the entries the ranks' sum adds up.
    #[must_use]
    pub fn correction_energy_blocks(
        &self,
        coarse: &Flat<'_>,
        layers: std::ops::Range<u64>,
    ) -> Vec<(Idx3, f64)> {
        let sums = self.energy_planes(coarse);
        let cols = Columns::of(self.spec);
        self.spec
            .block_indices()
            .into_iter()
            .filter(|b| layers.contains(&b[0]))
            .map(|b| (b, cols.block_sum(b, &sums)))
            .collect()
    }

    /// Per plane, the energy's sum over each block column of the plane.
    #[allow(clippy::many_single_char_names)] // grid axes (z, y, x) and stencil terms named as in the formulas
    fn energy_planes(&self, coarse: &Flat<'_>) -> Vec<Vec<f64>> {
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
                            // A cut unknown too: the staircase's energy, as the block
                            // passes take it.
                            let y = row_of(y).0;
                            let r = y * nx;
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
        sums.into_iter().flatten().collect()
    }
}
