//! The unknowns of a level held as arrays, as runs along x; and the block columns that
//! let whole-array passes sum per block as the block passes do.

use rayon::prelude::*;

use crate::grid::GridSpec;
use crate::solve::cuts::CUT;
use crate::voxelize::labels::INTERIOR;

/// The unknowns of a level as runs along x: for each plane, `(y, x0, x1)` with every
/// voxel of `x0..x1` of row `y` an unknown. Sweeps walk the runs and skip the rest.
/// An unknown with a cut arm ([`CUT`]) is a run of its own, its `y` marked with
/// [`CUT_ROW`]: the runs of a plane stay in y, x order, so that the sums over them add
/// the unknowns in the order the block passes do.
pub struct Runs {
    pub(super) planes: Vec<Vec<(u32, u32, u32)>>,
}

/// The mark on the row of a run that is one cut unknown.
pub(super) const CUT_ROW: u32 = 1 << 31;

/// A run's row, and whether it is one cut unknown.
#[inline]
pub(super) fn row_of(y: u32) -> (usize, bool) {
    ((y & !CUT_ROW) as usize, y & CUT_ROW != 0)
}

impl Runs {
    /// The runs of the unknowns of `mask` (a whole grid of `shape`).
    #[must_use]
    pub fn of(mask: &[u8], shape: [usize; 3]) -> Self {
        Self::of_planes(mask, shape, None)
    }

    /// [`Runs::of`] on the planes `planes` alone (all with `None`); the other planes
    /// have no runs, so the passes leave them alone (and never touch their memory).
    #[must_use]
    pub fn of_planes(
        mask: &[u8],
        shape: [usize; 3],
        planes: Option<&std::ops::Range<usize>>,
    ) -> Self {
        let [_, ny, nx] = shape;
        let planes = mask
            .par_chunks(ny * nx)
            .enumerate()
            .map(|(z, m)| {
                let mut out = Vec::new();
                if planes.as_ref().is_some_and(|p| !p.contains(&z)) {
                    return out;
                }
                for y in 0..ny {
                    let row = &m[y * nx..(y + 1) * nx];
                    let mut x = 0;
                    while x < nx {
                        if row[x] == INTERIOR {
                            let x0 = x;
                            while x < nx && row[x] == INTERIOR {
                                x += 1;
                            }
                            out.push((y as u32, x0 as u32, x as u32));
                        } else {
                            if row[x] == CUT {
                                out.push((y as u32 | CUT_ROW, x as u32, x as u32 + 1));
                            }
                            x += 1;
                        }
                    }
                }
                out
            })
            .collect();
        Self { planes }
    }

    /// The runs of plane `z` as ranges of offsets into the plane (rows of `nx`).
    pub(super) fn ranges(
        &self,
        z: usize,
        nx: usize,
    ) -> impl Iterator<Item = std::ops::Range<usize>> + '_ {
        self.planes[z].iter().map(move |&(y, x0, x1)| {
            let r = row_of(y).0 * nx;
            r + x0 as usize..r + x1 as usize
        })
    }
}

/// The block columns `(by, bx)` of a grid. The block passes sum per block, plane by
/// plane; a whole-array pass gives the same sums by keeping one sum per plane and
/// column and adding them up per block at the end.
pub(super) struct Columns {
    pub(super) chunk: [usize; 3],
    pub(super) nz: usize,
    pub(super) nbx: usize,
    pub(super) count: usize,
}

impl Columns {
    pub(super) fn of(spec: &GridSpec) -> Self {
        let [nz, ny, nx] = dims(spec);
        let chunk = spec.chunk.map(|c| c as usize);
        let nbx = nx.div_ceil(chunk[2]);
        Self {
            chunk,
            nz,
            nbx,
            count: ny.div_ceil(chunk[1]) * nbx,
        }
    }

    /// The parts of the run `x0..x1` of row `y` in each block column:
    /// `(column, x0, x1)`, in x order.
    pub(super) fn split(
        &self,
        y: usize,
        x0: usize,
        x1: usize,
    ) -> impl Iterator<Item = (usize, usize, usize)> {
        let [_, cy, cx] = self.chunk;
        let row = (y / cy) * self.nbx;
        let mut x = x0;
        std::iter::from_fn(move || {
            (x < x1).then(|| {
                let end = ((x / cx + 1) * cx).min(x1);
                let part = (row + x / cx, x, end);
                x = end;
                part
            })
        })
    }

    /// The sum over the blocks, in block order, of each block's plane sums in z order;
    /// `planes[z][column]`.
    pub(super) fn total(&self, spec: &GridSpec, planes: &[Vec<f64>]) -> f64 {
        spec.block_indices()
            .iter()
            .map(|&b| self.block_sum(b, planes))
            .sum()
    }

    /// Block `b`'s sum: its plane sums in z order; `planes[z][column]`.
    pub(super) fn block_sum(&self, [bz, by, bx]: crate::math::Idx3, planes: &[Vec<f64>]) -> f64 {
        let cz = self.chunk[0];
        let (bz, col) = (bz as usize, by as usize * self.nbx + bx as usize);
        let mut s = 0.0;
        for plane in &planes[bz * cz..((bz + 1) * cz).min(self.nz)] {
            s += plane[col];
        }
        s
    }
}

/// Planes per slab when `n` planes are cut into slabs for the whole-array passes: about
/// eight slabs per thread (work stealing evens out slabs of unequal work).
pub(super) fn slab_planes(n: usize) -> usize {
    n.div_ceil(8 * rayon::current_num_threads()).max(1)
}

pub(super) fn dims(spec: &GridSpec) -> [usize; 3] {
    spec.shape.map(|c| c as usize)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    pub(super) fn columns_split_runs_at_block_edges_and_total_sums_per_block_in_block_order() {
        let spec = GridSpec {
            shape: [4, 10, 10],
            origin: [0.0; 3],
            spacing: 1.0,
            chunk: [2, 4, 4],
            unit: None,
        };
        let cols = Columns::of(&spec);
        assert_eq!(cols.count, 9);
        // Row 5 is in block row 1; x 2..10 crosses columns 0, 1 and 2 of it.
        let parts: Vec<_> = cols.split(5, 2, 10).collect();
        assert_eq!(parts, vec![(3, 2, 4), (4, 4, 8), (5, 8, 10)]);
        assert_eq!(cols.split(5, 4, 4).count(), 0);
        // Plane z, column c holds 10^z * (c + 1): block (bz, by, bx) sums the planes
        // 2 bz and 2 bz + 1 of its column.
        let planes: Vec<Vec<f64>> = (0..4)
            .map(|z| (0..9).map(|c| 10f64.powi(z) * f64::from(c + 1)).collect())
            .collect();
        let want: f64 = spec
            .block_indices()
            .iter()
            .map(|&[bz, by, bx]| {
                let c = (by * 3 + bx + 1) as f64;
                let z = 2 * bz as i32;
                10f64.powi(z) * c + 10f64.powi(z + 1) * c
            })
            .sum();
        // Integers below 2^53: exact in any order.
        assert!((cols.total(&spec, &planes) - want).abs() < 0.5);
    }
}
