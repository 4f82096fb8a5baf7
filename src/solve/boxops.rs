//! Kernels of the 7-point operator on a box read with a halo (the point kernels are in
//! [`super::stencil`]), for the block passes of multigrid, SOR and Jacobi: red-black sweeps over shrinking sub-boxes (several sweeps per read),
//! residuals, full-weighting restriction and trilinear prolongation.
//!
//! The equation at an unknown `i` of a level is `6 u_i - sum of its 6 neighbours = f_i`
//! (level units: `f = h^2 g` for `-lap u = g`); `f = 0` on the finest level, where fixed
//! values sit in `u`. On coarser levels `u` is a correction and every node that is not an
//! unknown holds 0. Unknowns are the voxels whose mask is
//! [`INTERIOR`]; they never lie on the grid's edge, so
//! their neighbours are always inside the grid.
//!
//! Colors are by global index parity (`z + y + x` even is red), so a sweep gives the same
//! values whatever the blocking.

use super::cuts::{is_unknown, CutArrays, CUT};
use super::stencil::{defect_at, defect_of, energy_term, full_weighting};
use crate::voxelize::labels::INTERIOR;

/// A box of a level held in memory: `u`, the mask and (coarse levels) `f`, all of
/// `shape`, whose first voxel sits at global index `origin`.
pub struct BoxView<'a> {
    /// Values, C order.
    pub u: &'a mut [f64],
    /// Which voxels are unknowns.
    pub mask: &'a [u8],
    /// Right-hand side; `None` means 0.
    pub f: Option<&'a [f64]>,
    /// The packed arms of a level of a run with cuts (where the mask is [`CUT`]);
    /// `None` on the staircase.
    pub cuts: Option<&'a [u64]>,
    /// Box extent `[z, y, x]`.
    pub shape: [usize; 3],
    /// Global index of the first voxel.
    pub origin: [i64; 3],
}

