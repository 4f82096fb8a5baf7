//! Where the true boundary crosses the arms of the solve's stencil: the array `cuts`
//! (docs/format.md), for inputs whose surface is known exactly (triangle meshes here,
//! molecules in [`super::mol_cuts`]).
//!
//! An arm is the segment from the center of a solid voxel that is not in the center
//! ball (an unknown of the solve) to the center of one of its six neighbours. It is cut
//! when that neighbour is held fixed: a non-solid voxel (the boundary, phi = 1, lies on
//! the arm where it crosses the mesh) or a voxel of the center ball (phi = 0 on the
//! exact sphere of `--center-radius` voxels). Its fraction `theta` in (0, 1] is the
//! distance from the voxel center to the crossing nearest to it, in voxels.
//!
//! Each voxel stores its six arms in one `u64`, 10 bits an arm in the order x-, x+, y-,
//! y+, z-, z+ (bits `10 k .. 10 k + 10`): 0 for an arm that is not cut, else
//! `q = round(1023 theta)` clamped to `1..=1023`. The clamp is the guard on tiny arms:
//! a crossing closer than 1/1023 voxel is taken at 1/1023, which keeps the solve's
//! diagonal bounded. A voxel without cut arms stores 0 (the fill value).
//!
//! Crossings with the mesh are exact ray/triangle crossings along each axis (the
//! triangle's plane met by the line through the voxel centers, for the triangles whose
//! projection holds the line, tested with exact orientation signs). An arm from a
//! solid voxel to a non-solid one that meets no triangle (voxels added by the closing or
//! the topology repair, which lie outside the mesh) is cut at the neighbour's center,
//! `theta = 1`: the staircase, there only.

// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

use robust::{orient2d, Coord};

use super::classify::CenterBall;
use super::labels::{BOUNDARY, CENTER, EXTERIOR, INTERIOR, LAYER1};
use crate::grid::{BlockStore, GridSpec};
use crate::input::TriMesh;
use crate::math::Idx3;
use crate::parallel::map_bounded;
use crate::progress::Progress;

/// The image of the run that holds the packed arms: `RUN/cuts/0`.
pub const NAME: &str = "cuts";

/// Bytes one worker holds: a block of labels with a halo of 1, the block's words, and
/// the crossing lists of its lines (a few per line).
#[must_use]
pub fn worker_bytes(chunk: u64) -> u64 {
    let c = chunk;
    (c + 2).pow(3) + 8 * c * c * c + 3 * c * c * (24 + 4 * 8)
}

/// Levels of the quantized fraction: `theta = q / LEVELS`.
pub const LEVELS: f64 = 1023.0;
/// Bits an arm takes in the packed word.
const BITS: u32 = 10;
/// The mask of one arm's bits.
const ARM: u64 = (1 << BITS) - 1;

/// The packed word of six arm fractions (0 for an arm that is not cut).
#[must_use]
pub fn encode(arms: [f64; 6]) -> u64 {
    let mut p = 0u64;
    for (k, &t) in arms.iter().enumerate() {
        if t > 0.0 {
            #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
            let q = ((t * LEVELS).round() as u64).clamp(1, ARM);
            p |= q << (BITS * k as u32);
        }
    }
    p
}

/// The fraction of arm `k` (x-, x+, y-, y+, z-, z+) in the packed word `p`; 0 when the
/// arm is not cut.
#[inline]
#[must_use]
pub fn arm(p: u64, k: usize) -> f64 {
    ((p >> (BITS * k as u32)) & ARM) as f64 / LEVELS
}

/// The arm index of a step along grid axis `a` (0 z, 1 y, 2 x) in direction `up`.
fn arm_index(a: usize, up: bool) -> usize {
    2 * (2 - a) + usize::from(up)
}

/// The distance in voxels from the voxel center `g` (outside `ball`) along axis `a`
/// (`up`: towards +) to the ball's sphere, whose inside holds the neighbour.
fn sphere_arm(ball: &CenterBall, g: [i64; 3], a: usize) -> f64 {
    let d = [0, 1, 2].map(|b| g[b] as f64 - ball.center[b]);
    let rest: f64 = (0..3).filter(|&b| b != a).map(|b| d[b] * d[b]).sum();
    let s = d[a].abs() - (ball.radius * ball.radius - rest).max(0.0).sqrt();
    s.clamp(0.0, 1.0)
}

