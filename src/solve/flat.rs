//! The multigrid passes for levels held in memory as whole arrays ([`FlatStore`]): the
//! same operations as the block passes of [`super::multigrid`], done in place on the
//! arrays, with no box copies and no halo recomputation.
//!
//! Every value is computed with the same arithmetic in the same order as in the block
//! passes (red-black sweeps do not depend on the order within a color; the residual and
//! c.Ac are summed per block, plane by plane, blocks in block order; restriction and
//! prolongation are per node), so
//! a level in memory and a level in scratch files give the same bytes. The tests that
//! compare budgets check it.
//!
//! A half-sweep is parallel over slabs of z planes: a node of one color reads only
//! nodes of the other color, which the half-sweep does not change. The even slabs go
//! first, then the odd ones, so a slab borrows the planes next to it from slabs that
//! are not being written. The other passes run over slabs of whole planes too, with
//! buffers lent per task from pools that live with the level.

use std::sync::atomic::{AtomicBool, Ordering};

use rayon::prelude::*;

use super::boxops::{defect_at, defect_of, energy_term, full_weighting};

use crate::grid::{FlatStore, GridSpec};
use crate::parallel::Pool;
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

    /// The runs of plane `z` as ranges of offsets into the plane (rows of `nx`).
    fn ranges(&self, z: usize, nx: usize) -> impl Iterator<Item = std::ops::Range<usize>> + '_ {
        self.planes[z].iter().map(move |&(y, x0, x1)| {
            let r = y as usize * nx;
            r + x0 as usize..r + x1 as usize
        })
    }
}

/// The block columns `(by, bx)` of a grid. The block passes sum per block, plane by
/// plane; a whole-array pass gives the same sums by keeping one sum per plane and
/// column and adding them up per block at the end.
struct Columns {
    chunk: [usize; 3],
    nz: usize,
    nbx: usize,
    count: usize,
}

impl Columns {
    fn of(spec: &GridSpec) -> Self {
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
    fn split(&self, y: usize, x0: usize, x1: usize) -> impl Iterator<Item = (usize, usize, usize)> {
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
    fn total(&self, spec: &GridSpec, planes: &[Vec<f64>]) -> f64 {
        let cz = self.chunk[0];
        spec.block_indices()
            .iter()
            .map(|&[bz, by, bx]| {
                let (bz, col) = (bz as usize, by as usize * self.nbx + bx as usize);
                let mut s = 0.0;
                for plane in &planes[bz * cz..((bz + 1) * cz).min(self.nz)] {
                    s += plane[col];
                }
                s
            })
            .sum()
    }
}

/// What the whole-array passes of a level keep between passes: the runs of its
/// unknowns (built on first use), whether both generations hold the fixed values, and
/// buffers lent to the passes' tasks (at most [`PASS_PLANES`] planes per thread in all;
/// the memory plan counts them, see [`pass_bytes`]).
#[derive(Default)]
pub struct Cache {
    runs: std::sync::OnceLock<Runs>,
    planes: Pool<Vec<f64>>,
    prolong: Pool<PlanePair>,
    energy: Pool<(PlanePair, Vec<Vec<f64>>)>,
    /// Both generations hold the fixed values: set by the first pre-smoothing, which
    /// writes generation 1 whole (post-smoothing swaps the two); cleared by
    /// [`Cache::state_replaced`].
    fixed_in_both: AtomicBool,
}

/// Planes of f64 a thread's buffers hold in the pools of one level: restriction 3,
/// prolongation 2.5, c.Ac 5.5 (each rounded up in the sum).
pub const PASS_PLANES: u64 = 12;

/// Bytes the whole-array passes of a level of `spec` keep with `threads` threads: the
/// pools' planes, and the runs of unknowns (counted at two runs per row).
#[must_use]
pub fn pass_bytes(spec: &GridSpec, threads: usize) -> u64 {
    let [nz, ny, nx] = spec.shape;
    threads as u64 * PASS_PLANES * ny * nx * 8 + 2 * nz * ny * 12
}

impl Cache {
    /// Generation 0 was written whole from outside the passes (initialized, or read
    /// from a checkpoint): the next pre-smoothing writes generation 1 whole again.
    pub fn state_replaced(&self) {
        self.fixed_in_both.store(false, Ordering::Relaxed);
    }
}

/// Planes per slab when `n` planes are cut into slabs for the whole-array passes: about
/// eight slabs per thread (work stealing evens out slabs of unequal work).
fn slab_planes(n: usize) -> usize {
    n.div_ceil(8 * rayon::current_num_threads()).max(1)
}

fn dims(spec: &GridSpec) -> [usize; 3] {
    spec.shape.map(|c| c as usize)
}

/// One red-black half-sweep of `color` over the whole grid, in place. `f`: the
/// right-hand side (coarse levels).
///
/// The planes `1..nz-1` are cut into slabs, several per thread, relaxed in two rounds:
/// the even slabs, then the odd ones. A slab reads the planes next to it, which belong
/// to slabs of the other round (or are the grid's first and last planes), so a round
/// borrows its own slabs mutably and the others shared: no copies and no locks.
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
                    rows.relax(row, fz.map(|fz| &fz[r]), [x0, x1], z + y + color, w);
                }
            }
        });
    }
}