impl BoxView<'_> {
    fn strides(&self) -> (usize, usize) {
        (self.shape[2], self.shape[2] * self.shape[1])
    }

    /// `f + sum of neighbours - 6 u` at offset `i` (an unknown).
    #[inline]
    fn defect(&self, i: usize) -> f64 {
        let (sy, sz) = self.strides();
        defect_at(self.u, self.f, i, sy, sz)
    }

    /// The defect and the diagonal at the cut unknown at offset `i`.
    #[inline]
    fn cut(&self, i: usize) -> (f64, f64) {
        let (sy, sz) = self.strides();
        let cut = CutArrays {
            arms: self.cuts.expect("a CUT voxel on a level with cuts"),
            mask: self.mask,
            // A coarse level: a correction, with its right-hand side.
            coarse: self.f.is_some(),
        };
        cut.defect_in(self.u, self.f, i, sy, sz)
    }

    /// The defect at an unknown and the change a Jacobi step makes there (defect over
    /// the diagonal).
    #[inline]
    fn defect_and_step(&self, i: usize) -> (f64, f64) {
        if self.mask[i] == CUT {
            let (d, g) = self.cut(i);
            (d, d / g)
        } else {
            let d = self.defect(i);
            (d, d / 6.0)
        }
    }

    /// One red-black half-sweep of `color` (0 red, 1 black) over the local sub-box
    /// `[lo, hi)` (which must leave at least one voxel of the box on every side):
    /// `u_i += omega (f_i + sum of neighbours - 6 u_i) / 6`. Returns the largest change.
    pub fn half_sweep(&mut self, lo: [usize; 3], hi: [usize; 3], color: usize, omega: f64) -> f64 {
        let [_, ny, nx] = self.shape;
        let (sy, sz) = self.strides();
        let par = (self.origin[0] + self.origin[1] + self.origin[2]).rem_euclid(2) as usize;
        let w = omega / 6.0;
        let mut max = 0.0f64;
        for z in lo[0]..hi[0] {
            for y in lo[1]..hi[1] {
                let row = (z * ny + y) * nx;
                let x0 = lo[2] + (par + z + y + lo[2] + color) % 2;
                for x in (x0..hi[2]).step_by(2) {
                    let i = row + x;
                    if self.mask[i] != INTERIOR {
                        if self.mask[i] == CUT {
                            let (d, g) = self.cut(i);
                            let d = omega * d / g;
                            self.u[i] += d;
                            max = max.max(d.abs());
                        }
                        continue;
                    }
                    let u = &mut *self.u;
                    let nb = u[i - 1] + u[i + 1] + u[i - sy] + u[i + sy] + u[i - sz] + u[i + sz];
                    let d = w * defect_of(self.f.map_or(0.0, |f| f[i]), nb, u[i]);
                    u[i] += d;
                    max = max.max(d.abs());
                }
            }
        }
        max
    }

    /// `sweeps` red-black Gauss-Seidel sweeps (red then black), each half-sweep over a
    /// sub-box one voxel smaller on every face that `shrink` marks (faces inside the
    /// grid, whose halo values go stale), so that after them the values are exact on the
    /// box minus `2 * sweeps` voxels on those faces. Faces on the grid's edge stay put:
    /// nothing there is an unknown.
    pub fn sweeps(&mut self, sweeps: usize, shrink: [[bool; 2]; 3], omega: f64) {
        for j in 1..=2 * sweeps {
            let lo = [0, 1, 2].map(|a| if shrink[a][0] { j } else { 1 });
            let hi = [0, 1, 2].map(|a| self.shape[a] - if shrink[a][1] { j } else { 1 });
            if (0..3).any(|a| lo[a] >= hi[a]) {
                return;
            }
            self.half_sweep(lo, hi, (j - 1) % 2, omega);
        }
    }

    /// Sum of squares and count of the residual `r = defect / 6` over the local sub-box
    /// `[lo, hi)`, summed plane by plane (z), each plane in y, x order.
    #[must_use]
    pub fn residual_sq(&self, lo: [usize; 3], hi: [usize; 3]) -> (f64, u64) {
        let [_, ny, nx] = self.shape;
        let (mut s, mut n) = (0.0, 0u64);
        for z in lo[0]..hi[0] {
            // Summed plane by plane (the whole-array pass sums the same way).
            let mut plane = 0.0;
            for y in lo[1]..hi[1] {
                let row = (z * ny + y) * nx;
                for x in lo[2]..hi[2] {
                    if self.mask[row + x] == INTERIOR {
                        let r = self.defect(row + x) / 6.0;
                        plane += r * r;
                        n += 1;
                    } else if self.mask[row + x] == CUT {
                        let r = self.defect_and_step(row + x).1;
                        plane += r * r;
                        n += 1;
                    }
                }
            }
            s += plane;
        }
        (s, n)
    }

    /// The defect `f + sum of neighbours - 6 u` at every voxel of the sub-box `[lo, hi)`
    /// (0 where the voxel is not an unknown), as a C-order array of the sub-box.
    #[must_use]
    pub fn defects(&self, lo: [usize; 3], hi: [usize; 3]) -> Vec<f64> {
        let [_, ny, nx] = self.shape;
        let mut out = Vec::with_capacity((0..3).map(|a| hi[a] - lo[a]).product());
        for z in lo[0]..hi[0] {
            for y in lo[1]..hi[1] {
                let row = (z * ny + y) * nx;
                for x in lo[2]..hi[2] {
                    out.push(if self.mask[row + x] == INTERIOR {
                        self.defect(row + x)
                    } else if self.mask[row + x] == CUT {
                        self.cut(row + x).0
                    } else {
                        0.0
                    });
                }
            }
        }
        out
    }

    /// The change a Jacobi step makes at every voxel of the sub-box `[lo, hi)`: the
    /// defect over the diagonal (6, or a cut unknown's), 0 where the voxel is not an
    /// unknown; C order over the sub-box.
    #[must_use]
    pub fn steps(&self, lo: [usize; 3], hi: [usize; 3]) -> Vec<f64> {
        let [_, ny, nx] = self.shape;
        let mut out = Vec::with_capacity((0..3).map(|a| hi[a] - lo[a]).product());
        for z in lo[0]..hi[0] {
            for y in lo[1]..hi[1] {
                let row = (z * ny + y) * nx;
                for x in lo[2]..hi[2] {
                    out.push(if is_unknown(self.mask[row + x]) {
                        self.defect_and_step(row + x).1
                    } else {
                        0.0
                    });
                }
            }
        }
        out
    }
}