/// Is label `l` a fixed non-solid voxel (the exterior layers, or beyond)?
fn outside(l: u8) -> bool {
    l == EXTERIOR || l >= LAYER1
}

/// A triangle in voxel coordinates `[z, y, x]`.
type Tri = [[f64; 3]; 3];

/// Write the cut arms of every block of `labels` into `out`; returns the number of
/// voxels with a cut arm and the number of arms to the exterior that met no triangle.
pub fn mesh_cuts(
    mesh: &TriMesh,
    labels: &dyn BlockStore<u8>,
    ball: CenterBall,
    out: &dyn BlockStore<u64>,
    workers: usize,
    progress: &dyn Progress,
) -> Result<(u64, u64), crate::Error> {
    let spec = labels.spec().clone();
    let tris: Vec<Tri> = mesh
        .triangles
        .iter()
        .map(|t| {
            t.map(|i| {
                let v = spec.world_to_voxel(mesh.vertices[i as usize]);
                [v.z, v.y, v.x]
            })
        })
        .collect();
    let bins = bin_by_block(&spec, &tris);
    cut_blocks(labels, ball, out, workers, progress, |b| {
        crossings(&spec, b, &tris, &bins[block_id(&spec, b)])
    })
}

/// Where the true boundary crosses the arms of one block's voxels.
pub(super) trait BlockCrossings {
    /// The fraction in `[0, 1]` of the arm from the solid voxel `g` (the block's voxel
    /// `local`) along grid axis `a` (`up`: towards +) at which the arm leaves the solid,
    /// or `None` when the surface does not cross it there.
    fn arm(&self, local: [usize; 3], g: [i64; 3], a: usize, up: bool) -> Option<f64>;
}

/// Write the cut arms of every block of `labels` into `out`, the crossings with the
/// surface from what `prepare` builds for a block, those with the center ball from its
/// sphere; returns the number of voxels with a cut arm and the number of arms to the
/// exterior that met no surface (held at the staircase, `theta = 1`).
#[allow(clippy::too_many_lines)] // one block: its arms in one pass
pub(super) fn cut_blocks<C: BlockCrossings>(
    labels: &dyn BlockStore<u8>,
    ball: CenterBall,
    out: &dyn BlockStore<u64>,
    workers: usize,
    progress: &dyn Progress,
    prepare: impl Fn(Idx3) -> C + Sync,
) -> Result<(u64, u64), crate::Error> {
    let spec = labels.spec().clone();
    let blocks = spec.block_indices();
    progress.start("voxelize: boundary crossings", blocks.len() as u64);
    let parts = map_bounded(&blocks, workers, |&b| -> Result<(u64, u64), crate::Error> {
        crate::progress::check_interrupt(progress)?;
        let r = labels.read_block_halo(b, 1, EXTERIOR)?;
        let s = spec.block_shape(b).map(|c| c as usize);
        let start = spec.block_start(b).map(|c| c as i64);
        let [hy, hx] = [r.shape[1], r.shape[2]];
        let at = |z: usize, y: usize, x: usize| r.data[(z * hy + y) * hx + x];
        let mut data = vec![0u64; s[0] * s[1] * s[2]];
        // Nothing to cut unless an unknown borders a fixed voxel.
        let needs = r.data.iter().any(|&l| l == BOUNDARY || l == CENTER)
            && r.data.iter().any(|&l| l == BOUNDARY || l == INTERIOR);
        let (mut cut, mut missed) = (0u64, 0u64);
        if needs {
            let rows = prepare(b);
            for z in 0..s[0] {
                for y in 0..s[1] {
                    for x in 0..s[2] {
                        let l = at(z + 1, y + 1, x + 1);
                        if l != BOUNDARY && l != INTERIOR {
                            continue;
                        }
                        let g = [
                            start[0] + z as i64,
                            start[1] + y as i64,
                            start[2] + x as i64,
                        ];
                        let mut arms = [0.0; 6];
                        for a in 0..3 {
                            for up in [false, true] {
                                let mut h = [z + 1, y + 1, x + 1];
                                h[a] = if up { h[a] + 1 } else { h[a] - 1 };
                                let nl = at(h[0], h[1], h[2]);
                                let k = arm_index(a, up);
                                if nl == CENTER {
                                    arms[k] = sphere_arm(&ball, g, a);
                                } else if outside(nl) {
                                    let t = rows.arm([z, y, x], g, a, up);
                                    if t.is_none() {
                                        missed += 1;
                                    }
                                    // A crossing at the voxel's own center is the
                                    // shortest arm, not an uncut one.
                                    arms[k] = t.unwrap_or(1.0).max(f64::MIN_POSITIVE);
                                }
                            }
                        }
                        let p = encode(arms);
                        if p != 0 {
                            cut += 1;
                        }
                        data[(z * s[1] + y) * s[2] + x] = p;
                    }
                }
            }
        }
        out.write_block(b, &data)?;
        progress.advance(1);
        Ok((cut, missed))
    })?;
    progress.finish();
    Ok(parts.iter().fold((0, 0), |(a, m), &(c, n)| (a + c, m + n)))
}

