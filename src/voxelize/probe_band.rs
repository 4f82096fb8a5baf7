//! The fast path of the molecular solid of one block: atoms drawn into the block ball by
//! ball, and for the SES an exact Euclidean distance transform that decides every voxel
//! except those near the probe boundary.
//!
//! [`rasterize`] visits, for each atom near the block, only the voxels of its ball's
//! rows (a few more at each end) and makes the same distance test as a voxel-by-atom
//! loop, so the inside sets are the same to the bit; the cost is the balls' volume, not
//! voxels times atoms.
//!
//! [`ProbeBand`] is the SES's erosion of the solvent-accessible (SAS) solid by the probe,
//! as EDTSurf (Xu and Zhang, 2009) does it, but with the probe centers the exact test
//! uses: the free, solvent-facing samples of the SAS spheres (see [`super::spheres`]).
//! Each sample marks the voxel whose center is nearest to it (at most `h = sqrt(3)/2`
//! voxel away), and the separable exact transform of Felzenszwalb and Huttenlocher
//! ([`super::closing::edt_sq`]) gives every voxel of the block, read with a halo of one
//! probe radius, the distance `D` to the nearest marked center. Every sample is then
//! between `D - h` and `D + h` away: `D - h >= probe` proves that no probe center reaches
//! the voxel (solid), `D + h < probe` that one does (not solid), and only the voxels in
//! between, a shell about two voxels thick around the SES surface, ask the k-d tree of
//! samples for the exact nearest distance. The solid is therefore the same, voxel for
//! voxel, as asking the tree everywhere.
// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

use glam::DVec3;

use crate::grid::GridSpec;
use crate::math::Idx3;

/// Voxel state written by [`rasterize`]: outside every grown ball.
pub const OUT: u8 = 0;
/// Inside a grown ball (radius + grow) but no atom.
pub const GROWN: u8 = 1;
/// Inside an atom's own ball.
pub const ATOM: u8 = 2;

/// Largest halo box (voxels) the transform uses per block; beyond it (a probe of tens
/// of voxels) every voxel asks the tree.
const MAX_BOX: u64 = 1 << 21;

/// Per voxel of the block at `st` of shape `sh`: [`ATOM`] where the center is within an
/// atom's radius of one of the atoms `near`, [`GROWN`] where within radius + `grow`,
/// [`OUT`] elsewhere. The test is `|p - c|^2 <= r^2` on the voxel center `p`, as
/// computed by [`GridSpec::voxel_center`].
#[must_use]
pub fn rasterize(
    spec: &GridSpec,
    st: Idx3,
    sh: Idx3,
    near: &[u32],
    centers: &[DVec3],
    radii: &[f64],
    grow: f64,
) -> Vec<u8> {
    let (nz, ny, nx) = (sh[0] as usize, sh[1] as usize, sh[2] as usize);
    let mut out = vec![OUT; nz * ny * nx];
    let s = spec.spacing;
    let o = spec.origin;
    // Voxel index range (block-local, clamped) of [a - w, b + w] along one axis, with a
    // voxel of slack at each end; the exact test decides inside it.
    let range = |lo_w: f64, hi_w: f64, org: f64, start: u64, n: usize| -> (usize, usize) {
        let a = ((lo_w - org) / s).floor() - 1.0 - start as f64;
        let b = ((hi_w - org) / s).ceil() + 1.0 - start as f64;
        let a = a.max(0.0);
        let b = b.min(n as f64 - 1.0);
        if a > b {
            (1, 0)
        } else {
            (a as usize, b as usize)
        }
    };
    for &i in near {
        let (c, r) = (centers[i as usize], radii[i as usize]);
        let g = r + grow;
        let (r2, g2) = (r * r, g * g);
        let (z0, z1) = range(c.z - g, c.z + g, o[2], st[0], nz);
        let (y0, y1) = range(c.y - g, c.y + g, o[1], st[1], ny);
        for z in z0..=z1 {
            let pz = o[2] + s * (st[0] + z as u64) as f64;
            let dz2 = (pz - c.z) * (pz - c.z);
            if dz2 > g2 * (1.0 + 1e-9) + s * s {
                continue;
            }
            for y in y0..=y1 {
                let py = o[1] + s * (st[1] + y as u64) as f64;
                let rem = g2 - dz2 - (py - c.y) * (py - c.y);
                if rem < -(g2 * 1e-9 + s * s) {
                    continue;
                }
                let w = rem.max(0.0).sqrt();
                let (x0, x1) = range(c.x - w, c.x + w, o[0], st[2], nx);
                if x0 > x1 {
                    continue;
                }
                let row = (z * ny + y) * nx;
                for x in x0..=x1 {
                    let p =
                        spec.voxel_center([st[0] + z as u64, st[1] + y as u64, st[2] + x as u64]);
                    let d2 = (p - c).length_squared();
                    let v = &mut out[row + x];
                    if d2 <= r2 {
                        *v = ATOM;
                    } else if d2 <= g2 && *v == OUT {
                        *v = GROWN;
                    }
                }
            }
        }
    }
    out
}

