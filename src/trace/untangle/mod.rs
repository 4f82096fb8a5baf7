//! Untangling the sphere map of a surface: the streamlines' arrival points, with every
//! flipped or degenerate triangle made positive by moving as few vertices as it takes,
//! as little as it takes.
//!
//! Where a shape squeezes (arms, ears, fins) the streamline map takes a surface triangle
//! to a sliver whose edges are 1e-6 radians long and whose singular values differ by up
//! to 10^4. The continuous map keeps its orientation there, but the flat triangle of
//! three arrival points can turn over: no rounding, step control or node precision
//! moves these flips (docs/trace.md, Limits). What makes the discrete map one-to-one is
//! the standard remedy of mesh untangling, applied on the sphere.
//!
//! Behavior:
//! - A triangle is bad when its three vertices reached the center and its flat sphere
//!   triangle is not positive ([`orientation`]).
//! - Local optimization (Freitag and Plassmann, 2000): a vertex of a bad triangle moves,
//!   on the plane touching the sphere at it (a gnomonic projection: great circles become
//!   lines, and a flat sphere triangle is positive exactly where its projection is
//!   counter-clockwise), toward the point that maximizes the smallest signed area of
//!   its triangles. Those areas are linear in the vertex's position, so that point is
//!   the solution of a linear program in two unknowns, and it does not depend on how
//!   the map squeezes (an affine change of the plane scales every area alike). The
//!   vertex goes only part of the way: to the nearest point of the segment where the
//!   smallest area is half the best one.
//! - A move is kept only when, as stored (the points rebuilt from their f64 theta and
//!   psi), fewer of the vertex's triangles are bad, or as many and the smallest of them
//!   grew. Only the vertex's own triangles change, so the number of bad triangles never
//!   rises.
//! - When a sweep leaves as many bad triangles as before, the neighbours within one
//!   more ring move too, to make room (toward their own best point, where that raises
//!   their smallest area), up to [`MAX_RINGS`] rings.
//! - Where local moves stall (a region the streamlines laid down twice, as the two
//!   sides of a thin sheet; a fan of slivers around a pole), the bad triangles are
//!   grouped into tangles, and each tangle's region (the stars of the vertices within
//!   a few rings of it, from 0 up to [`MAX_REGION_RINGS`], smallest first) is
//!   re-embedded inside its fixed boundary: each inner vertex at a weighted mean of its
//!   neighbours on the gnomonic projection (Tutte 1963; Floater's mean value weights
//!   from the map as it is first, so that vertices whose rings are laid down well stay
//!   put, then inverse edge lengths, then uniform). The first region whose embedding
//!   leaves fewer bad triangles than it holds is kept, and local moves run again, for
//!   up to [`MAX_REGION_ROUNDS`] rounds ([`Reembedder`]).
//! - Last, when regions were re-embedded, every moved vertex goes back toward its
//!   arrival point, all the way or by halves of the way down to a 32nd, wherever none of its positive triangles turns
//!   bad: the untangled map keeps the streamlines' map wherever it need not leave it.
//! - Vertices that did not reach the center are never given a point, and a vertex with
//!   one among its neighbours is held in the local moves (its ring is open), as is a
//!   vertex of more than [`MAX_VALENCE`] triangles.
//! - Not every tangle clears: a surface that is not one sphere (two_spheres' two
//!   overlapping components, which no one-to-one map of one sphere can take) keeps
//!   its bad triangles, counted.
//!
//! - The work is bounded: vertex moves tried, triangles of the regions tried and their
//!   solvers' iterations times unknowns, at most [`WORK_PER_TRIANGLE`] per triangle of
//!   the surface. A surface whose tangles
//!   keep most of their bad triangles through every round (a molecule with handles
//!   under `--allow-genus`, whose map no untangling makes one-to-one) would otherwise
//!   try rounds of sweeps over thousands of tangles; when the bound is reached the
//!   untangling stops where it is, and the report says so (`out_of_work`).
//!
//! Deterministic: vertices in index order, sequential sweeps, no parallel sums; the
//! work bound counts moves, not time.
//!
//! Performance: one pass over the triangles when nothing is flipped. Otherwise a
//! vertex-to-triangle index ([`UNTANGLE_TRIANGLE_BYTES`] a triangle and
//! [`UNTANGLE_VERTEX_BYTES`] a vertex), and work in proportion to the tangles, at most
//! [`WORK_PER_TRIANGLE`] per triangle.