impl BlockCrossings for Rows {
    fn arm(&self, local: [usize; 3], g: [i64; 3], a: usize, up: bool) -> Option<f64> {
        nearest(self.row(a, local), g[a] as f64, up)
    }
}

/// The distance from `c` to the nearest crossing of `row` within one voxel in the
/// direction `up`.
fn nearest(row: &[f64], c: f64, up: bool) -> Option<f64> {
    row.iter()
        .map(|&t| if up { t - c } else { c - t })
        .filter(|&d| (0.0..=1.0).contains(&d))
        .min_by(f64::total_cmp)
}

fn block_id(spec: &GridSpec, b: Idx3) -> usize {
    let nb = spec.blocks();
    ((b[0] * nb[1] + b[1]) * nb[2] + b[2]) as usize
}

/// The triangles that may cross an arm of each block (bounding box widened by a voxel).
fn bin_by_block(spec: &GridSpec, tris: &[Tri]) -> Vec<Vec<u32>> {
    let nb = spec.blocks();
    let c = spec.chunk;
    let mut bins = vec![Vec::new(); (nb[0] * nb[1] * nb[2]) as usize];
    for (t, v) in tris.iter().enumerate() {
        let mut lo = [0u64; 3];
        let mut hi = [0u64; 3];
        let mut skip = false;
        for a in 0..3 {
            let mn = v[0][a].min(v[1][a]).min(v[2][a]) - 1.0;
            let mx = v[0][a].max(v[1][a]).max(v[2][a]) + 1.0;
            let n = spec.shape[a] as f64;
            if !(mx >= 0.0 && mn <= n - 1.0) {
                skip = true;
                break;
            }
            #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
            {
                lo[a] = (mn.floor().max(0.0) as u64).min(spec.shape[a] - 1) / c[a];
                hi[a] = (mx.ceil().max(0.0) as u64).min(spec.shape[a] - 1) / c[a];
            }
        }
        if skip {
            continue;
        }
        for bz in lo[0]..=hi[0] {
            for by in lo[1]..=hi[1] {
                for bx in lo[2]..=hi[2] {
                    bins[((bz * nb[1] + by) * nb[2] + bx) as usize].push(t as u32);
                }
            }
        }
    }
    bins
}

/// The crossings of the lines through a block's voxel centers, one list per line and
/// axis, in voxel coordinates along the line.
struct Rows {
    shape: [usize; 3],
    lines: [Vec<Vec<f64>>; 3],
}

impl Rows {
    /// The other two axes of axis `a`, in index order.
    fn others(a: usize) -> (usize, usize) {
        match a {
            0 => (1, 2),
            1 => (0, 2),
            _ => (0, 1),
        }
    }

    /// The crossings along axis `a` of the line through the block's local voxel `local`.
    fn row(&self, a: usize, local: [usize; 3]) -> &[f64] {
        let (p, q) = Self::others(a);
        &self.lines[a][local[p] * self.shape[q] + local[q]]
    }
}

