//! Folded voxels: where the volume map x -> ball point reverses orientation.
//!
//! The ball point of a voxel is p = phi d(theta, psi) = (1 - u) d. Its Jacobian by
//! central differences of u and of the direction (one-sided where a neighbour has no
//! value), in the chart of the ball around the voxel's own point ([`Jacobian`]), has a
//! negative determinant where the map folds. Block by block with a one-voxel halo,
//! within the budget; the folded voxels are grouped into 26-connected clusters, the
//! largest reported by size and centroid.

use std::collections::HashMap;

use glam::{DVec2, DVec3};
use serde::{Deserialize, Serialize};

use super::upwind::is_target;
use crate::grid::{BlockStore, Decomposition, GridError, GridSpec, MemBudget};
use crate::math::{volume, Idx3};
use crate::parallel::map_bounded;
use crate::progress::Progress;
use crate::trace::integrate::StopBall;

/// How many of the largest clusters the report lists.
const CLUSTERS: usize = 5;

/// A connected group of folded voxels.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FoldCluster {
    /// Its voxels (26-connected).
    pub voxels: u64,
    /// Its centroid, world (x, y, z).
    pub center: [f64; 3],
}

/// The folded voxels of a volume map.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Folded {
    /// Mapped voxels outside the stop ball whose Jacobian was measured.
    pub measured: u64,
    /// Of those, with a negative determinant.
    pub voxels: u64,
    /// Of those, with a zero determinant (neighbours whose stored angles are equal).
    pub degenerate: u64,
    /// The largest clusters of folded voxels, largest first.
    pub clusters: Vec<FoldCluster>,
    /// Whether the clusters were found among the first folded voxels only (more than
    /// the budget's share holds).
    pub clusters_partial: bool,
}

/// The unit directions of a block with a one-voxel halo (None where a voxel has none),
/// from the stored angles or from the direction field they were written from.
pub(super) type HaloDirections<'a> =
    &'a (dyn Fn(Idx3) -> Result<Vec<Option<DVec3>>, GridError> + Sync);

/// Count the folded voxels of the map (`u` and the directions `dirs` gives) over the
/// blocks `decomp` owns, outside `ball`, and group them into clusters over every part's
/// (the counts and the kept positions are gathered, so every part returns the whole
/// map's figures, the same as one process's); `dir_bytes` is what `dirs` holds for a
/// block. Also returns the folded voxels found ([z, y, x], in block order; the first
/// that the budget's share holds, see [`Folded::clusters_partial`]).
#[allow(clippy::too_many_arguments)]
pub(super) fn folded(
    u: &dyn BlockStore<f64>,
    labels: &dyn BlockStore<u8>,
    dirs: HaloDirections<'_>,
    dir_bytes: u64,
    ball: &StopBall,
    decomp: &dyn Decomposition,
    mem: MemBudget,
    progress: &dyn Progress,
) -> Result<(Folded, Vec<[u32; 3]>), crate::Error> {
    let spec = u.spec().clone();
    let blocks = decomp.owned(&spec);
    let halo = spec.chunk.map(|c| c + 2);
    let per_worker = volume(halo) * (8 + 32) + dir_bytes + volume(spec.chunk);
    let workers = mem.workers(
        "counting folded voxels (u, theta and psi of a block with a halo)",
        0,
        per_worker,
        rayon::current_num_threads(),
    )?;
    progress.start("map (folded voxels)", blocks.len() as u64);
    let per_block = map_bounded(&blocks, workers, |&b| -> Result<_, GridError> {
        let r = block(u, labels, dirs, ball, &spec, b)?;
        progress.advance(1);
        Ok(r)
    })?;
    progress.finish();
    let mut f = Folded::default();
    // Positions kept for the clusters: 12 bytes each, plus the union-find's ~40.
    let cap = (mem.work_bytes() / 4 / 64).max(1 << 16) as usize;
    let mut kept: Vec<[u32; 3]> = Vec::new();
    for (measured, degenerate, pos) in per_block {
        f.measured += measured;
        f.degenerate += degenerate;
        f.voxels += pos.len() as u64;
        for p in pos {
            if kept.len() < cap {
                kept.push(p);
            } else {
                f.clusters_partial = true;
            }
        }
    }
    if decomp.parts() > 1 {
        // The parts own slabs in block order: their kept positions one after another
        // are the first of the whole map's, as one process keeps them.
        let total = decomp.sum_u64(&[f.measured, f.degenerate, f.voxels])?;
        [f.measured, f.degenerate, f.voxels] = [total[0], total[1], total[2]];
        let mine = kept
            .iter()
            .flatten()
            .flat_map(|c| c.to_le_bytes())
            .collect();
        kept = decomp
            .all_gather_bytes(mine)?
            .iter()
            .flat_map(|b| {
                b.chunks_exact(12).map(|p| {
                    let c = |i: usize| u32::from_le_bytes(p[i..i + 4].try_into().expect("4"));
                    [c(0), c(4), c(8)]
                })
            })
            .take(cap)
            .collect();
        f.clusters_partial = f.voxels > kept.len() as u64;
    }
    f.clusters = clusters(&kept, &spec);
    Ok((f, kept))
}

