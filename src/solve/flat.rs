//! The multigrid passes for levels held in memory as whole arrays ([`FlatStore`]): the
//! same operations as the block passes of [`super::multigrid`], done in place on the
//! arrays, with no box copies and no halo recomputation.
//!
//! Every value is computed with the same arithmetic in the same order as in the block
//! passes (red-black sweeps do not depend on the order within a color; the residual is
//! summed block by block in block order; restriction and prolongation are per node), so
//! a level in memory and a level in scratch files give the same bytes. The tests that
//! compare budgets check it.
//!
//! A half-sweep is parallel over slabs of z planes: a node of one color reads only
//! nodes of the other color, which the half-sweep does not change, so each slab takes
//! copies of the two planes next to it and updates its own planes alone.

use rayon::prelude::*;

use super::boxops::{defect_at, defect_of, full_weighting};

use crate::grid::{FlatStore, GridSpec};
use crate::voxelize::labels::INTERIOR;

/// The unknowns of a level as runs along x: for each plane, `(y, x0, x1)` with every
/// voxel of `x0..x1` of row `y` an unknown. Sweeps walk the runs and skip the rest.
pub struct Runs {
    planes: Vec<Vec<(u32, u32, u32)>>,
}

impl Runs {
    /// The runs of the unknowns of `mask` (a whole grid of `shape`).
    #[must_use]
    pub fn of(mask: &[u8], shape: [usize; 3]) -> Self {
        let [_, ny, nx] = shape;
        let planes = mask
            .par_chunks(ny * nx)
            .map(|m| {
                let mut out = Vec::new();
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
                            x += 1;
                        }
                    }
                }
                out
            })
            .collect();
        Self { planes }
    }
}

fn dims(spec: &GridSpec) -> [usize; 3] {
    spec.shape.map(|c| c as usize)
}

/// One red-black half-sweep of `color` over the whole grid, in place. `f`: the
/// right-hand side (coarse levels).
fn half_sweep(
    u: &mut [f64],
    runs: &Runs,
    f: Option<&[f64]>,
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
    // Slabs of planes 1..nz-1, a few per thread.
    let tasks = (4 * rayon::current_num_threads()).min(nz - 2).max(1);
    let per = (nz - 2).div_ceil(tasks);
    let bounds: Vec<(usize, usize)> = (1..nz - 1)
        .step_by(per)
        .map(|a| (a, (a + per).min(nz - 1)))
        .collect();
    let ghosts: Vec<(Vec<f64>, Vec<f64>)> = bounds
        .iter()
        .map(|&(a, b)| {
            (
                u[(a - 1) * p..a * p].to_vec(),
                u[b * p..(b + 1) * p].to_vec(),
            )
        })
        .collect();
    let mut parts = Vec::with_capacity(bounds.len());
    let mut rest = &mut u[p..(nz - 1) * p];
    for &(a, b) in &bounds {
        let (head, tail) = rest.split_at_mut((b - a) * p);
        parts.push(head);
        rest = tail;
    }
    parts
        .into_par_iter()
        .zip(bounds)
        .zip(ghosts)
        .for_each(|((part, (a, b)), (below, above))| {
            for z in a..b {
                let k = z - a;
                let (before, after) = part.split_at_mut(k * p);
                let (cur, after) = after.split_at_mut(p);
                let prev: &[f64] = if k == 0 {
                    &below
                } else {
                    &before[(k - 1) * p..k * p]
                };
                let next: &[f64] = if z + 1 == b { &above } else { &after[..p] };
                let fz = f.map(|f| &f[z * p..(z + 1) * p]);
                for &(y, x0, x1) in &runs.planes[z] {
                    let (y, x0, x1) = (y as usize, x0 as usize, x1 as usize);
                    let r = y * nx..(y + 1) * nx;
                    let (lo, hi) = cur.split_at_mut(y * nx);
                    let (row, hi) = hi.split_at_mut(nx);
                    let rows = Rows {
                        ym: &lo[(y - 1) * nx..],
                        yp: &hi[..nx],
                        zm: &prev[r.clone()],
                        zp: &next[r.clone()],
                    };
                    // The first voxel of `color` in the run: (z + y + x) % 2 == color.
                    let first = x0 + (z + y + x0 + color) % 2;
                    match fz {
                        None => rows.sweep(row, None, first, x1, w),
                        Some(fz) => rows.sweep(row, Some(&fz[r]), first, x1, w),
                    }
                }
            }
        });
}

/// The rows around the row being relaxed: y - 1, y + 1, z - 1 and z + 1.
struct Rows<'a> {
    ym: &'a [f64],
    yp: &'a [f64],
    zm: &'a [f64],
    zp: &'a [f64],
}