/// Distances from the voxels of one block to the voxels that hold a probe center.
pub struct ProbeBand {
    /// Squared distance (voxels) per voxel of the block; infinite: none in the box.
    dist: Vec<f32>,
    /// The block's shape `[z, y, x]`.
    shape: [usize; 3],
    /// What decides: the probe radius and `h` (world units), and a tolerance for
    /// rounding.
    probe: f64,
    h: f64,
    tol: f64,
    spacing: f64,
}

/// What the band says of one voxel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// No probe center within the probe radius: solid.
    Solid,
    /// A probe center within the probe radius: not solid.
    Open,
    /// Too close to call from the voxels: ask the probe centers.
    Ask,
}

/// Halo (voxels) of the transform box for a probe of `probe` on `spacing`.
#[must_use]
pub fn halo(probe: f64, spacing: f64) -> u64 {
    let h = 0.5 * 3f64.sqrt() * spacing;
    ((probe + h) / spacing).ceil() as u64 + 1
}

/// Bytes one worker holds for the transform of a block of `chunk` voxels a side (0 when
/// the probe is too wide for it, see [`ProbeBand::new`]).
#[must_use]
pub fn worker_bytes(chunk: u64, probe: f64, spacing: f64) -> u64 {
    let e = chunk + 2 * halo(probe, spacing);
    if e * e * e > MAX_BOX.max(chunk * chunk * chunk) {
        return 0;
    }
    // The marks (bool), the f32 work array, the block's distances and a few lines.
    e * e * e * (1 + 4) + chunk * chunk * chunk * 4 + 64 * e
}

impl ProbeBand {
    /// The band of the block at `st` of shape `sh` for probe centers `pts` (world
    /// `(x, y, z)`), or `None` when the halo box would exceed the transform's limit.
    #[must_use]
    pub fn new(spec: &GridSpec, st: Idx3, sh: Idx3, pts: &[[f64; 3]], probe: f64) -> Option<Self> {
        let s = spec.spacing;
        let halo = halo(probe, s) as usize;
        let shape = sh.map(|n| n as usize + 2 * halo);
        let n = shape[0] * shape[1] * shape[2];
        if n as u64 > MAX_BOX.max(sh[0] * sh[1] * sh[2]) {
            return None;
        }
        let mut mark = vec![false; n];
        for q in pts {
            let v = spec.world_to_voxel(DVec3::from_array(*q)).round();
            let idx = [v.z, v.y, v.x];
            let mut lin = 0usize;
            let mut inside = true;
            for a in 0..3 {
                let k = idx[a] - st[a] as f64 + halo as f64;
                if k < 0.0 || k >= shape[a] as f64 {
                    inside = false;
                    break;
                }
                lin = lin * shape[a] + k as usize;
            }
            if inside {
                mark[lin] = true;
            }
        }
        let dist = edt_inner(&mark, shape, halo);
        Some(Self {
            dist,
            shape: sh.map(|n| n as usize),
            probe,
            h: 0.5 * 3f64.sqrt() * s,
            tol: 1e-6 * s,
            spacing: s,
        })
    }

    /// The verdict for block-local voxel `[z, y, x]`.
    #[must_use]
    pub fn verdict(&self, z: usize, y: usize, x: usize) -> Verdict {
        let [_, ny, nx] = self.shape;
        let e = self.dist[(z * ny + y) * nx + x];
        if e.is_infinite() {
            return Verdict::Solid;
        }
        let d = f64::from(e).sqrt() * self.spacing;
        if d - self.h > self.probe + self.tol {
            Verdict::Solid
        } else if d + self.h + self.tol < self.probe {
            Verdict::Open
        } else {
            Verdict::Ask
        }
    }
}