/// One block: (voxels measured, degenerate, the folded voxels [z, y, x]).
#[allow(clippy::too_many_arguments, clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
fn block(
    u: &dyn BlockStore<f64>,
    labels: &dyn BlockStore<u8>,
    dirs: HaloDirections<'_>,
    ball: &StopBall,
    spec: &GridSpec,
    b: Idx3,
) -> Result<(u64, u64, Vec<[u32; 3]>), GridError> {
    let lab = labels.read_block(b)?;
    let uh = u.read_block_halo(b, 1, f64::NAN)?;
    let d = dirs(b)?;
    let [hz, hy, hx] = uh.shape;
    // Per halo voxel: u and the unit direction, or None.
    let point: Vec<Option<(f64, DVec3)>> = uh
        .data
        .iter()
        .zip(&d)
        .map(|(&uu, d)| d.filter(|_| uu.is_finite()).map(|d| (uu, d)))
        .collect();
    let start = spec.block_start(b);
    let shape = spec.block_shape(b);
    let strides = [hy * hx, hx, 1];
    let (mut measured, mut degenerate, mut folded) = (0u64, 0u64, Vec::new());
    let r2 = ball.radius * ball.radius;
    let mut li = 0;
    for z in 0..shape[0] as usize {
        for y in 0..shape[1] as usize {
            for x in 0..shape[2] as usize {
                let l = lab[li];
                li += 1;
                if !is_target(l) {
                    continue;
                }
                let g = [
                    start[0] + z as u64,
                    start[1] + y as u64,
                    start[2] + x as u64,
                ];
                let c = DVec3::new(g[2] as f64, g[1] as f64, g[0] as f64);
                if (c - ball.center).length_squared() <= r2 {
                    continue;
                }
                let i = ((z + 1) * hy + (y + 1)) * hx + (x + 1);
                let Some(p0) = point[i] else { continue };
                let pt = |j: usize| point[j];
                let Some(jac) = columns(pt, p0, i, strides) else {
                    continue;
                };
                let det = jac.det();
                measured += 1;
                if det < 0.0 {
                    folded.push(g.map(|c| c as u32));
                } else if det == 0.0 || !det.is_finite() {
                    degenerate += 1;
                }
            }
        }
    }
    debug_assert_eq!(hz, shape[0] as usize + 2);
    Ok((measured, degenerate, folded))
}

/// The Jacobian of the map x -> (u, direction) at a voxel with unit direction d0, by
/// central differences in a chart of the ball around the voxel's point: the
/// neighbours' directions projected stereographically onto the plane tangent at d0
/// (theta and psi measured about d0 would do as well; about the z axis the chart's
/// poles and psi's seam would be in the way) and 1 - u along the radius. The frame (e1, e2, d0) is right-handed, so
/// the determinant has the sign of the ball point p = (1 - u) d's Jacobian, the chart
/// being orientation-preserving.
///
/// Why not the differences of p itself: down a thin arm neighbouring directions differ
/// by 1e-5 to 1e-10 radians and u by 1e-17 per voxel, and the chord between two
/// points of a sphere of radius 1 - u has a part along d0 of |d - d0|^2 / 2 that differs
/// between the two sides (1e-12 where the directions are 1e-5 apart): far more than the
/// differences of u, so the radial row of those differences is the sphere's curvature,
/// not the map (and their sum in f64 rounds at 1e-16 besides). In the chart the radial
/// row is the differences of u alone.
#[derive(Clone, Copy, Debug)]
pub(super) struct Jacobian {
    /// The columns d / d x, d y, d z (world order), each (e1, e2, radial).
    pub cols: [DVec3; 3],
}

