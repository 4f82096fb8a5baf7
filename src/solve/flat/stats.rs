//! The largest change and the residual of a whole array, summed per block in block
//! order as the block passes sum them.

use rayon::prelude::*;

use super::runs::{dims, row_of, slab_planes, Columns, Runs};
use crate::grid::GridSpec;
use crate::solve::cuts::CutArrays;
use crate::solve::stencil::defect_at;

/// Per plane of a level held as an array: the largest |u - old| and the count of
/// unknowns, and the residual's sum of squares over each block column of the plane
/// (`sums[z][column]`). Planes outside the ones measured hold zeros.
pub(crate) struct PlaneStats {
    max: Vec<f64>,
    count: Vec<u64>,
    sums: Vec<Vec<f64>>,
    measured: bool,
}

impl PlaneStats {
    /// The largest change, the residual's sum of squares (per block, plane by plane,
    /// the blocks in block order, as the block passes sum it) and the count.
    pub(crate) fn whole(&self, spec: &GridSpec) -> (f64, f64, u64) {
        let max = self.max.iter().copied().fold(0.0, f64::max);
        if !self.measured {
            return (max, 0.0, 0);
        }
        let n = self.count.iter().sum();
        (max, Columns::of(spec).total(spec, &self.sums), n)
    }

    /// The numbers of each block of the block layers `layers` (on an MPI rank, the ones
    /// it owns), in block order: each block's residual sum, and for the first block of
    /// each layer the layer's count and largest change (the others 0), so that the
    /// ranks' entries added in block order give [`PlaneStats::whole`]'s numbers.
    pub(crate) fn per_block(
        &self,
        spec: &GridSpec,
        layers: std::ops::Range<u64>,
    ) -> Vec<(crate::math::Idx3, crate::solve::level::PassStats)> {
        let cols = Columns::of(spec);
        let cz = spec.chunk[0] as usize;
        spec.block_indices()
            .into_iter()
            .filter(|b| layers.contains(&b[0]))
            .map(|b| {
                let planes = b[0] as usize * cz..((b[0] as usize + 1) * cz).min(self.max.len());
                let first = b[1] == 0 && b[2] == 0;
                let st = crate::solve::level::PassStats {
                    res_sq: if self.measured {
                        cols.block_sum(b, &self.sums)
                    } else {
                        0.0
                    },
                    count: if first && self.measured {
                        self.count[planes.clone()].iter().sum()
                    } else {
                        0
                    },
                    max_change: if first {
                        self.max[planes].iter().copied().fold(0.0, f64::max)
                    } else {
                        0.0
                    },
                };
                (b, st)
            })
            .collect()
    }
}

