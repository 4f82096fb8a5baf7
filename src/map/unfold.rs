//! Unfolding: the directions of the voxels around a fold moved until no voxel of it
//! folds.
//!
//! The map x -> p = (1 - u) d of a streamline flow cannot fold (streamlines do not
//! cross), but its samples can: at a pole of the starfish the arrival directions of
//! neighbouring voxels turn by tens of degrees over a voxel and the central differences
//! no longer see the map's orientation, and next to the boundary one-sided differences
//! of an upwind map that is a tenth of a degree off can turn over. As the trace untangles
//! the sphere map of its surface seeds, the map untangles its folds: u stays (it is the
//! solve's), and the direction of a voxel in a fold's stencil moves on the sphere to
//! where the Jacobians it enters (its own and its six neighbours') are fewest negative
//! and the worst of them is least negative (relative to its columns' lengths), with a
//! compass search whose steps are fractions of the distance to its neighbours'
//! directions and toward their mean. Sweeps run until no Jacobian of the box folds or
//! one moves nothing; a box that stalls takes the stencils of its stencil voxels too,
//! up to [`RINGS`] of them.
//!
//! The folded voxels are grouped (those within `2 MARGIN` voxels of each other),
//! each group's bounding box widened by [`MARGIN`] and cut into boxes of at most
//! [`CORE`] voxels a side plus the margin; the boxes are worked one after another in
//! a fixed order, each reading the moves of those before it, so the result depends on
//! neither the threads nor the budget. A voxel moves only at least two voxels inside its
//! box, so every Jacobian it enters has its whole stencil in the box. Voxels in the
//! stop ball keep their direction (the ray from the center), and their Jacobians are
//! not measured, as in [`super::folds`].

use std::collections::{BTreeMap, HashMap};

use glam::DVec3;
use serde::{Deserialize, Serialize};

use super::folds::{columns, root, Jacobian};
use super::upwind::is_target;
use crate::grid::{BlockStore, Decomposition, GridError, GridSpec};
use crate::math::Idx3;
use crate::progress::Progress;
use crate::trace::integrate::StopBall;
use crate::trace::{angles, unit};

/// Voxels between a folded voxel and the face of its box.
const MARGIN: i64 = 4;
/// The largest side of a box's core (its margin not counted).
const CORE: i64 = 56;
/// How many times a stalled box widens the voxels it moves.
const RINGS: usize = 3;
/// Sweeps over a box's moving voxels, at most, per ring.
const SWEEPS: usize = 40;
/// Sweeps in a row that clear no fold before a ring gives up.
const STALE_SWEEPS: usize = 3;
/// How far a voxel's direction may move: this many times the largest distance from
/// its direction as mapped to its neighbours'.
const TRUST: f64 = 1.0;
/// Sweeps of the way back toward the directions as mapped, at most.
const BACK_SWEEPS: usize = 50;
/// Step lengths of the compass search: the distance to the farthest neighbour's
/// direction over 4^0 .. 4^(STEPS - 1). A sheet the map squeezes to a curve on the
/// sphere folds across the curve far below the steps along it; finer steps than these
/// cleared fewer folds on fandisk, cheburashka and adk_open, at twice the time.
const STEPS: i32 = 6;
/// Moves of one voxel per visit, at most.
const MOVES_PER_VISIT: usize = 2;

/// What unfolding did.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Unfold {
    /// Folded voxels before (those the count kept the positions of).
    pub folded_before: u64,
    /// Boxes worked.
    pub boxes: u64,
    /// Voxels whose direction moved.
    pub moved: u64,
    /// The median and the largest move, degrees.
    pub median_move_degrees: f64,
    /// The largest move, degrees.
    pub max_move_degrees: f64,
    /// Seconds spent moving the directions.
    #[serde(default)]
    pub seconds: f64,
    /// Seconds spent counting the folded voxels again.
    #[serde(default)]
    pub seconds_recount: f64,
}

/// Moved angles, by linear voxel index.
type Moves = BTreeMap<u64, (f64, f64)>;