impl Jacobian {
    /// The determinant.
    #[must_use]
    pub fn det(&self) -> f64 {
        let [c0, c1, c2] = self.cols;
        c0.dot(c1.cross(c2))
    }

    /// The determinant over the product of the columns' lengths (-1 to 1; 0 where a
    /// column is zero): how far from folding, whatever the map's scale there.
    #[must_use]
    pub fn relative(&self) -> f64 {
        let n: f64 = self.cols.iter().map(|c| c.length()).product();
        if n > 0.0 && n.is_finite() {
            self.det() / n
        } else {
            0.0
        }
    }
}

/// The Jacobian at halo voxel `i` with point `p0` = (u, unit direction), from its
/// neighbours `pt(j)`: central differences, one-sided where a neighbour has no value;
/// None where an axis has neither. The halo's axes are z, y, x (`strides`).
#[inline]
pub(super) fn columns(
    pt: impl Fn(usize) -> Option<(f64, DVec3)>,
    p0: (f64, DVec3),
    i: usize,
    strides: [usize; 3],
) -> Option<Jacobian> {
    let d0 = p0.1;
    let e1 = d0.any_orthonormal_vector();
    let e2 = d0.cross(e1);
    // The chart: the stereographic projection from -d0 onto the plane tangent at d0
    // (conformal, orientation-preserving, the identity at d0; no trigonometry), from e
    // = d - d0, which keeps the differences' relative precision: the projection of d
    // is its tangent part over (1 + d . d0) / 2 = 1 - |e|^2 / 4.
    let chart = |(u, d): (f64, DVec3)| {
        let e = d - d0;
        let w = DVec2::new(e.dot(e1), e.dot(e2));
        (w / (1.0 - 0.25 * e.length_squared()), u)
    };
    let diff = |a: (f64, DVec3), b: (f64, DVec3)| {
        let ((wa, ua), (wb, ub)) = (chart(a), chart(b));
        let w = wb - wa;
        DVec3::new(w.x, w.y, ua - ub)
    };
    let mut cols = [DVec3::ZERO; 3];
    for (k, col) in cols.iter_mut().enumerate() {
        let s = strides[2 - k];
        *col = match (pt(i - s), pt(i + s)) {
            (Some(a), Some(b)) => diff(a, b),
            (None, Some(b)) => diff(p0, b),
            (Some(a), None) => diff(a, p0),
            (None, None) => return None,
        };
    }
    Some(Jacobian { cols })
}