use glam::{DVec2, DVec3};
use serde::Serialize;

use super::metrics::orientation;

mod regions;
mod solvers;

use regions::Reembedder;
pub use regions::MAX_REGION_RINGS;

/// Bytes [`untangle`] holds a triangle at most: its three entries of the vertex-to-
/// triangle index (12), its stamps (8), and in a re-embedded region (a quarter of the
/// surface at most) its entry (4) and three half-edges in a hash map (about 32 each).
pub const UNTANGLE_TRIANGLE_BYTES: u64 = 48;

/// Bytes [`untangle`] holds a vertex at most: its offset in the index (4), its stamps,
/// ring and unknown (16), its first point when it moves (32), and in a re-embedded
/// region (a quarter of the surface at most) its unknown's vectors, neighbours and
/// boundary entry (about 160).
pub const UNTANGLE_VERTEX_BYTES: u64 = 96;

/// Rings of neighbours around the bad triangles that may move to make room, at most.
pub const MAX_RINGS: u32 = 8;

/// Triangles around a vertex that may move, at most. The linear program is solved by
/// enumerating its vertices (in the fourth power of this); and a vertex of a fan of
/// slivers (the poles of a latitude-longitude mesh: the built-in starfish has two of
/// 240 triangles) has a ring that spans tens of degrees, across which no move is small.
pub const MAX_VALENCE: usize = 16;

/// Sweeps over the movable vertices in a round of local moves, at most.
const MAX_SWEEPS: u32 = 200;

/// Rounds of re-embedding (each followed by local moves), at most.
const MAX_REGION_ROUNDS: u32 = 32;

/// Vertex moves tried, region triangles visited and the regions' solver iterations
/// times their unknowns, that the untangling may spend, per triangle of the surface.
pub const WORK_PER_TRIANGLE: u64 = 2000;

/// Sweeps that move a re-embedded region's vertices back toward their points before
/// it, at most.
const RETURN_SWEEPS: u32 = 200;

/// What [`untangle`] changed.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct UntangleReport {
    /// Triangles of the arrival points that were flipped (orientation negative).
    pub flipped_arrivals: u64,
    /// Triangles of the arrival points with no area (orientation zero).
    pub degenerate_arrivals: u64,
    /// Sweeps over the bad triangles' vertices.
    pub sweeps: u64,
    /// Seeds whose sphere point moved.
    pub seeds_moved: u64,
    /// The largest move on the sphere (degrees).
    pub max_move_deg: f64,
    /// The median move of the seeds that moved (degrees).
    pub median_move_deg: f64,
    /// Rings around the bad triangles from which a vertex moved, at the most.
    pub max_rings: u64,
    /// The largest move as a share of the mover's ring (the largest distance from its
    /// new point to a neighbour's): near 1 or below, the seeds moved within their own
    /// neighbourhood on the sphere.
    pub max_move_of_ring: f64,
    /// Regions of the surface re-embedded whole (a Tutte embedding on the sphere inside
    /// their fixed boundary) where the local moves left bad triangles.
    pub regions: u64,
    /// Rings around its tangle the largest re-embedded region took.
    pub region_rings: u64,
    /// Seeds inside re-embedded regions.
    pub region_seeds: u64,
    /// Bad triangles left.
    pub unresolved: u64,
    /// The untangling stopped at its work bound ([`WORK_PER_TRIANGLE`]) with bad
    /// triangles left that more work might have cleared.
    pub out_of_work: bool,
    /// The work spent (vertex moves tried, region triangles visited, solver iterations
    /// times unknowns), per triangle of the surface.
    pub work_per_triangle: f64,
    /// The seeds whose sphere point moved, in index order (not recorded).
    #[serde(skip)]
    pub moved: Vec<u32>,
}

/// Untangle the sphere map `sphere[v]` (unit vectors; `None` where the seed did not
/// reach the center) of the surface `triangles` (facing outward).
///
/// # Behavior
/// See the module docs. Moved points are stored back as the unit vector of their f64
/// angles ([`super::angles`], [`super::unit`]), so the stored theta and psi give exactly
/// the orientations checked here.
///
/// # Returns
/// What changed; the counts of the arrival points before it.
#[must_use]
pub fn untangle(triangles: &[[u32; 3]], sphere: &mut [Option<DVec3>]) -> UntangleReport {
    untangle_within(triangles, sphere, WORK_PER_TRIANGLE as f64)
}