/// The crossings of the mesh with the lines along each axis through the voxel centers
/// of block `b`, within a voxel of the block along the line.
fn crossings(spec: &GridSpec, b: Idx3, tris: &[Tri], list: &[u32]) -> Rows {
    let s = spec.block_shape(b).map(|c| c as usize);
    let start = spec.block_start(b).map(|c| c as f64);
    let lines = [0, 1, 2].map(|a| {
        let (p, q) = Rows::others(a);
        let mut rows = vec![Vec::new(); s[p] * s[q]];
        for &t in list {
            let v = tris[t as usize];
            let pc = v.map(|w| Coord { x: w[p], y: w[q] });
            let area = orient2d(pc[0], pc[1], pc[2]);
            if area == 0.0 {
                continue; // edge-on along this axis: no line crosses it
            }
            let lo = |k: usize| v[0][k].min(v[1][k]).min(v[2][k]);
            let hi = |k: usize| v[0][k].max(v[1][k]).max(v[2][k]);
            #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
            let range = |k: usize| {
                let a0 = (lo(k) - start[k]).ceil().max(0.0) as usize;
                let a1 = ((hi(k) - start[k]).floor() + 1.0).clamp(0.0, s[k] as f64) as usize;
                a0..a1
            };
            for i in range(p) {
                for j in range(q) {
                    let pt = Coord {
                        x: start[p] + i as f64,
                        y: start[q] + j as f64,
                    };
                    let e = [
                        orient2d(pc[1], pc[2], pt),
                        orient2d(pc[2], pc[0], pt),
                        orient2d(pc[0], pc[1], pt),
                    ];
                    // Inclusive: a line through an edge is crossed there (twice at
                    // worst, at the same point).
                    let inside = if area > 0.0 {
                        e.iter().all(|&x| x >= 0.0)
                    } else {
                        e.iter().all(|&x| x <= 0.0)
                    };
                    if !inside {
                        continue;
                    }
                    let t = (e[0] * v[0][a] + e[1] * v[1][a] + e[2] * v[2][a]) / area;
                    if t >= start[a] - 1.0 && t <= start[a] + s[a] as f64 {
                        rows[i * s[q] + j].push(t);
                    }
                }
            }
        }
        rows
    });
    Rows { shape: s, lines }
}

#[cfg(test)]
#[allow(clippy::float_cmp)] // quantized values and exact coefficients, compared exactly on purpose
mod tests {
    use super::*;

    #[test]
    fn arms_pack_into_ten_bits_each_and_tiny_arms_are_clamped() {
        let p = encode([0.0, 0.5, 1.0, 1e-6, 0.25, 0.0]);
        assert_eq!(arm(p, 0), 0.0);
        assert!((arm(p, 1) - 0.5).abs() <= 0.5 / LEVELS);
        assert_eq!(arm(p, 2), 1.0);
        assert_eq!(arm(p, 3), 1.0 / LEVELS);
        assert!((arm(p, 4) - 0.25).abs() <= 0.5 / LEVELS);
        assert_eq!(arm(p, 5), 0.0);
        assert_eq!(encode([0.0; 6]), 0);
        assert_eq!((arm_index(2, false), arm_index(2, true)), (0, 1));
        assert_eq!((arm_index(0, false), arm_index(0, true)), (4, 5));
    }

    #[test]
    fn sphere_arm_is_the_distance_to_the_sphere_along_the_axis() {
        let ball = CenterBall {
            center: [10.0, 10.0, 10.0],
            radius: 2.5,
        };
        // From (10, 10, 13) towards -x: the sphere at x = 12.5.
        assert!((sphere_arm(&ball, [10, 10, 13], 2) - 0.5).abs() < 1e-12);
        // From (10, 1 + 10, 13): sqrt(2.5^2 - 1) = 2.2913; 3 - 2.2913.
        let want = 3.0 - (2.5f64 * 2.5 - 1.0).sqrt();
        assert!((sphere_arm(&ball, [10, 11, 13], 2) - want).abs() < 1e-12);
    }
}