/// Unfold the map around `folded` (positions [z, y, x] of folded voxels), reading u
/// and the labels and the (staged) angles `theta` and `psi`, and write the moved
/// angles into the blocks `decomp` owns. Every part works every box (the same bytes),
/// so every part returns the same report.
#[allow(clippy::too_many_arguments)]
pub(super) fn unfold(
    u: &dyn BlockStore<f64>,
    labels: &dyn BlockStore<u8>,
    theta: &dyn BlockStore<f64>,
    psi: &dyn BlockStore<f64>,
    ball: &StopBall,
    folded: &[[u32; 3]],
    decomp: &dyn Decomposition,
    progress: &dyn Progress,
) -> Result<Unfold, GridError> {
    let t0 = std::time::Instant::now();
    let spec = u.spec().clone();
    let boxes = boxes(folded, &spec);
    progress.start("map (unfolding)", boxes.len() as u64);
    let mut moves = Moves::new();
    let mut original: HashMap<u64, DVec3> = HashMap::new();
    for (lo, hi) in &boxes {
        let b = Region::read(u, labels, theta, psi, ball, &spec, *lo, *hi, &moves)?;
        for (k, d0, d1) in b.untangle() {
            original.entry(k).or_insert(d0);
            moves.insert(k, angles(d1));
        }
        progress.advance(1);
    }
    progress.finish();
    // The moves, with a voxel moved back where it started left out.
    let mut degrees: Vec<f64> = Vec::new();
    moves.retain(|k, &mut (t, p)| {
        let a = original[k].angle_between(unit(t, p)).to_degrees();
        if a > 0.0 {
            degrees.push(a);
        }
        a > 0.0
    });
    // Every part has read what it needs before any part writes its blocks: a part
    // still reading a block another part rewrites would read a torn chunk.
    decomp.barrier()?;
    write(theta, psi, &spec, &moves, decomp)?;
    degrees.sort_by(f64::total_cmp);
    Ok(Unfold {
        folded_before: folded.len() as u64,
        boxes: boxes.len() as u64,
        moved: moves.len() as u64,
        median_move_degrees: degrees.get(degrees.len() / 2).copied().unwrap_or(0.0),
        max_move_degrees: degrees.last().copied().unwrap_or(0.0),
        seconds: t0.elapsed().as_secs_f64(),
        seconds_recount: 0.0,
    })
}

/// Write `moves` into the blocks of `theta` and `psi` that `decomp` owns.
fn write(
    theta: &dyn BlockStore<f64>,
    psi: &dyn BlockStore<f64>,
    spec: &GridSpec,
    moves: &Moves,
    decomp: &dyn Decomposition,
) -> Result<(), GridError> {
    let n = spec.shape;
    let mut by_block: BTreeMap<Idx3, Vec<(usize, f64, f64)>> = BTreeMap::new();
    for (&k, &(t, p)) in moves {
        let g = [k / (n[1] * n[2]), (k / n[2]) % n[1], k % n[2]];
        let b = [0, 1, 2].map(|a| g[a] / spec.chunk[a]);
        let st = spec.block_start(b);
        let sh = spec.block_shape(b);
        let l = (((g[0] - st[0]) * sh[1] + (g[1] - st[1])) * sh[2] + (g[2] - st[2])) as usize;
        by_block.entry(b).or_default().push((l, t, p));
    }
    let blocks: Vec<_> = by_block
        .into_iter()
        .filter(|(b, _)| decomp.owns(spec, *b))
        .collect();
    crate::parallel::map_bounded(&blocks, 2, |(b, vs)| -> Result<(), GridError> {
        let mut th = theta.read_block(*b)?;
        let mut ps = psi.read_block(*b)?;
        for &(l, t, p) in vs {
            th[l] = t;
            ps[l] = p;
        }
        theta.write_block(*b, &th)?;
        psi.write_block(*b, &ps)
    })?;
    Ok(())
}