/// [`untangle`] with a work bound of `per_triangle` a triangle.
fn untangle_within(
    triangles: &[[u32; 3]],
    sphere: &mut [Option<DVec3>],
    per_triangle: f64,
) -> UntangleReport {
    let mut report = UntangleReport::default();
    let mut bad: Vec<u32> = Vec::new();
    for (t, tri) in triangles.iter().enumerate() {
        if let Some(o) = orient(sphere, *tri) {
            if o < 0.0 {
                report.flipped_arrivals += 1;
            } else if o == 0.0 {
                report.degenerate_arrivals += 1;
            }
            if o <= 0.0 {
                bad.push(t as u32);
            }
        }
    }
    if bad.is_empty() {
        return report;
    }
    let mut u = Untangler::new(triangles, sphere.len());
    u.limit = (per_triangle * triangles.len() as f64) as u64;
    let mut moved: Vec<(u32, DVec3)> = Vec::new();
    let mut ring_of = vec![0u32; sphere.len()];
    for round in 0..=MAX_REGION_ROUNDS {
        if u.exhausted() {
            break;
        }
        local(
            &mut u,
            sphere,
            &mut bad,
            &mut moved,
            &mut ring_of,
            &mut report,
        );
        if bad.is_empty() || round == MAX_REGION_ROUNDS {
            break;
        }
        let before = bad.len();
        bad = Reembedder::new(&u).run(sphere, bad, &mut moved, &mut report);
        if bad.len() >= before {
            break;
        }
    }
    // The first point recorded for a vertex is its arrival point.
    moved.sort_by_key(|&(v, _)| v);
    moved.dedup_by_key(|&mut (v, _)| v);
    if report.regions > 0 {
        Reembedder::new(&u).go_back(sphere, &moved);
        bad.retain(|&t| orient(sphere, triangles[t as usize]).is_some_and(|o| o <= 0.0));
    }
    report.unresolved = bad.len() as u64;
    report.out_of_work = u.exhausted() && !bad.is_empty();
    report.work_per_triangle = u.work.get() as f64 / triangles.len() as f64;
    let mut moves: Vec<f64> = Vec::with_capacity(moved.len());
    for &(v, a) in &moved {
        let p = sphere[v as usize].expect("moved points are reached");
        if p == a {
            continue;
        }
        report.moved.push(v);
        moves.push(a.dot(p).clamp(-1.0, 1.0).acos().to_degrees());
        let ring = u
            .around(v)
            .iter()
            .flat_map(|&t| triangles[t as usize])
            .filter_map(|w| sphere[w as usize])
            .map(|q| q.distance(p))
            .fold(0.0, f64::max);
        if ring > 0.0 {
            report.max_move_of_ring = report.max_move_of_ring.max(p.distance(a) / ring);
        }
    }
    moves.sort_by(f64::total_cmp);
    report.seeds_moved = moves.len() as u64;
    report.max_move_deg = moves.last().copied().unwrap_or(0.0);
    report.median_move_deg = moves.get(moves.len() / 2).copied().unwrap_or(0.0);
    report
}

/// The local moves (see the module docs) of the vertices of the `bad` triangles
/// (sorted) and, when a sweep stalls, of their neighbours within one more ring, up to
/// [`MAX_RINGS`]; `bad` is left holding the bad triangles that are left, sorted.
fn local(
    u: &mut Untangler<'_>,
    sphere: &mut [Option<DVec3>],
    bad: &mut Vec<u32>,
    moved: &mut Vec<(u32, DVec3)>,
    ring_of: &mut [u32],
    report: &mut UntangleReport,
) {
    let mut rings = 0u32;
    let mut sweeps = 0u32;
    while !bad.is_empty() && sweeps < MAX_SWEEPS {
        sweeps += 1;
        report.sweeps += 1;
        let before = bad.len();
        let mut touched: Vec<u32> = Vec::new();
        let near = u.near(bad, rings, ring_of);
        if !u.spend(near.len() as u64) {
            break;
        }
        for v in near {
            let ring = ring_of[v as usize];
            if let Some(p) = u.improve(sphere, v, ring > 0) {
                moved.push((v, sphere[v as usize].expect("reached")));
                sphere[v as usize] = Some(p);
                touched.extend_from_slice(u.around(v));
                report.max_rings = report.max_rings.max(u64::from(ring));
            }
        }
        // Only the moved vertices' triangles can have changed.
        bad.extend(touched);
        bad.sort_unstable();
        bad.dedup();
        bad.retain(|&t| orient(sphere, u.triangles[t as usize]).is_some_and(|o| o <= 0.0));
        if bad.len() >= before {
            if rings == MAX_RINGS {
                break;
            }
            rings += 1;
        }
    }
}

