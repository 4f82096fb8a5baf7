//! The largest change and the residual of a whole array, summed per block in block
//! order as the block passes sum them.

use rayon::prelude::*;

use super::runs::{dims, slab_planes, Columns, Runs};
use crate::grid::GridSpec;
use crate::solve::stencil::defect_at;

/// Over the unknowns of `u`: the largest |u - old| (with `old`), and the sum of squares
/// and count of the residual `defect / 6` (with `measure`), summed as the block passes
/// sum them: per block, plane by plane, each plane in y, x order; the blocks in block
/// order. Parallel over slabs of planes, which keep one sum per block column and plane.
#[allow(clippy::many_single_char_names)] // grid axes (z, y, x) and stencil terms named as in the formulas
pub(super) fn block_stats(
    spec: &GridSpec,
    u: &[f64],
    old: Option<&[f64]>,
    runs: &Runs,
    f: Option<&[f64]>,
    measure: bool,
) -> (f64, f64, u64) {
    if old.is_none() && !measure {
        return (0.0, 0.0, 0);
    }
    let [nz, ny, nx] = dims(spec);
    let (sy, sz) = (nx, nx * ny);
    let cols = Columns::of(spec);
    let per = slab_planes(nz);
    let slabs: Vec<(f64, u64, Vec<Vec<f64>>)> = (0..nz.div_ceil(per))
        .into_par_iter()
        .map(|slab| {
            let (mut max, mut n) = (0.0f64, 0u64);
            let mut planes = Vec::with_capacity(per);
            for z in slab * per..((slab + 1) * per).min(nz) {
                let mut col = vec![0.0; if measure { cols.count } else { 0 }];
                for &(y, x0, x1) in &runs.planes[z] {
                    let (y, row) = (y as usize, (z * ny + y as usize) * nx);
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
                            let r = defect_at(u, f, i, sy, sz) / 6.0;
                            col[c] += r * r;
                        }
                        n += (b - a) as u64;
                    }
                }
                planes.push(col);
            }
            (max, n, planes)
        })
        .collect();
    let (mut max, mut n) = (0.0f64, 0u64);
    let mut planes = Vec::with_capacity(nz);
    for (m, c, p) in slabs {
        max = max.max(m);
        n += c;
        planes.extend(p);
    }
    if !measure {
        return (max, 0.0, 0);
    }
    let sum = cols.total(spec, &planes);
    (max, sum, n)
}