/// Over the unknowns of `u` on the planes `own`: per plane the largest |u - old| (with
/// `old`), and the sum of squares and count of the residual `defect / 6` (with
/// `measure`), summed as the block passes sum them: per block, plane by plane, each
/// plane in y, x order (the blocks in block order: [`PlaneStats::whole`]). Parallel over
/// slabs of planes, which keep one sum per block column and plane.
#[allow(clippy::many_single_char_names)] // grid axes (z, y, x) and stencil terms named as in the formulas
pub(super) fn plane_stats(
    spec: &GridSpec,
    u: &[f64],
    old: Option<&[f64]>,
    runs: &Runs,
    (f, cut): (Option<&[f64]>, Option<CutArrays<'_>>),
    measure: bool,
    own: &std::ops::Range<usize>,
) -> PlaneStats {
    let [nz, ny, nx] = dims(spec);
    let (sy, sz) = (nx, nx * ny);
    let cols = Columns::of(spec);
    let per = slab_planes(nz);
    if old.is_none() && !measure {
        return PlaneStats {
            max: vec![0.0; nz],
            count: vec![0; nz],
            sums: vec![Vec::new(); nz],
            measured: false,
        };
    }
    let slabs: Vec<Vec<(f64, u64, Vec<f64>)>> = (0..nz.div_ceil(per))
        .into_par_iter()
        .map(|slab| {
            let mut planes = Vec::with_capacity(per);
            for z in slab * per..((slab + 1) * per).min(nz) {
                let (mut max, mut n) = (0.0f64, 0u64);
                let mut col = vec![0.0; if measure { cols.count } else { 0 }];
                if !own.contains(&z) {
                    planes.push((max, n, col));
                    continue;
                }
                for &(y, x0, x1) in &runs.planes[z] {
                    let (y, is_cut) = row_of(y);
                    let row = (z * ny + y) * nx;
                    if let Some(old) = old {
                        for i in row + x0 as usize..row + x1 as usize {
                            max = max.max((u[i] - old[i]).abs());
                        }
                    }
                    if !measure {
                        continue;
                    }
                    for (c, a, b) in cols.split(y, x0 as usize, x1 as usize) {
                        for i in row + a..row + b {
                            let r = if is_cut {
                                let cut = cut.expect("cut unknowns on a level with arms");
                                let (d, g) = cut.defect_in(u, f, i, sy, sz);
                                d / g
                            } else {
                                defect_at(u, f, i, sy, sz) / 6.0
                            };
                            col[c] += r * r;
                        }
                        n += (b - a) as u64;
                    }
                }
                planes.push((max, n, col));
            }
            planes
        })
        .collect();
    let mut out = PlaneStats {
        max: Vec::with_capacity(nz),
        count: Vec::with_capacity(nz),
        sums: Vec::with_capacity(nz),
        measured: measure,
    };
    for (m, c, p) in slabs.into_iter().flatten() {
        out.max.push(m);
        out.count.push(c);
        out.sums.push(p);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::level::PassStats;
    use crate::voxelize::labels::{BOUNDARY, INTERIOR};

    /// Measured in parts of block layers, as MPI ranks measure their slabs, and the
    /// parts' blocks added in block order, the numbers are the whole array's, bit for
    /// bit.
    #[test]
    fn per_block_numbers_of_slabs_add_up_to_the_whole() {
        let spec = GridSpec {
            shape: [21, 13, 11],
            origin: [0.0; 3],
            spacing: 1.0,
            chunk: [4, 5, 6],
            unit: None,
        };
        let [nz, ny, nx] = dims(&spec);
        let n = nz * ny * nx;
        let edge = |i: usize, k: usize| i == 0 || i + 1 == k;
        let mut mask = vec![BOUNDARY; n];
        let mut u = vec![0.0; n];
        let mut old = vec![0.0; n];
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let i = (z * ny + y) * nx + x;
                    let w = ((z * 7 + y * 3 + x) as f64).sin();
                    u[i] = 0.5 + 0.3 * w;
                    old[i] = u[i] + 1e-3 * (w * 5.0).cos();
                    if !(edge(z, nz) || edge(y, ny) || edge(x, nx)) && (x + y) % 5 != 0 {
                        mask[i] = INTERIOR;
                    }
                }
            }
        }
        let runs = Runs::of(&mask, [nz, ny, nx]);
        let (max, sum, count) =
            plane_stats(&spec, &u, Some(&old), &runs, (None, None), true, &(0..nz)).whole(&spec);
        assert!(count > 0 && sum > 0.0 && max > 0.0);
        for cuts in [vec![0, 6], vec![0, 1, 3, 6], vec![0, 2, 6]] {
            let mut parts: Vec<(crate::math::Idx3, PassStats)> = Vec::new();
            for w in cuts.windows(2) {
                let layers = w[0]..w[1];
                let own = w[0] as usize * 4..(w[1] as usize * 4).min(nz);
                let st = plane_stats(&spec, &u, Some(&old), &runs, (None, None), true, &own);
                parts.extend(st.per_block(&spec, layers));
            }
            parts.sort_by_key(|(b, _)| spec.block_linear(*b));
            assert_eq!(parts.len() as u64, spec.num_blocks());
            let all = PassStats::reduce(parts.into_iter().map(|(_, p)| p).collect());
            assert_eq!(all.res_sq.to_bits(), sum.to_bits(), "{cuts:?}");
            assert_eq!(all.count, count, "{cuts:?}");
            assert_eq!(all.max_change.to_bits(), max.to_bits(), "{cuts:?}");
        }
    }
}