/// The orientation of triangle `t`'s sphere points, if all three reached.
fn orient(sphere: &[Option<DVec3>], t: [u32; 3]) -> Option<f64> {
    let [a, b, c] = t.map(|i| sphere[i as usize]);
    Some(orientation(a?, b?, c?))
}

/// The point stored for direction `p`: the unit vector of its f64 angles.
fn stored(p: DVec3) -> DVec3 {
    let (theta, psi) = super::angles(p);
    super::unit(theta, psi)
}

/// The vertex-to-triangle index and a stamp a vertex, to collect vertices once.
struct Untangler<'a> {
    triangles: &'a [[u32; 3]],
    /// Triangles of vertex `v`: `entries[offsets[v]..offsets[v + 1]]`.
    offsets: Vec<u32>,
    entries: Vec<u32>,
    /// A vertex's stamp: equal to `stamp` when it is in the current set.
    stamp_of: Vec<u32>,
    stamp: u32,
    /// Work spent, and the bound ([`WORK_PER_TRIANGLE`] a triangle).
    work: std::cell::Cell<u64>,
    limit: u64,
}

impl<'a> Untangler<'a> {
    fn new(triangles: &'a [[u32; 3]], vertices: usize) -> Self {
        let mut offsets = vec![0u32; vertices + 1];
        for t in triangles {
            for &v in t {
                offsets[v as usize + 1] += 1;
            }
        }
        for v in 0..vertices {
            offsets[v + 1] += offsets[v];
        }
        let mut fill = offsets.clone();
        let mut entries = vec![0u32; triangles.len() * 3];
        for (i, t) in triangles.iter().enumerate() {
            for &v in t {
                entries[fill[v as usize] as usize] = i as u32;
                fill[v as usize] += 1;
            }
        }
        Self {
            triangles,
            offsets,
            entries,
            stamp_of: vec![0; vertices],
            stamp: 0,
            work: std::cell::Cell::new(0),
            limit: WORK_PER_TRIANGLE * triangles.len() as u64,
        }
    }

    /// Spend `n` units of work; false (and nothing spent) when that would pass the
    /// bound.
    fn spend(&self, n: u64) -> bool {
        let w = self.work.get() + n;
        if w > self.limit {
            self.work.set(self.limit);
            return false;
        }
        self.work.set(w);
        true
    }

    /// Whether the work bound is reached.
    fn exhausted(&self) -> bool {
        self.work.get() >= self.limit
    }

    fn around(&self, v: u32) -> &[u32] {
        &self.entries[self.offsets[v as usize] as usize..self.offsets[v as usize + 1] as usize]
    }

    /// The vertices of the triangles `bad` and their neighbours within `rings` rings, in
    /// index order; `ring_of[v]` is set to the ring of each (0: of a bad triangle).
    fn near(&mut self, bad: &[u32], rings: u32, ring_of: &mut [u32]) -> Vec<u32> {
        self.stamp += 1;
        let stamp = self.stamp;
        let mut out: Vec<u32> = Vec::new();
        for &t in bad {
            for v in self.triangles[t as usize] {
                if self.stamp_of[v as usize] != stamp {
                    self.stamp_of[v as usize] = stamp;
                    ring_of[v as usize] = 0;
                    out.push(v);
                }
            }
        }
        let mut start = 0;
        for ring in 1..=rings {
            let end = out.len();
            for i in start..end {
                let v = out[i];
                for k in self.offsets[v as usize]..self.offsets[v as usize + 1] {
                    for w in self.triangles[self.entries[k as usize] as usize] {
                        if self.stamp_of[w as usize] != stamp {
                            self.stamp_of[w as usize] = stamp;
                            ring_of[w as usize] = ring;
                            out.push(w);
                        }
                    }
                }
            }
            start = end;
        }
        out.sort_unstable();
        out
    }