/// The boxes ([lo, hi) in grid [z, y, x], margin included, possibly off the grid) that
/// cover the folded voxels, in a fixed order.
fn boxes(folded: &[[u32; 3]], spec: &GridSpec) -> Vec<([i64; 3], [i64; 3])> {
    // Group: union-find over buckets of 2 MARGIN voxels a side.
    let pos: Vec<[i64; 3]> = folded.iter().map(|v| v.map(i64::from)).collect();
    let cell = 2 * MARGIN;
    let mut buckets: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for (i, p) in pos.iter().enumerate() {
        buckets
            .entry(p.map(|c| c.div_euclid(cell)))
            .or_default()
            .push(i);
    }
    let mut parent: Vec<usize> = (0..pos.len()).collect();
    for (i, p) in pos.iter().enumerate() {
        let c = p.map(|c| c.div_euclid(cell));
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let Some(js) = buckets.get(&[c[0] + dz, c[1] + dy, c[2] + dx]) else {
                        continue;
                    };
                    for &j in js {
                        let q = pos[j];
                        if (0..3).all(|a| (p[a] - q[a]).abs() <= cell) {
                            let (a, b) = (root(&mut parent, i), root(&mut parent, j));
                            if a != b {
                                parent[a.max(b)] = a.min(b);
                            }
                        }
                    }
                }
            }
        }
    }
    let mut groups: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for i in 0..pos.len() {
        let r = root(&mut parent, i);
        groups.entry(r).or_default().push(i);
    }
    let grid = spec.shape.map(|c| c as i64);
    let mut out = Vec::new();
    for members in groups.values() {
        let mut lo = [i64::MAX; 3];
        let mut hi = [i64::MIN; 3];
        for &i in members {
            for a in 0..3 {
                lo[a] = lo[a].min(pos[i][a]);
                hi[a] = hi[a].max(pos[i][a] + 1);
            }
        }
        // Cut the core into tiles of at most CORE a side; keep those with a folded voxel.
        let tiles = [0, 1, 2].map(|a| ((hi[a] - lo[a]) + CORE - 1) / CORE);
        for tz in 0..tiles[0] {
            for ty in 0..tiles[1] {
                for tx in 0..tiles[2] {
                    let t = [tz, ty, tx];
                    let clo: [i64; 3] = std::array::from_fn(|a| lo[a] + t[a] * CORE);
                    let chi: [i64; 3] = std::array::from_fn(|a| (clo[a] + CORE).min(hi[a]));
                    if !members
                        .iter()
                        .any(|&i| (0..3).all(|a| pos[i][a] >= clo[a] && pos[i][a] < chi[a]))
                    {
                        continue;
                    }
                    out.push((
                        std::array::from_fn(|a| (clo[a] - MARGIN).max(-2)),
                        std::array::from_fn(|a| (chi[a] + MARGIN).min(grid[a] + 2)),
                    ));
                }
            }
        }
    }
    out
}

/// The unit direction of `c`'s angles as stored (f64 theta and psi): what a move
/// writes, so the Jacobians checked are those of the stored map.
fn stored(c: DVec3) -> DVec3 {
    let (t, p) = angles(c.normalize());
    unit(t, p)
}

/// A box of the map in memory.
struct Region {
    /// Its first voxel (grid z, y, x; may be off the grid).
    origin: [i64; 3],
    /// Its extent [z, y, x].
    shape: [usize; 3],
    /// Per voxel: u and the unit direction of its angles, where it has both.
    point: Vec<Option<(f64, DVec3)>>,
    /// Per voxel: whether its Jacobian is measured (a target voxel outside the stop
    /// ball, one voxel inside the box).
    measured: Vec<bool>,
    /// Per voxel: whether it may move (a target voxel outside the stop ball with a
    /// direction, two voxels inside the box).
    movable: Vec<bool>,
    /// The grid's shape, for linear indices.
    grid: [u64; 3],
}