/// `c . A c` over the unknowns of the local sub-box `[lo, hi)` of a box of `shape`
/// (which must leave a voxel on every side of it), for a correction `c` on that box
/// taken as 0 off the unknowns; `A c = 6 c - sum of neighbours` (at cut unknowns too:
/// the staircase's energy, which only sets the correction's length). Summed plane by plane
/// (z), each plane in y, x order.
#[must_use]
pub fn correction_energy(
    mask: &[u8],
    c: &[f64],
    shape: [usize; 3],
    lo: [usize; 3],
    hi: [usize; 3],
) -> f64 {
    let [_, ny, nx] = shape;
    let (sy, sz) = (nx, nx * ny);
    let at = |j: usize| if is_unknown(mask[j]) { c[j] } else { 0.0 };
    let mut den = 0.0;
    for z in lo[0]..hi[0] {
        // Summed plane by plane (the whole-array pass sums the same way).
        let mut plane = 0.0;
        for y in lo[1]..hi[1] {
            let row = (z * ny + y) * nx;
            for i in row + lo[2]..row + hi[2] {
                if !is_unknown(mask[i]) {
                    continue;
                }
                plane += energy_term(
                    c[i],
                    at(i - 1) + at(i + 1) + at(i - sy) + at(i + sy) + at(i - sz) + at(i + sz),
                );
            }
        }
        den += plane;
    }
    den
}

/// Full weighting with the coarse-level scaling: the coarse right-hand side at coarse
/// node `I` is `4 * sum_d w(d) D(2I + d)`, `d` in `{-1, 0, 1}^3`, `w = 1/8` at the center,
/// `1/16` on faces, `1/32` on edges, `1/64` at corners (the factor 4 is `(2h)^2 / h^2`).
/// `d` is the fine defect array over the fine box whose first voxel is `d_origin`
/// (global) with extent `d_shape`, which must cover `2I - 1 ..= 2I + 1` for every coarse
/// node asked for. Writes the coarse box `[c_origin, c_origin + c_shape)` where
/// `c_mask` (same box) marks unknowns; 0 elsewhere.
#[must_use]
#[allow(clippy::many_single_char_names)] // grid axes (z, y, x) and stencil terms named as in the formulas
pub fn restrict(
    d: &[f64],
    d_origin: [i64; 3],
    d_shape: [usize; 3],
    c_mask: &[u8],
    c_origin: [i64; 3],
    c_shape: [usize; 3],
) -> Vec<f64> {
    let mut out = vec![0.0; c_shape.iter().product()];
    let (sy, sz) = (d_shape[2], d_shape[2] * d_shape[1]);
    for z in 0..c_shape[0] {
        for y in 0..c_shape[1] {
            for x in 0..c_shape[2] {
                let o = (z * c_shape[1] + y) * c_shape[2] + x;
                if !is_unknown(c_mask[o]) {
                    continue;
                }
                let g = [z, y, x].map(|v| v as i64);
                let l = [0, 1, 2].map(|a| (2 * (c_origin[a] + g[a]) - d_origin[a]) as usize);
                let c = (l[0] * d_shape[1] + l[1]) * d_shape[2] + l[2];
                out[o] = full_weighting(d, c, sy, sz);
            }
        }
    }
    out
}

/// Per-axis interpolation table: for each fine index of the box, the first coarse node
/// (local to the coarse box) and whether the fine node is odd (then it also takes the
/// next coarse node, both at half weight).
fn axis_table(origin: i64, n: usize, c_origin: i64) -> Vec<(usize, bool)> {
    (0..n as i64)
        .map(|l| {
            let g = origin + l;
            ((g.div_euclid(2) - c_origin) as usize, g.rem_euclid(2) == 1)
        })
        .collect()
}