/// Squared Euclidean distance (voxels, exact integers in `f32`) from each voxel of the
/// inner box (the box of `shape` without `halo` voxels on every side) to the nearest
/// marked voxel of the whole box; infinite when there is none. Separable: the nearest
/// mark along each row, then the lower envelope of parabolas (Felzenszwalb and
/// Huttenlocher, "Distance transforms of sampled functions", 2012) along y for the
/// inner columns and along z for the inner (y, x), so the halo is transformed only as
/// far as the inner box needs.
#[must_use]
pub fn edt_inner(mark: &[bool], shape: [usize; 3], halo: usize) -> Vec<f32> {
    let [nz, ny, nx] = shape;
    let inner = shape.map(|n| n - 2 * halo);
    let mut g = vec![f32::INFINITY; nz * ny * nx];
    // Rows along x: distance to the nearest mark, both ways.
    for row in 0..nz * ny {
        let m = &mark[row * nx..(row + 1) * nx];
        if !m.contains(&true) {
            continue;
        }
        let gr = &mut g[row * nx..(row + 1) * nx];
        let mut last: Option<usize> = None;
        for x in 0..nx {
            if m[x] {
                last = Some(x);
            }
            if let Some(l) = last {
                gr[x] = ((x - l) * (x - l)) as f32;
            }
        }
        last = None;
        for x in (0..nx).rev() {
            if m[x] {
                last = Some(x);
            }
            if let Some(l) = last {
                gr[x] = gr[x].min(((l - x) * (l - x)) as f32);
            }
        }
    }
    let n = nx.max(ny).max(nz);
    let mut f = vec![0f32; n];
    let mut d = vec![0f32; n];
    let mut v = vec![0usize; n];
    let mut zb = vec![0f32; n + 1];
    // Columns along y, for the inner x only.
    for z in 0..nz {
        for x in halo..halo + inner[2] {
            let base = z * ny * nx + x;
            let mut any = false;
            for (y, fy) in f[..ny].iter_mut().enumerate() {
                *fy = g[base + y * nx];
                any |= fy.is_finite();
            }
            if !any {
                continue;
            }
            envelope(&f[..ny], &mut d[..ny], &mut v, &mut zb);
            for (y, dy) in d[..ny].iter().enumerate() {
                g[base + y * nx] = *dy;
            }
        }
    }
    // Along z, for the inner (y, x), into the inner box.
    let mut out = vec![f32::INFINITY; inner[0] * inner[1] * inner[2]];
    for y in 0..inner[1] {
        for x in 0..inner[2] {
            let base = (y + halo) * nx + x + halo;
            let mut any = false;
            for (z, fz) in f[..nz].iter_mut().enumerate() {
                *fz = g[base + z * ny * nx];
                any |= fz.is_finite();
            }
            if !any {
                continue;
            }
            envelope(&f[..nz], &mut d[..nz], &mut v, &mut zb);
            for z in 0..inner[0] {
                out[(z * inner[1] + y) * inner[2] + x] = d[z + halo];
            }
        }
    }
    out
}

/// The lower envelope of the parabolas `(q - p)^2 + f(p)` over the finite `f(p)`, at
/// every `q`, into `d` (`f` has a finite value).
fn envelope(f: &[f32], d: &mut [f32], v: &mut [usize], zb: &mut [f32]) {
    let sq = |p: usize| (p * p) as f32;
    let mut k: usize = 0;
    let mut started = false;
    for q in 0..f.len() {
        if !f[q].is_finite() {
            continue;
        }
        if !started {
            started = true;
            v[0] = q;
            zb[0] = f32::NEG_INFINITY;
            zb[1] = f32::INFINITY;
            continue;
        }
        loop {
            let p = v[k];
            let s = ((f[q] + sq(q)) - (f[p] + sq(p))) / (2 * (q - p)) as f32;
            // zb[0] is minus infinity, so k stays >= 0.
            if s <= zb[k] {
                k -= 1;
                continue;
            }
            k += 1;
            v[k] = q;
            zb[k] = s;
            zb[k + 1] = f32::INFINITY;
            break;
        }
    }
    let mut j = 0usize;
    for (q, dq) in d.iter_mut().enumerate() {
        while zb[j + 1] < q as f32 {
            j += 1;
        }
        let p = v[j];
        let t = q.abs_diff(p);
        *dq = (t * t) as f32 + f[p];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inner_distances_match_brute_force() {
        let (shape, halo) = ([13usize, 11, 12], 3usize);
        let n: usize = shape.iter().product();
        let pos = |i: usize| {
            [
                i / (shape[1] * shape[2]),
                (i / shape[2]) % shape[1],
                i % shape[2],
            ]
        };
        for seed in [37usize, 101, 997] {
            let mark: Vec<bool> = (0..n).map(|i| (i * seed) % 211 == 5).collect();
            let d = edt_inner(&mark, shape, halo);
            let inner = shape.map(|s| s - 2 * halo);
            for z in 0..inner[0] {
                for y in 0..inner[1] {
                    for x in 0..inner[2] {
                        let p = [z + halo, y + halo, x + halo];
                        let best = (0..n)
                            .filter(|&j| mark[j])
                            .map(|j| {
                                let q = pos(j);
                                (0..3).map(|a| p[a].abs_diff(q[a]).pow(2)).sum::<usize>() as f32
                            })
                            .fold(f32::INFINITY, f32::min);
                        // Exact integers (or both infinite): compare their bits.
                        assert_eq!(
                            d[(z * inner[1] + y) * inner[2] + x].to_bits(),
                            best.to_bits(),
                            "{p:?} seed {seed}"
                        );
                    }
                }
            }
        }
    }
}