impl Region {
    /// Read the box [lo, hi) with the moves made so far.
    #[allow(clippy::too_many_arguments)]
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn read(
        u: &dyn BlockStore<f64>,
        labels: &dyn BlockStore<u8>,
        theta: &dyn BlockStore<f64>,
        psi: &dyn BlockStore<f64>,
        ball: &StopBall,
        spec: &GridSpec,
        lo: [i64; 3],
        hi: [i64; 3],
        moves: &Moves,
    ) -> Result<Self, GridError> {
        let shape = [0, 1, 2].map(|a| (hi[a] - lo[a]) as usize);
        let uu = u.read_region(lo, shape, f64::NAN)?.data;
        let lab = labels.read_region(lo, shape, 0)?.data;
        let th = theta.read_region(lo, shape, f64::NAN)?.data;
        let ps = psi.read_region(lo, shape, f64::NAN)?.data;
        let grid = spec.shape;
        let n = uu.len();
        let (mut point, mut target) = (vec![None; n], vec![false; n]);
        let r2 = ball.radius * ball.radius;
        for z in 0..shape[0] {
            for y in 0..shape[1] {
                for x in 0..shape[2] {
                    let i = (z * shape[1] + y) * shape[2] + x;
                    let g = [lo[0] + z as i64, lo[1] + y as i64, lo[2] + x as i64];
                    let inside = (0..3).all(|a| g[a] >= 0 && (g[a] as u64) < grid[a]);
                    if !inside {
                        continue;
                    }
                    let k = ((g[0] as u64 * grid[1]) + g[1] as u64) * grid[2] + g[2] as u64;
                    let (t, p) = moves.get(&k).copied().unwrap_or((th[i], ps[i]));
                    if uu[i].is_finite() && t.is_finite() && p.is_finite() {
                        point[i] = Some((uu[i], unit(t, p)));
                    }
                    let c = DVec3::new(g[2] as f64, g[1] as f64, g[0] as f64);
                    target[i] = is_target(lab[i]) && (c - ball.center).length_squared() > r2;
                }
            }
        }
        let mut r = Self {
            origin: lo,
            shape,
            point,
            measured: vec![false; n],
            movable: vec![false; n],
            grid,
        };
        for (i, &t) in target.iter().enumerate() {
            r.measured[i] = t && r.depth_at_least(i, 1);
            r.movable[i] = t && r.depth_at_least(i, 2) && r.point[i].is_some();
        }
        Ok(r)
    }

    /// Strides of the box's axes z, y, x.
    fn strides(&self) -> [usize; 3] {
        [self.shape[1] * self.shape[2], self.shape[2], 1]
    }

    /// The Jacobian at box voxel `i`, if it is measured and has one.
    fn jacobian(&self, i: usize) -> Option<Jacobian> {
        if !self.measured[i] {
            return None;
        }
        let p0 = self.point[i]?;
        columns(|j| self.point[j], p0, i, self.strides())
    }

    /// The stencil of voxel `i` (itself and its six neighbours).
    fn stencil(&self, i: usize) -> [usize; 7] {
        let s = self.strides();
        [
            i,
            i - s[0],
            i + s[0],
            i - s[1],
            i + s[1],
            i - s[2],
            i + s[2],
        ]
    }

    /// The box coordinates [z, y, x] of box voxel `i`.
    fn coords(&self, i: usize) -> [usize; 3] {
        let s = self.strides();
        [i / s[0], (i / s[1]) % self.shape[1], i % self.shape[2]]
    }

    /// Whether box voxel `i` is at least `d` voxels from the box's faces.
    fn depth_at_least(&self, i: usize, d: usize) -> bool {
        let c = self.coords(i);
        (0..3).all(|a| c[a] >= d && c[a] + d < self.shape[a])
    }

    /// Whether the Jacobian at box voxel `i` is measured and folds.
    fn folds_at(&self, i: usize) -> bool {
        self.jacobian(i).is_some_and(|jac| jac.det() < 0.0)
    }

    /// How the Jacobians that voxel `i` enters stand: (negative ones, the least
    /// relative determinant). Smaller negatives, then a larger least, is better.
    fn score(&self, i: usize) -> (usize, f64) {
        let mut neg = 0;
        let mut least = f64::INFINITY;
        for j in self.stencil(i) {
            if let Some(jac) = self.jacobian(j) {
                let det = jac.det();
                if det < 0.0 {
                    neg += 1;
                }
                least = least.min(jac.relative());
            }
        }
        (neg, least)
    }