/// The rows around the row being relaxed: y - 1, y + 1, z - 1 and z + 1.
struct Rows<'a> {
    ym: &'a [f64],
    yp: &'a [f64],
    zm: &'a [f64],
    zp: &'a [f64],
}

impl Rows<'_> {
    /// Relax the voxels of the run `x0..x1` of `row` whose `(z + y + x) % 2` is the
    /// color: `parity` is `z + y + color`.
    #[inline]
    fn relax(
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

/// `n` red-black sweeps (red, then black) of the whole grid, in place; with `src`, of
/// `src` into `u` (the first half-sweep reads `src` and writes the unknowns of `u`, and
/// the fixed voxels too unless `u` already holds them).
fn sweeps(
    u: &mut [f64],
    src: Option<(&[f64], bool)>,
    cache: &Cache,
    f: Option<&[f64]>,
    shape: [usize; 3],
    n: usize,
) {
    let runs = cache
        .runs
        .get()
        .expect("runs are built with the level's Flat");
    for k in 0..n {
        match src {
            Some((src, fixed)) if k == 0 => relax_from(u, src, fixed, runs, f, shape, 0, 1.0),
            _ => half_sweep(u, runs, f, shape, 0, 1.0),
        }
        half_sweep(u, runs, f, shape, 1, 1.0);
    }
    if n == 0 {
        if let Some((src, _)) = src {
            u.par_chunks_mut(1 << 16)
                .zip(src.par_chunks(1 << 16))
                .for_each(|(d, s)| d.copy_from_slice(s));
        }
    }
}

/// `u` = `src` after a half-sweep of `color`, in one pass: the unknowns of each plane
/// are copied and those of `color` relaxed with neighbours read from `src` (they are
/// of the other color, which the half-sweep leaves alone, so the values are those an
/// in-place half-sweep of the copy would read). The fixed voxels are the same in
/// every state: with `fixed`, `u` holds them already and only the unknowns are
/// written; otherwise whole planes are copied.
#[allow(clippy::too_many_arguments)]
fn relax_from(
    u: &mut [f64],
    src: &[f64],
    fixed: bool,
    runs: &Runs,
    f: Option<&[f64]>,
    shape: [usize; 3],
    color: usize,
    omega: f64,
) {
    let [nz, ny, nx] = shape;
    let p = ny * nx;
    let w = omega / 6.0;
    u.par_chunks_mut(p).enumerate().for_each(|(z, cur)| {
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
        for &(y, x0, x1) in &runs.planes[z] {
            let (y, x0, x1) = (y as usize, x0 as usize, x1 as usize);
            let r = y * nx..(y + 1) * nx;
            let rows = Rows {
                ym: &here[(y - 1) * nx..y * nx],
                yp: &here[(y + 1) * nx..(y + 2) * nx],
                zm: &prev[r.clone()],
                zp: &next[r.clone()],
            };
            let row = &mut cur[r.clone()];
            if fixed {
                row[x0..x1].copy_from_slice(&here[y * nx + x0..y * nx + x1]);
            }
            rows.relax(row, fz.map(|fz| &fz[r]), [x0, x1], z + y + color, w);
        }
    });
}

/// Over the unknowns of `u`: the largest |u - old| (with `old`), and the sum of squares
/// and count of the residual `defect / 6` (with `measure`), summed as the block passes
/// sum them: per block, plane by plane, each plane in y, x order; the blocks in block
/// order. Parallel over slabs of planes, which keep one sum per block column and plane.
fn block_stats(
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

/// The defect plane `z` (0 off the unknowns, and off the grid).
fn defect_plane(
    u: &[f64],
    runs: &Runs,
    f: Option<&[f64]>,
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
        let (y, x0, x1) = (y as usize, x0 as usize, x1 as usize);
        let row = (z * ny + y) * nx;
        for x in x0..x1 {
            out[y * nx + x] = defect_at(u, f, row + x, sy, sz);
        }
    }
}

/// Full weighting of the defect of the fine level into the coarse right-hand side
/// (the same weights and order as [`super::boxops::restrict`]), and 0 off the coarse
/// unknowns. Parallel over slabs of coarse planes; within a slab, the fine defect
/// plane `2 zc + 1` of one coarse plane is the plane `2 zc' - 1` of the next, and is
/// kept rather than computed twice.
#[allow(clippy::too_many_arguments)]
fn restrict(
    fine: [usize; 3],
    u: &[f64],
    runs: &Runs,
    f: Option<&[f64]>,
    coarse: [usize; 3],
    cmask: &[u8],
    cf: &mut [f64],
    planes: &Pool<Vec<f64>>,
) {
    let [_, ny, nx] = fine;
    let [cnz, cny, cnx] = coarse;
    let (p, cp) = (ny * nx, cny * cnx);
    let per = slab_planes(cnz);
    cf.par_chunks_mut(per * cp)
        .enumerate()
        .for_each(|(slab, outs)| {
            planes.with(|d| {
                d.resize(3 * p, 0.0);
                // The fine plane held in d's last third.
                let mut last: Option<i64> = None;
                for (k, out) in outs.chunks_exact_mut(cp).enumerate() {
                    let zc = slab * per + k;
                    let cm = &cmask[zc * cp..(zc + 1) * cp];
                    if !cm.contains(&INTERIOR) {
                        out.fill(0.0);
                        continue;
                    }
                    let z0 = 2 * zc as i64 - 1;
                    if last == Some(z0) {
                        d.copy_within(2 * p.., 0);
                    } else {
                        defect_plane(u, runs, f, fine, z0, &mut d[..p]);
                    }
                    defect_plane(u, runs, f, fine, z0 + 1, &mut d[p..2 * p]);
                    defect_plane(u, runs, f, fine, z0 + 2, &mut d[2 * p..]);
                    last = Some(z0 + 2);
                    for yc in 0..cny {
                        for xc in 0..cnx {
                            let o = yc * cnx + xc;
                            out[o] = if cm[o] == INTERIOR {
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

/// Coarse planes interpolated in x and y onto the fine plane (see [`prolong_add`]),
/// two of them, tagged with the coarse plane each holds.
#[derive(Default)]
pub struct PlanePair {
    tag: [Option<usize>; 2],
    buf: [Vec<f64>; 2],
    ex: Vec<f64>,
}

/// The interpolated correction at offset `i` of fine plane `z`, from the coarse planes
/// [`PlanePair::planes_for`] gives: the mean of the two for odd `z` (the z step of
/// [`super::boxops::prolong`]).
#[inline]
fn correction_at(a: &[f64], b: &[f64], z: usize, i: usize) -> f64 {
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
    fn planes_for(
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
    fn get(
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
/// into `out`; `ex` is scratch. The arithmetic of [`super::boxops::prolong`].
fn interpolate_xy(
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
/// level, axis by axis in the order of [`super::boxops::prolong`] (x, then y, then z).
/// Parallel over slabs of fine planes; a slab interpolates each coarse plane it needs
/// in x and y once (a fine plane takes one or two of them, its neighbours share them).
#[allow(clippy::too_many_arguments)]
fn prolong_add(
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
    /// The runs of the unknowns and the passes' buffers.
    pub cache: &'a Cache,
}

impl Flat<'_> {
    /// The level's stores as arrays, when all of them are.
    #[must_use]
    pub fn of(l: &super::multigrid::Level) -> Option<Flat<'_>> {
        let mask = l.mask.as_flat()?;
        Some(Flat {
            spec: &l.spec,
            mask,
            cache: {
                l.flat
                    .runs
                    .get_or_init(|| Runs::of(&mask.read(), dims(&l.spec)));
                &l.flat
            },
            u: [l.u[0].as_flat()?, l.u[1].as_flat()?],
            f: match &l.f {
                Some(f) => Some(f.as_flat()?),
                None => None,
            },
        })
    }

    fn runs(&self) -> &Runs {
        self.cache
            .runs
            .get()
            .expect("Flat::of builds the runs of the level")
    }

    /// `c . A c` of the interpolated correction `c = P e` of `coarse`: the sum of
    /// [`super::boxops::correction_energy`] over the blocks in block order, each summed
    /// plane by plane, with the same arithmetic. Parallel over slabs of planes; a slab
    /// keeps `c` (0 off the unknowns) on three planes and interpolates each coarse
    /// plane once.
    #[must_use]
    pub fn correction_energy(&self, coarse: &Flat<'_>) -> f64 {
        let spec = self.spec;
        let [nz, ny, nx] = dims(spec);
        let p = ny * nx;
        let cols = Columns::of(spec);
        let e = coarse.u[0].read();
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

    /// Pre-smoothing: generation 1 = generation 0 after `n` sweeps; with `measure`, the
    /// residual of generation 0 first; then the restriction of the defect into
    /// `coarse` (its right-hand side, and a zero correction in its generation 0).
    pub fn pre(&self, n: usize, measure: bool, coarse: &Flat<'_>) -> (f64, u64) {
        let shape = dims(self.spec);
        let f = self.f.map(FlatStore::read);
        let f = f.as_deref().map(Vec::as_slice);
        let u0 = self.u[0].read();
        let st = if measure {
            let (_, sum, n) = block_stats(self.spec, &u0, None, self.runs(), f, true);
            (sum, n)
        } else {
            (0.0, 0)
        };
        let mut u1 = self.u[1].write();
        // Generation 1 holds the fixed values once it has been written whole.
        let fixed = self.cache.fixed_in_both.swap(true, Ordering::Relaxed);
        sweeps(&mut u1, Some((&u0, fixed)), self.cache, f, shape, n);
        drop(u0);
        let cmask = coarse.mask.read();
        let mut cf = coarse
            .f
            .expect("coarse levels have a right-hand side")
            .write();
        restrict(
            shape,
            &u1,
            self.runs(),
            f,
            dims(coarse.spec),
            &cmask,
            &mut cf,
            &self.cache.planes,
        );
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
        let f = self.f.map(FlatStore::read);
        let f = f.as_deref().map(Vec::as_slice);
        let mut u1 = self.u[1].write();
        {
            let e = coarse.u[0].read();
            prolong_add(
                shape,
                &mut u1,
                self.runs(),
                dims(coarse.spec),
                &e,
                alpha,
                &self.cache.prolong,
            );
        }
        sweeps(&mut u1, None, self.cache, f, shape, n);
        let mut u0 = self.u[0].write();
        // The result becomes generation 0; generation 1 keeps the old state, which the
        // next pre-smoothing overwrites.
        std::mem::swap(&mut *u0, &mut *u1);
        // The largest change against the old state and the residual of the new one, in
        // one pass.
        let old = change.then_some(&u1[..]);
        let (max, sum, n) = block_stats(self.spec, &u0, old, self.runs(), f, measure);
        let st = (sum, n);
        (max, st)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn columns_split_runs_at_block_edges_and_total_sums_per_block_in_block_order() {
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