    /// The better point for vertex `v`, if there is one (see the module docs).
    #[allow(clippy::many_single_char_names)] // the names of the formulas (c the vertex's point, v its index, s the step, q its offset on the plane)
    fn improve(&self, sphere: &[Option<DVec3>], v: u32, make_room: bool) -> Option<DVec3> {
        let c = sphere[v as usize]?;
        let ring = self.around(v);
        if ring.len() > MAX_VALENCE {
            return None;
        }
        // A triangle with v twice has no area wherever v goes.
        if ring.iter().any(|&t| {
            let tri = self.triangles[t as usize];
            tri.iter().filter(|&&x| x == v).count() > 1
        }) {
            return None;
        }

        // The other two corners of each triangle, in its order after v.
        let mut corners: Vec<[DVec3; 2]> = Vec::with_capacity(ring.len());
        for &t in ring {
            let tri = self.triangles[t as usize];
            let k = tri.iter().position(|&x| x == v)?;
            corners.push([
                sphere[tri[(k + 1) % 3] as usize]?,
                sphere[tri[(k + 2) % 3] as usize]?,
            ]);
        }
        let e1 = c.any_orthonormal_vector();
        let e2 = c.cross(e1);
        let mut plane: Vec<[DVec2; 2]> = Vec::with_capacity(ring.len());
        for pair in &corners {
            let mut q = [DVec2::ZERO; 2];
            for (i, p) in pair.iter().enumerate() {
                let h = p.dot(c);
                if h <= 0.2 {
                    return None;
                }
                q[i] = DVec2::new(p.dot(e1), p.dot(e2)) / h;
            }
            plane.push(q);
        }
        // At the scale of the ring, so that the program works on O(1) values.
        let scale = plane
            .iter()
            .flatten()
            .map(|q| q.abs().max_element())
            .fold(0.0, f64::max);
        if scale.is_nan() || scale <= 0.0 || !scale.is_finite() {
            return None;
        }
        // The doubled signed area of (x, b, c) is cross(b, c) + cross(x, b - c): a.x + k.
        let lines: Vec<(DVec2, f64)> = plane
            .iter()
            .map(|[b, cc]| {
                let (b, cc) = (*b / scale, *cc / scale);
                let d = b - cc;
                (DVec2::new(d.y, -d.x), b.perp_dot(cc))
            })
            .collect();
        let now = smallest(&lines, DVec2::ZERO);
        let (best, top) = max_min(&lines)?;
        if top.is_nan() || top <= now || top <= 0.0 {
            return None;
        }
        // The nearest point toward it where the smallest area is half the best one.
        let goal = 0.5 * top;
        let mut s = 0.0f64;
        for (a, k) in &lines {
            if *k < goal {
                let gain = a.dot(best);
                if gain > 0.0 {
                    s = s.max((goal - k) / gain);
                }
            }
        }
        let q = best * s.min(1.0) * scale;
        let p = stored((c + q.x * e1 + q.y * e2).normalize());
        if !p.is_finite() || p == c {
            return None;
        }
        // Kept only when it helps as stored.
        let score = |x: DVec3| {
            let mut bad = 0u32;
            let mut least = f64::INFINITY;
            for [b, cc] in &corners {
                let o = orientation(x, *b, *cc);
                if o <= 0.0 {
                    bad += 1;
                }
                least = least.min(o);
            }
            (bad, least)
        };
        let (bad_now, least_now) = score(c);
        let (bad_new, least_new) = score(p);
        (bad_new < bad_now
            || (bad_new == bad_now && (bad_now > 0 || make_room) && least_new > least_now))
            .then_some(p)
    }
}

/// The smallest of the affine functions `a . x + k` at `x`.
fn smallest(lines: &[(DVec2, f64)], x: DVec2) -> f64 {
    lines
        .iter()
        .map(|(a, k)| a.dot(x) + k)
        .fold(f64::INFINITY, f64::min)
}