    /// Move the voxels around the box's folds; returns (linear index, old direction,
    /// new direction) of every voxel that moved, in box order.
    fn untangle(mut self) -> Vec<(u64, DVec3, DVec3)> {
        let n = self.point.len();
        let start = self.point.clone();
        let mut bad: Vec<usize> = (0..n).filter(|&j| self.folds_at(j)).collect();
        let mut ring = 1;
        while !bad.is_empty() && ring <= RINGS {
            // The voxels that move: the stencils of the folded ones, grown `ring` times.
            let mut active: Vec<usize> = bad.clone();
            for _ in 0..ring {
                let mut next: Vec<usize> = active
                    .iter()
                    .flat_map(|&j| self.stencil(j))
                    .filter(|&j| self.depth_at_least(j, 1))
                    .collect();
                next.sort_unstable();
                next.dedup();
                active = next;
            }
            active.retain(|&i| self.movable[i]);
            // The Jacobians the moves can change (the folded ones among them).
            let mut watch: Vec<usize> = active.iter().flat_map(|&i| self.stencil(i)).collect();
            watch.extend(&bad);
            watch.sort_unstable();
            watch.dedup();

            let mut fewest = bad.len();
            let mut stale = 0;
            for _ in 0..SWEEPS {
                let mut moved = false;
                for &i in &active {
                    moved |= self.improve(i, &start);
                }
                bad = watch
                    .iter()
                    .copied()
                    .filter(|&j| self.folds_at(j))
                    .collect();
                if bad.is_empty() || !moved {
                    break;
                }
                // Sweeps that leave as many folds only polish the worst Jacobian.
                if bad.len() < fewest {
                    (fewest, stale) = (bad.len(), 0);
                } else {
                    stale += 1;
                    if stale == STALE_SWEEPS {
                        break;
                    }
                }
            }
            ring += 1;
        }
        self.go_back(&start);
        let mut out = Vec::new();
        for (i, (a, b)) in start.iter().zip(&self.point).enumerate() {
            if let (Some(a), Some(b)) = (a, b) {
                if a.1 != b.1 {
                    out.push((self.linear(i), a.1, b.1));
                }
            }
        }
        out
    }

    /// Every moved voxel back toward its direction at `start`, all the way or by
    /// halves down to 1/32, wherever no Jacobian it enters gets more negative ones.
    fn go_back(&mut self, start: &[Option<(f64, DVec3)>]) {
        let moved: Vec<usize> = (0..self.point.len())
            .filter(|&i| match (start[i], self.point[i]) {
                (Some(a), Some(b)) => a.1 != b.1,
                _ => false,
            })
            .collect();
        for _ in 0..BACK_SWEEPS {
            let mut any = false;
            for &i in &moved {
                let (ui, d) = self.point[i].expect("moved voxels have a direction");
                let home = start[i].expect("moved voxels had a direction").1;
                if d == home {
                    continue;
                }
                let before = self.score(i).0;
                for k in 0..6 {
                    let c = if k == 0 {
                        home
                    } else {
                        stored(d + (home - d) * 0.5f64.powi(k))
                    };
                    self.point[i] = Some((ui, c));
                    if self.score(i).0 <= before {
                        any = true;
                        break;
                    }
                    self.point[i] = Some((ui, d));
                }
            }
            if !any {
                break;
            }
        }
    }

    /// The grid's linear index of box voxel `i`.
    fn linear(&self, i: usize) -> u64 {
        let c = self.coords(i);
        let g = [0, 1, 2].map(|a| (self.origin[a] + c[a] as i64) as u64);
        (g[0] * self.grid[1] + g[1]) * self.grid[2] + g[2]
    }