#[inline]
fn interp(v: &[f64], t: (usize, bool)) -> f64 {
    if t.1 {
        0.5 * (v[t.0] + v[t.0 + 1])
    } else {
        v[t.0]
    }
}

/// The trilinear interpolant of the coarse correction `e` (box at `e_origin`, extent
/// `e_shape`, covering every coarse node the fine box needs, one past its last odd
/// node) at every voxel of the fine box at `origin` with extent `shape`, computed one
/// axis at a time.
#[must_use]
pub fn prolong(
    e: &[f64],
    e_origin: [i64; 3],
    e_shape: [usize; 3],
    origin: [i64; 3],
    shape: [usize; 3],
) -> Vec<f64> {
    let tz = axis_table(origin[0], shape[0], e_origin[0]);
    let ty = axis_table(origin[1], shape[1], e_origin[1]);
    let tx = axis_table(origin[2], shape[2], e_origin[2]);
    let [cz, cy, cx] = e_shape;
    let [nz, ny, nx] = shape;
    // x: coarse (z, y) rows to fine x.
    // (Each array is built by appending, so nothing is zeroed first.)
    let mut ex = Vec::with_capacity(cz * cy * nx);
    for r in 0..cz * cy {
        let src = &e[r * cx..(r + 1) * cx];
        ex.extend(tx.iter().map(|&t| interp(src, t)));
    }
    // y: coarse z planes to fine y.
    let mut exy = Vec::with_capacity(cz * ny * nx);
    for z in 0..cz {
        let plane = &ex[z * cy * nx..(z + 1) * cy * nx];
        for &t in &ty {
            let a = &plane[t.0 * nx..][..nx];
            if t.1 {
                let b = &plane[(t.0 + 1) * nx..][..nx];
                exy.extend(a.iter().zip(b).map(|(a, b)| 0.5 * (a + b)));
            } else {
                exy.extend_from_slice(a);
            }
        }
    }
    // z: to fine planes.
    let pn = ny * nx;
    let mut out = Vec::with_capacity(nz * pn);
    for &t in &tz {
        let a = &exy[t.0 * pn..][..pn];
        if t.1 {
            let b = &exy[(t.0 + 1) * pn..][..pn];
            out.extend(a.iter().zip(b).map(|(a, b)| 0.5 * (a + b)));
        } else {
            out.extend_from_slice(a);
        }
    }
    out
}