/// The root of `i` in the union-find forest `parent` (halving the path).
pub(super) fn root(parent: &mut [usize], mut i: usize) -> usize {
    while parent[i] != i {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    i
}

/// The largest 26-connected clusters of `voxels` ([z, y, x], in block order), largest
/// first (ties: the cluster whose first voxel comes first).
fn clusters(voxels: &[[u32; 3]], spec: &GridSpec) -> Vec<FoldCluster> {
    let index: HashMap<[u32; 3], usize, foldhash::fast::FixedState> =
        voxels.iter().enumerate().map(|(i, &v)| (v, i)).collect();
    let mut parent: Vec<usize> = (0..voxels.len()).collect();
    for (i, v) in voxels.iter().enumerate() {
        for dz in -1i64..=1 {
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    let n = [
                        i64::from(v[0]) + dz,
                        i64::from(v[1]) + dy,
                        i64::from(v[2]) + dx,
                    ];
                    if n.iter().any(|&c| c < 0) {
                        continue;
                    }
                    if let Some(&j) = index.get(&n.map(|c| c as u32)) {
                        let (a, b) = (root(&mut parent, i), root(&mut parent, j));
                        if a != b {
                            parent[a.max(b)] = a.min(b);
                        }
                    }
                }
            }
        }
    }
    // Per root: count, sum of positions, first voxel.
    let mut acc: HashMap<usize, (u64, DVec3, usize), foldhash::fast::FixedState> =
        HashMap::default();
    for (i, v) in voxels.iter().enumerate() {
        let r = root(&mut parent, i);
        let p = spec.voxel_center(v.map(u64::from));
        let e = acc.entry(r).or_insert((0, DVec3::ZERO, i));
        e.0 += 1;
        e.1 += p;
        e.2 = e.2.min(i);
    }
    let mut all: Vec<(u64, DVec3, usize)> = acc.into_values().collect();
    all.sort_by(|a, b| b.0.cmp(&a.0).then(a.2.cmp(&b.2)));
    all.into_iter()
        .take(CLUSTERS)
        .map(|(n, s, _)| FoldCluster {
            voxels: n,
            center: (s / n as f64).to_array(),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Down a thin arm: directions 1e-10 apart around a direction with no zero
    /// component, u 1e-17 per voxel. The map x -> (u, d) has determinant a^2 c > 0
    /// in the chart everywhere; the differences of p = (1 - u) d have parts along d0
    /// (1e-17) far below the rounding of the components' differences (1e-16).
    #[test]
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn the_determinant_keeps_its_sign_down_a_thin_arm() {
        let d0 = DVec3::new(1.0, 2.0, 3.0).normalize();
        let e1 = d0.any_orthogonal_vector().normalize();
        let e2 = d0.cross(e1);
        let (a, b, c) = (1e-10, 0.7e-10, 1e-17);
        let (mut naive_negative, mut checked) = (0, 0);
        for s in 0..200 {
            let o = DVec3::new(
                f64::from(s) * 0.37,
                f64::from(s) * 0.11,
                f64::from(s) * 0.23,
            );
            let point = |x: f64, y: f64, z: f64| {
                let (x, y, z) = (x + o.x, y + o.y, z + o.z);
                let d = (d0 + e1 * (a * x + b * z) + e2 * (a * y)).normalize();
                (c * (1000.0 - z), d)
            };
            let pts: Vec<Option<(f64, DVec3)>> = (0..27)
                .map(|i| {
                    let (z, y, x) = (i / 9, (i / 3) % 3, i % 3);
                    Some(point(
                        f64::from(x) - 1.0,
                        f64::from(y) - 1.0,
                        f64::from(z) - 1.0,
                    ))
                })
                .collect();
            let jac = columns(|j| pts[j], pts[13].expect("set"), 13, [9, 3, 1]).expect("set");
            let det = jac.det();
            let want = (2.0 * a) * (2.0 * a) * (2.0 * c);
            assert!((det - want).abs() < 1e-3 * want, "{det} against {want}");
            // The columns as plain differences of (1 - u) d: their sign is noise.
            let p = |i: usize| pts[i].map(|(u, d)| d * (1.0 - u)).expect("set");
            let cols = [p(14) - p(12), p(16) - p(10), p(22) - p(4)];
            if cols[0].dot(cols[1].cross(cols[2])) < 0.0 {
                naive_negative += 1;
            }
            checked += 1;
        }
        assert_eq!(checked, 200);
        assert!(
            naive_negative > 10,
            "plain differences folded {naive_negative} times"
        );
    }

    #[test]
    #[allow(clippy::float_cmp)] // means of small integers: exact
    fn clusters_are_26_connected_groups_largest_first() {
        let spec = GridSpec {
            shape: [20, 20, 20],
            origin: [0.0; 3],
            spacing: 1.0,
            chunk: [8, 8, 8],
            unit: None,
        };
        // A diagonal line of 3 (corner-connected), a pair, and a single voxel.
        let v = vec![
            [1, 1, 1],
            [10, 10, 10],
            [2, 2, 2],
            [3, 3, 3],
            [15, 1, 1],
            [15, 1, 2],
        ];
        let c = clusters(&v, &spec);
        assert_eq!(
            c.iter().map(|c| c.voxels).collect::<Vec<_>>(),
            vec![3, 2, 1]
        );
        assert_eq!(c[0].center, [2.0, 2.0, 2.0]);
        assert_eq!(c[1].center, [1.5, 1.0, 15.0]);
    }
}