    /// A compass search for voxel `i`'s direction, within [`TRUST`] times the largest
    /// distance to its neighbours' directions at `start` from its own there; whether
    /// it moved.
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn improve(&mut self, i: usize, start: &[Option<(f64, DVec3)>]) -> bool {
        let Some((ui, _)) = self.point[i] else {
            return false;
        };
        let home = start[i].expect("a movable voxel has a direction").1;
        let trust = TRUST
            * self.stencil(i)[1..]
                .iter()
                .filter_map(|&j| start[j].map(|p| (p.1 - home).length()))
                .fold(0.0f64, f64::max);
        let mut any = false;
        for _ in 0..MOVES_PER_VISIT {
            let current = self.score(i);
            if current.0 == 0 && current.1 > 0.0 && !any {
                // Nothing it enters folds: leave it.
                return false;
            }
            let d = self.point[i].expect("set").1;
            let neighbours: Vec<DVec3> = self.stencil(i)[1..]
                .iter()
                .filter_map(|&j| self.point[j].map(|p| p.1))
                .collect();
            let scale = neighbours
                .iter()
                .map(|n| (*n - d).length())
                .fold(0.0f64, f64::max);
            if scale == 0.0 || !scale.is_finite() {
                return any;
            }
            let mean = neighbours.iter().fold(DVec3::ZERO, |a, n| a + *n);
            let (t1, t2) = d.any_orthonormal_pair();
            let mut candidates: Vec<DVec3> = Vec::with_capacity(48);
            if mean.length() > 0.0 {
                let m = mean.normalize();
                for k in 0..4 {
                    candidates.push(d + (m - d) * 0.5f64.powi(k));
                }
            }
            for k in 0..STEPS {
                let step = scale * 0.25f64.powi(k);
                for j in 0..8 {
                    let (s, c) = (f64::from(j) * std::f64::consts::FRAC_PI_4).sin_cos();
                    candidates.push(d + (t1 * c + t2 * s) * step);
                }
            }
            let mut best = current;
            let mut best_d = None;
            for c in candidates {
                let c = stored(c);
                if c == d || (c - home).length() > trust {
                    continue;
                }
                self.point[i] = Some((ui, c));
                let s = self.score(i);
                if s.0 < best.0 || (s.0 == best.0 && s.1 > best.1) {
                    best = s;
                    best_d = Some(c);
                }
            }
            let Some(c) = best_d else {
                self.point[i] = Some((ui, d));
                return any;
            };
            self.point[i] = Some((ui, c));
            any = true;
        }
        any
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 12^3 box of the radial map around (0, 0, 0) at (x, y, z) = (20, 0, 0) + ...,
    /// u = 1 - r / 40, with `flip` applied to the voxel at the middle.
    fn radial(flip: impl Fn(DVec3) -> DVec3) -> Region {
        let shape = [12usize; 3];
        let n = 12 * 12 * 12;
        let mut point = vec![None; n];
        for z in 0..12 {
            for y in 0..12 {
                for x in 0..12 {
                    let p = DVec3::new(x as f64 + 20.0, y as f64 - 6.0, z as f64 - 6.0);
                    let mut d = p.normalize();
                    if (x, y, z) == (6, 6, 6) {
                        d = flip(d);
                    }
                    let (t, ps) = angles(d);
                    point[(z * 12 + y) * 12 + x] = Some((1.0 - p.length() / 40.0, unit(t, ps)));
                }
            }
        }
        let mut r = Region {
            origin: [0; 3],
            shape,
            point,
            measured: vec![false; n],
            movable: vec![false; n],
            grid: [12; 3],
        };
        for i in 0..n {
            r.measured[i] = r.depth_at_least(i, 1);
            r.movable[i] = r.depth_at_least(i, 2);
        }
        r
    }

    fn folds(r: &Region) -> usize {
        (0..r.point.len()).filter(|&j| r.folds_at(j)).count()
    }

    #[test]
    fn the_radial_map_does_not_fold_and_is_left_alone() {
        let r = radial(|d| d);
        assert_eq!(folds(&r), 0);
        assert!(r.untangle().is_empty());
    }

    #[test]
    fn a_voxel_thrown_across_its_neighbours_is_put_back() {
        // The middle voxel's direction moved past its neighbours' (by about three
        // voxels' worth of angle): its neighbours' Jacobians fold.
        let flip = |d: DVec3| (d + DVec3::Y * 0.15).normalize();
        let r = radial(flip);
        assert!(folds(&r) > 0, "the test's fold");
        let mut after = radial(flip);
        let moved = r.untangle();
        assert!(!moved.is_empty());
        for &(k, from, to) in &moved {
            // Box and grid are one: the linear index is the box's.
            let i = k as usize;
            assert_eq!(after.point[i].expect("set").1, from);
            // Within the trust region: the neighbours are at most 0.2 away.
            assert!((to - from).length() <= 0.2, "{}", (to - from).length());
            after.point[i] = Some((after.point[i].expect("set").0, to));
        }
        assert_eq!(folds(&after), 0, "moved {}", moved.len());
    }

    #[test]
    fn boxes_group_near_folds_and_cut_large_groups() {
        let spec = GridSpec {
            shape: [200, 200, 200],
            origin: [0.0; 3],
            spacing: 1.0,
            chunk: [32, 32, 32],
            unit: None,
        };
        // Two voxels 5 apart: one box; one far away: another.
        let b = boxes(&[[10, 10, 10], [10, 10, 15], [100, 100, 100]], &spec);
        assert_eq!(b.len(), 2);
        assert_eq!(b[0], ([6, 6, 6], [15, 15, 20]));
        // A line of 150 voxels along x, each 1 apart: cut into tiles of CORE.
        let line: Vec<[u32; 3]> = (20..170).map(|x| [50, 50, x]).collect();
        let b = boxes(&line, &spec);
        assert_eq!(b.len(), 3);
        assert!(b.iter().all(|(lo, hi)| hi[2] - lo[2] <= CORE + 2 * MARGIN));
    }
}