/// Add `scale` times the trilinear interpolant of the coarse correction `e` (see
/// [`prolong`]) to every unknown of the fine box `fine`.
pub fn prolong_add(
    fine: &mut BoxView<'_>,
    e: &[f64],
    e_origin: [i64; 3],
    e_shape: [usize; 3],
    scale: f64,
) {
    let c = prolong(e, e_origin, e_shape, fine.origin, fine.shape);
    for ((u, &m), c) in fine.u.iter_mut().zip(fine.mask).zip(&c) {
        if is_unknown(m) {
            *u += scale * c;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    #[allow(clippy::many_single_char_names)] // grid axes (z, y, x) and stencil terms named as in the formulas
    fn restriction_of_a_constant_defect_is_four_times_it_and_prolongation_is_exact_on_linear() {
        // Full weighting keeps constants (times the level factor 4).
        let n = 9;
        let d = vec![3.0; n * n * n];
        let mask = vec![INTERIOR; 27];
        let c = restrict(&d, [0; 3], [n; 3], &mask, [1, 1, 1], [3; 3]);
        assert!(c.iter().all(|&v| (v - 12.0).abs() < 1e-12), "{c:?}");
        // Trilinear interpolation reproduces a linear function of the coarse index.
        let es = [6usize; 3];
        let lin = |c: [f64; 3]| 1.0 + 2.0 * c[0] - 0.5 * c[1] + 0.25 * c[2];
        let mut e = vec![0.0; 216];
        for z in 0..6 {
            for y in 0..6 {
                for x in 0..6 {
                    e[(z * 6 + y) * 6 + x] = lin([z as f64, y as f64, x as f64]);
                }
            }
        }
        let fs = [7usize; 3];
        let mut u = vec![0.0; 343];
        let fmask = vec![INTERIOR; 343];
        let mut v = BoxView {
            u: &mut u,
            mask: &fmask,
            f: None,
            cuts: None,
            shape: fs,
            origin: [2, 3, 1],
        };
        prolong_add(&mut v, &e, [0; 3], es, 1.0);
        for z in 0..7 {
            for y in 0..7 {
                for x in 0..7 {
                    let g = [
                        (z + 2) as f64 / 2.0,
                        (y + 3) as f64 / 2.0,
                        (x + 1) as f64 / 2.0,
                    ];
                    assert!((u[(z * 7 + y) * 7 + x] - lin(g)).abs() < 1e-12);
                }
            }
        }
    }

    #[test]
    #[allow(clippy::many_single_char_names)] // grid axes (z, y, x) and stencil terms named as in the formulas
    fn shrinking_sweeps_on_a_haloed_box_equal_sweeps_on_the_whole_grid() {
        // Two Gauss-Seidel sweeps of a 20^3 grid, and the same two sweeps on a box of it
        // read with a halo of 4 (two layers per sweep), agree on the box interior.
        let n = 20usize;
        let mut mask = vec![0u8; n * n * n];
        let mut u = vec![0.0; n * n * n];
        let mut f = vec![0.0; n * n * n];
        for z in 0..n {
            for y in 0..n {
                for x in 0..n {
                    let i = (z * n + y) * n + x;
                    let edge = [z, y, x].iter().any(|&c| c == 0 || c == n - 1);
                    mask[i] = if edge || (z * 7 + y * 3 + x) % 11 == 0 {
                        1
                    } else {
                        INTERIOR
                    };
                    u[i] = ((i * 37) % 101) as f64 / 101.0;
                    f[i] = ((i * 13) % 7) as f64 / 7.0 - 0.5;
                }
            }
        }
        let mut whole = u.clone();
        let mut w = BoxView {
            u: &mut whole,
            mask: &mask,
            f: Some(&f),
            cuts: None,
            shape: [n; 3],
            origin: [0; 3],
        };
        w.sweeps(2, [[false; 2]; 3], 1.0);
        // The box [5, 13) x [3, 11) x [7, 15) with halo 4: [1, 17) x [-1, 15) x [3, 19).
        let org = [1i64, -1, 3];
        let sh = [16usize, 16, 16];
        let take = |v: &[f64], fill: f64| -> Vec<f64> {
            let mut out = vec![fill; 16 * 16 * 16];
            for z in 0..16 {
                for y in 0..16 {
                    for x in 0..16 {
                        let g = [org[0] + z, org[1] + y, org[2] + x];
                        if g.iter().all(|&c| c >= 0 && c < n as i64) {
                            out[((z * 16 + y) * 16 + x) as usize] =
                                v[((g[0] as usize) * n + g[1] as usize) * n + g[2] as usize];
                        }
                    }
                }
            }
            out
        };
        let mut bu = take(&u, 0.0);
        let bm: Vec<u8> = take(&mask.iter().map(|&m| f64::from(m)).collect::<Vec<_>>(), 0.0)
            .iter()
            .map(|&m| m as u8)
            .collect();
        let bf = take(&f, 0.0);
        let mut b = BoxView {
            u: &mut bu,
            mask: &bm,
            f: Some(&bf),
            cuts: None,
            shape: sh,
            origin: org,
        };
        // The y face at -1 lies off the grid: it does not shrink.
        b.sweeps(2, [[true, true], [false, true], [true, true]], 1.0);
        for z in 4..12 {
            for y in 4..12 {
                for x in 4..12 {
                    let g = [org[0] + z, org[1] + y, org[2] + x].map(|c| c as usize);
                    let wv = whole[(g[0] * n + g[1]) * n + g[2]];
                    assert_eq!(bu[((z * 16 + y) * 16 + x) as usize].to_bits(), wv.to_bits());
                }
            }
        }
    }
}