impl Rows<'_> {
    /// Relax `row` at `first, first + 2, ...` below `end` (all unknowns): the
    /// arithmetic of [`super::boxops::BoxView::half_sweep`], term by term.
    #[inline]
    fn sweep(&self, row: &mut [f64], f: Option<&[f64]>, first: usize, end: usize, w: f64) {
        let n = row.len();
        let (ym, yp, zm, zp) = (&self.ym[..n], &self.yp[..n], &self.zm[..n], &self.zp[..n]);
        for x in (first..end).step_by(2) {
            let nb = row[x - 1] + row[x + 1] + ym[x] + yp[x] + zm[x] + zp[x];
            let d = w * defect_of(f.map_or(0.0, |f| f[x]), nb, row[x]);
            row[x] += d;
        }
    }
}

/// `sweeps` red-black sweeps (red, then black) of the whole grid, in place.
fn sweeps(u: &mut [f64], runs: &Runs, f: Option<&[f64]>, shape: [usize; 3], n: usize) {
    for _ in 0..n {
        half_sweep(u, runs, f, shape, 0, 1.0);
        half_sweep(u, runs, f, shape, 1, 1.0);
    }
}

/// Over the unknowns of `u`: the largest |u - old| (with `old`), and the sum of squares
/// and count of the residual `defect / 6` (with `measure`), summed block by block (each
/// in z, y, x order) and the blocks in block order, as the block passes sum them.
fn block_stats(
    spec: &GridSpec,
    u: &[f64],
    old: Option<&[f64]>,
    mask: &[u8],
    f: Option<&[f64]>,
    measure: bool,
) -> (f64, f64, u64) {
    if old.is_none() && !measure {
        return (0.0, 0.0, 0);
    }
    let [_, ny, nx] = dims(spec);
    let (sy, sz) = (nx, nx * ny);
    let parts: Vec<(f64, f64, u64)> = spec
        .block_indices()
        .par_iter()
        .with_max_len(1)
        .map(|&b| {
            let s = spec.block_start(b).map(|c| c as usize);
            let e = [0, 1, 2].map(|a| s[a] + spec.block_shape(b)[a] as usize);
            let (mut max, mut sum, mut n) = (0.0f64, 0.0, 0u64);
            for z in s[0]..e[0] {
                for y in s[1]..e[1] {
                    let row = (z * ny + y) * nx;
                    for i in row + s[2]..row + e[2] {
                        if mask[i] != INTERIOR {
                            continue;
                        }
                        if let Some(old) = old {
                            max = max.max((u[i] - old[i]).abs());
                        }
                        if measure {
                            let r = defect_at(u, f, i, sy, sz) / 6.0;
                            sum += r * r;
                            n += 1;
                        }
                    }
                }
            }
            (max, sum, n)
        })
        .collect();
    parts.into_iter().fold((0.0f64, 0.0, 0), |a, p| {
        (a.0.max(p.0), a.1 + p.1, a.2 + p.2)
    })
}

/// The defect plane `z` (0 off the unknowns and on planes without two neighbours).
fn defect_plane(
    u: &[f64],
    mask: &[u8],
    f: Option<&[f64]>,
    shape: [usize; 3],
    z: i64,
    out: &mut [f64],
) {
    let [nz, ny, nx] = shape;
    out.fill(0.0);
    if z < 1 || z as usize + 1 >= nz {
        return;
    }
    let z = z as usize;
    let (sy, sz) = (nx, nx * ny);
    for y in 1..ny - 1 {
        let row = (z * ny + y) * nx;
        for x in 1..nx - 1 {
            if mask[row + x] == INTERIOR {
                out[y * nx + x] = defect_at(u, f, row + x, sy, sz);
            }
        }
    }
}

/// Full weighting of the defect of the fine level into the coarse right-hand side
/// (the same weights and order as [`super::boxops::restrict`]), and 0 off the coarse
/// unknowns.
fn restrict(
    fine: [usize; 3],
    u: &[f64],
    mask: &[u8],
    f: Option<&[f64]>,
    coarse: [usize; 3],
    cmask: &[u8],
    cf: &mut [f64],
) {
    let [_, ny, nx] = fine;
    let [_, cny, cnx] = coarse;
    let cp = cny * cnx;
    cf.par_chunks_mut(cp).enumerate().for_each(|(zc, out)| {
        let cm = &cmask[zc * cp..(zc + 1) * cp];
        if !cm.contains(&INTERIOR) {
            out.fill(0.0);
            return;
        }
        let mut d = vec![0.0; 3 * ny * nx];
        for (k, plane) in d.chunks_exact_mut(ny * nx).enumerate() {
            defect_plane(u, mask, f, fine, 2 * zc as i64 - 1 + k as i64, plane);
        }
        let p = ny * nx;
        for yc in 0..cny {
            for xc in 0..cnx {
                let o = yc * cnx + xc;
                if cm[o] != INTERIOR {
                    out[o] = 0.0;
                    continue;
                }
                out[o] = full_weighting(&d, p + (2 * yc) * nx + 2 * xc, nx, p);
            }
        }
    });
}