/// The point that maximizes the smallest of the affine functions `a . x + k` (whose
/// directions `a` span the plane positively, as the edges of a closed ring do, so that
/// the maximum exists), and that smallest value: the best of the points where three of
/// them are equal (a linear program in two unknowns, solved by its vertices).
fn max_min(lines: &[(DVec2, f64)]) -> Option<(DVec2, f64)> {
    let n = lines.len();
    let mut best: Option<(DVec2, f64)> = None;
    for i in 0..n {
        for j in (i + 1)..n {
            for l in (j + 1)..n {
                let (ai, ki) = lines[i];
                let (aj, kj) = lines[j];
                let (al, kl) = lines[l];
                // (ai - aj) . x = kj - ki, (ai - al) . x = kl - ki.
                let (r1, r2) = (ai - aj, ai - al);
                let det = r1.perp_dot(r2);
                if det.abs() < 1e-300 {
                    continue;
                }
                let (b1, b2) = (kj - ki, kl - ki);
                let x = DVec2::new(b1 * r2.y - b2 * r1.y, r1.x * b2 - r2.x * b1) / det;
                if !x.is_finite() {
                    continue;
                }
                let v = smallest(lines, x);
                if best.is_none_or(|(_, b)| v > b) {
                    best = Some((x, v));
                }
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A grid of `k x k` quads (two triangles each, counter-clockwise seen from +z) on
    /// the plane z = 0, and its sphere map: a small cap around +z, squeezed `squeeze`
    /// times along y.
    fn cap(k: usize, squeeze: f64) -> (Vec<DVec3>, Vec<[u32; 3]>, Vec<Option<DVec3>>) {
        let mut pos = Vec::new();
        let mut sphere = Vec::new();
        for j in 0..=k {
            for i in 0..=k {
                let (x, y) = (i as f64 / k as f64 - 0.5, j as f64 / k as f64 - 0.5);
                pos.push(DVec3::new(x, y, 0.0));
                sphere.push(Some(stored(
                    DVec3::new(0.01 * x, 0.01 * y / squeeze, 1.0).normalize(),
                )));
            }
        }
        let id = |i: usize, j: usize| (j * (k + 1) + i) as u32;
        let mut tris = Vec::new();
        for j in 0..k {
            for i in 0..k {
                tris.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                tris.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        (pos, tris, sphere)
    }

    fn bad_count(tris: &[[u32; 3]], sphere: &[Option<DVec3>]) -> usize {
        tris.iter()
            .filter(|&&t| orient(sphere, t).is_some_and(|o| o <= 0.0))
            .count()
    }

    /// On `cap(16, _)`: vertices in columns 6..=9 of rows 5..=10 mirrored across column
    /// 7.5, so that the patch is laid down reversed, as the two sides of a thin sheet are.
    fn laid_down_twice(sphere: &mut [Option<DVec3>]) {
        let at = |i: usize, j: usize| j * 17 + i;
        let original = sphere.to_vec();
        for j in 5..=10 {
            for i in 6..=9 {
                sphere[at(i, j)] = original[at(15 - i, j)];
            }
        }
    }

    #[test]
    fn a_region_laid_down_twice_is_reembedded_inside_its_boundary() {
        for squeeze in [1.0, 1e4] {
            let (_pos, tris, mut sphere) = cap(16, squeeze);
            laid_down_twice(&mut sphere);
            let tangled = sphere.clone();
            let bad: Vec<u32> = (0..tris.len() as u32)
                .filter(|&t| orient(&sphere, tris[t as usize]).is_some_and(|o| o <= 0.0))
                .collect();
            assert!(bad.len() > 10, "the test needs a fold");
            let u = Untangler::new(&tris, sphere.len());
            let mut r = Reembedder::new(&u);
            let mut moved = Vec::new();
            let mut report = UntangleReport::default();
            let left = r.run(&mut sphere, bad, &mut moved, &mut report);
            assert_eq!(left, Vec::<u32>::new(), "squeeze {squeeze}");
            assert_eq!(bad_count(&tris, &sphere), 0);
            assert_eq!(report.regions, 1);
            assert!(report.region_seeds > 0);
            // Only the region's inner vertices moved.
            for (v, (a, b)) in sphere.iter().zip(&tangled).enumerate() {
                let (i, j) = ((v % 17) as i64, (v / 17) as i64);
                if !(3..=12).contains(&i) || !(2..=13).contains(&j) {
                    assert_eq!(a, b, "vertex {v} moved");
                }
            }
        }
    }

    #[test]
    fn untangling_stops_at_its_work_bound() {
        let (_pos, tris, mut sphere) = cap(16, 1.0);
        laid_down_twice(&mut sphere);
        let tangled = sphere.clone();
        let whole = untangle(&tris, &mut sphere);
        assert_eq!((whole.unresolved, whole.out_of_work), (0, false));
        assert!(
            whole.work_per_triangle > 0.0 && whole.work_per_triangle <= WORK_PER_TRIANGLE as f64
        );
        // With a bound below what it took, it stops with flips left, and says so.
        let mut sphere = tangled;
        let cut = untangle_within(&tris, &mut sphere, 0.5 * whole.work_per_triangle);
        assert!(cut.out_of_work && cut.unresolved > 0, "{cut:?}");
        assert!(cut.work_per_triangle <= 0.5 * whole.work_per_triangle + 1e-9);
        assert_eq!(bad_count(&tris, &sphere) as u64, cut.unresolved);
    }

    #[test]
    fn a_map_without_flips_is_left_alone() {
        let (_pos, tris, mut sphere) = cap(12, 1e4);
        let before = sphere.clone();
        let r = untangle(&tris, &mut sphere);
        assert_eq!(r, UntangleReport::default());
        assert_eq!(sphere, before);
    }

    #[test]
    fn a_fold_in_a_squeezed_map_is_untangled_by_moving_only_its_patch() {
        // Squeezed 1e4 times: edges of 1e-6 across. Three inner vertices pushed across
        // their neighbours fold the triangles around them.
        let (_pos, tris, mut sphere) = cap(16, 1e4);
        let original = sphere.clone();
        for (i, j, di, dj) in [(5, 5, 1.6, 0.4), (6, 5, -0.3, 1.4), (11, 9, 0.2, -1.7)] {
            let v = j * 17 + i;
            let p = sphere[v].unwrap();
            let q = DVec3::new(p.x + di * 0.01 / 16.0, p.y + dj * 0.01 / 16.0 / 1e4, p.z);
            sphere[v] = Some(stored(q.normalize()));
        }
        let tangled = sphere.clone();
        assert!(bad_count(&tris, &sphere) > 0, "the test needs a fold");
        let r = untangle(&tris, &mut sphere);
        assert_eq!(bad_count(&tris, &sphere), 0);
        assert_eq!(r.unresolved, 0);
        assert!(r.flipped_arrivals + r.degenerate_arrivals > 0);
        assert!(r.sweeps >= 1 && r.seeds_moved >= 1);
        // Vertices far from the folds keep their points bit for bit.
        let moved = (0..sphere.len())
            .filter(|&v| sphere[v] != tangled[v])
            .count() as u64;
        assert_eq!(moved, r.seeds_moved);
        for (v, (a, b)) in sphere.iter().zip(&tangled).enumerate() {
            let (i, j) = ((v % 17) as i64, (v / 17) as i64);
            let near = [(5, 5), (6, 5), (11, 9)]
                .iter()
                .any(|&(ci, cj)| (i - ci).abs() <= 8 && (j - cj).abs() <= 8);
            if !near {
                assert_eq!(a, b, "vertex {v} moved");
            }
        }
        // The relaxed points lie close to the unfolded map (the patch reproduces its
        // affine squeeze): within a few of the squeezed edges (1e-6 rad) of it.
        for v in 0..sphere.len() {
            let d = sphere[v].unwrap().angle_between(original[v].unwrap());
            assert!(d < 2e-3, "vertex {v} is {d} rad from the unfolded map");
        }
    }

    #[test]
    fn a_fold_next_to_an_unreached_vertex_is_untangled_around_it() {
        let (_pos, tris, mut sphere) = cap(8, 1.0);
        // Vertex (4, 4) crosses its neighbour (5, 4); (4, 5) did not reach.
        let p = sphere[4 * 9 + 5].unwrap();
        sphere[4 * 9 + 4] = Some(stored((p + DVec3::new(0.0006, 0.0, 0.0)).normalize()));
        sphere[5 * 9 + 4] = None;
        assert!(bad_count(&tris, &sphere) > 0);
        let before = sphere.clone();
        let r = untangle(&tris, &mut sphere);
        assert_eq!(bad_count(&tris, &sphere), 0);
        assert_eq!(r.unresolved, 0);
        // The unreached vertex gets no point.
        assert_eq!(sphere[5 * 9 + 4], None);
        assert_eq!(
            (0..sphere.len())
                .filter(|&v| sphere[v] != before[v])
                .count() as u64,
            r.seeds_moved
        );
        assert!(r.seeds_moved > 0);
    }
}