/// `u += scale * P e` at the unknowns, `P` trilinear interpolation from the coarse
/// level, axis by axis in the order of [`super::boxops::prolong`] (x, then y, then z).
fn prolong_add(
    fine: [usize; 3],
    u: &mut [f64],
    mask: &[u8],
    coarse: [usize; 3],
    e: &[f64],
    scale: f64,
) {
    let [nz, ny, nx] = fine;
    let [_, cny, cnx] = coarse;
    let p = ny * nx;
    // The coarse plane `zc` interpolated in x and then y, at the fine interior nodes.
    let plane_xy = |zc: usize, out: &mut Vec<f64>| {
        let mut ex = vec![0.0; cny * nx];
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
        out.resize(p, 0.0);
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
    };
    u.par_chunks_mut(p).enumerate().for_each(|(z, uz)| {
        if z == 0 || z + 1 >= nz {
            return;
        }
        let m = &mask[z * p..(z + 1) * p];
        if !m.contains(&INTERIOR) {
            return;
        }
        let (mut a, mut b) = (Vec::new(), Vec::new());
        plane_xy(z / 2, &mut a);
        if z % 2 == 1 {
            plane_xy(z / 2 + 1, &mut b);
        }
        for i in 0..p {
            if m[i] == INTERIOR {
                let c = if z % 2 == 1 {
                    0.5 * (a[i] + b[i])
                } else {
                    a[i]
                };
                uz[i] += scale * c;
            }
        }
    });
}

/// A level held as whole arrays.
pub struct Flat<'a> {
    /// Shape and blocks.
    pub spec: &'a GridSpec,
    /// Unknowns are `INTERIOR`.
    pub mask: &'a FlatStore<u8>,
    /// The two generations.
    pub u: [&'a FlatStore<f64>; 2],
    /// The right-hand side (coarse levels).
    pub f: Option<&'a FlatStore<f64>>,
    /// The unknowns as runs along x.
    pub runs: &'a Runs,
}

impl Flat<'_> {
    /// The level's stores as arrays, when all of them are.
    #[must_use]
    pub fn of(l: &super::multigrid::Level) -> Option<Flat<'_>> {
        let mask = l.mask.as_flat()?;
        Some(Flat {
            spec: &l.spec,
            mask,
            runs: l.runs.get_or_init(|| Runs::of(&mask.read(), dims(&l.spec))),
            u: [l.u[0].as_flat()?, l.u[1].as_flat()?],
            f: match &l.f {
                Some(f) => Some(f.as_flat()?),
                None => None,
            },
        })
    }

    /// Pre-smoothing: generation 1 = generation 0 after `n` sweeps; with `measure`, the
    /// residual of generation 0 first; then the restriction of the defect into
    /// `coarse` (its right-hand side, and a zero correction in its generation 0).
    pub fn pre(&self, n: usize, measure: bool, coarse: &Flat<'_>) -> (f64, u64) {
        let shape = dims(self.spec);
        let mask = self.mask.read();
        let f = self.f.map(FlatStore::read);
        let f = f.as_deref().map(Vec::as_slice);
        let u0 = self.u[0].read();
        let st = if measure {
            let (_, sum, n) = block_stats(self.spec, &u0, None, &mask, f, true);
            (sum, n)
        } else {
            (0.0, 0)
        };
        let mut u1 = self.u[1].write();
        u1.par_chunks_mut(1 << 16)
            .zip(u0.par_chunks(1 << 16))
            .for_each(|(d, s)| d.copy_from_slice(s));
        drop(u0);
        sweeps(&mut u1, self.runs, f, shape, n);
        let cmask = coarse.mask.read();
        let mut cf = coarse
            .f
            .expect("coarse levels have a right-hand side")
            .write();
        restrict(shape, &u1, &mask, f, dims(coarse.spec), &cmask, &mut cf);
        coarse.u[0].write().par_iter_mut().for_each(|v| *v = 0.0);
        st
    }

    /// Correction and post-smoothing: generation 0 = generation 1 plus `alpha` times the
    /// interpolated correction of `coarse`, after `n` sweeps. Returns the largest change
    /// against generation 0's previous content (with `change`) and the residual of the
    /// result (with `measure`).
    pub fn post(
        &self,
        n: usize,
        coarse: &Flat<'_>,
        alpha: f64,
        change: bool,
        measure: bool,
    ) -> (f64, (f64, u64)) {
        let shape = dims(self.spec);
        let mask = self.mask.read();
        let f = self.f.map(FlatStore::read);
        let f = f.as_deref().map(Vec::as_slice);
        let mut u1 = self.u[1].write();
        {
            let e = coarse.u[0].read();
            prolong_add(shape, &mut u1, &mask, dims(coarse.spec), &e, alpha);
        }
        sweeps(&mut u1, self.runs, f, shape, n);
        let mut u0 = self.u[0].write();
        // The result becomes generation 0; generation 1 keeps the old state, which the
        // next pre-smoothing overwrites.
        std::mem::swap(&mut *u0, &mut *u1);
        // The largest change against the old state and the residual of the new one, in
        // one pass.
        let old = change.then_some(&u1[..]);
        let (max, sum, n) = block_stats(self.spec, &u0, old, &mask, f, measure);
        let st = (sum, n);
        (max, st)
    }
}
