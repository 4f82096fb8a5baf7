//! The nearest point of a triangle surface, within a few voxels.
//!
//! When the run's input is a triangle mesh, the sub-voxel values of the boundary nodes
//! ([`super::surface`]) take their depth and normal from the mesh itself instead of
//! from the smoothed voxel solid. [`SurfaceIndex`] answers "the nearest point of the
//! surface within [`RADIUS`] voxels" for a node, with a bounding volume hierarchy over
//! the triangles: boxes farther than the best distance found so far are not opened.
//!
//! Answers are exact (closest point on each triangle, Ericson's "Real-Time Collision
//! Detection", 5.1.5) and deterministic: the tree is built in a fixed way from the mesh,
//! and of equally near triangles a query answers with the one first in the tree's
//! order, whichever boxes its hint (the triangle of a neighbouring query) spares it
//! from opening.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

use crate::math::Vec3;

/// How far (voxels) a query looks for the surface.
pub const RADIUS: f64 = 2.0;
/// Triangles per leaf of the tree, at most.
const LEAF: usize = 4;

/// A node of the tree: its box, and either two children (the left one is the next
/// node, the right one `first`) or a run of `count` triangles from `first`.
#[derive(Clone, Copy)]
struct Node {
    lo: Vec3,
    hi: Vec3,
    /// Leaf: its first triangle. Inner: its right child.
    first: u32,
    /// Triangles of a leaf; 0 for an inner node.
    count: u32,
}

/// A triangle surface in voxel coordinates (x, y, z), in a tree for nearest-point
/// queries.
pub struct SurfaceIndex {
    /// The triangles' corners, in tree order.
    tris: Vec<[Vec3; 3]>,
    nodes: Vec<Node>,
    /// Answers for grid nodes ([`SurfaceIndex::nearest_node`]), in shards by node.
    /// (Grid nodes are within 2^20 of the origin on every axis, so keys do not collide.)
    /// The map builds a block's tiles once per visit, several times over; the trace's
    /// tiles share their halos.
    cache: Vec<Mutex<HashMap<u64, Answer, NodeHash>>>,
    /// Bytes the cache may hold; once full, it answers from what it holds and
    /// computes the rest.
    cache_cap: u64,
    cached: AtomicU64,
}

/// The hash of a node's key: one folded multiply (the keys are packed coordinates, not
/// chosen by an adversary; SipHash took a fifth of the map's time).
#[derive(Clone, Copy, Default)]
struct NodeHash;

impl std::hash::BuildHasher for NodeHash {
    type Hasher = NodeHasher;
    fn build_hasher(&self) -> NodeHasher {
        NodeHasher(0)
    }
}

/// [`NodeHash`]'s hasher.
struct NodeHasher(u64);

impl std::hash::Hasher for NodeHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(u64::from(b));
        }
    }
    fn write_u64(&mut self, k: u64) {
        let m = u128::from(self.0 ^ k) * 0x9E37_79B9_7F4A_7C15;
        self.0 = (m as u64) ^ ((m >> 64) as u64);
    }
}

/// An answer: the nearest point within [`RADIUS`] and its triangle.
type Answer = Option<(Nearest, u32)>;
/// Shards of the cache.
const SHARDS: usize = 64;
/// Bytes a cached answer takes: key and value (56 bytes) and the hash table's slack
/// (a control byte a slot, and up to half the slots empty after it doubles; 65-130
/// bytes an entry measured).
pub const CACHE_ENTRY_BYTES: u64 = 136;

/// The nearest point of the surface to a query point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Nearest {
    /// Distance (voxels).
    pub distance: f64,
    /// The point of the surface (voxel coordinates x, y, z).
    pub point: Vec3,
}

/// Squared distance from `p` to the box `[lo, hi]`.
#[inline]
fn box_distance2(p: Vec3, lo: Vec3, hi: Vec3) -> f64 {
    (lo - p).max(p - hi).max(Vec3::ZERO).length_squared()
}

impl SurfaceIndex {
    /// Index the triangles `triangles` over `vertices` (voxel coordinates x, y, z).
    /// Triangles with an index out of range or a non-finite vertex are left out.
    #[must_use]
    pub fn new(vertices: &[Vec3], triangles: &[[u32; 3]]) -> Self {
        let n = vertices.len();
        let mut tris: Vec<[Vec3; 3]> = triangles
            .iter()
            .filter(|t| {
                t.iter()
                    .all(|&i| (i as usize) < n && vertices[i as usize].is_finite())
            })
            // A triangle without area: its edges are its neighbours' (and the closest
            // point formulas divide by its edges' lengths).
            .filter(|t| {
                let [a, b, c] = t.map(|i| vertices[i as usize]);
                (b - a).cross(c - a).length_squared() > 0.0
            })
            .map(|t| t.map(|i| vertices[i as usize]))
            .collect();
        tris.shrink_to_fit();
        // At most one node a triangle: leaves hold two to four (one only when the mesh
        // has one triangle), so there are fewer inner nodes than triangles.
        let mut nodes = Vec::with_capacity(tris.len());
        if !tris.is_empty() {
            let len = tris.len();
            build(&mut tris, 0, len, &mut nodes);
        }
        Self {
            tris,
            nodes,
            cache: (0..SHARDS).map(|_| Mutex::default()).collect(),
            cache_cap: 0,
            cached: AtomicU64::new(0),
        }
    }

    /// Keep up to `bytes` of answers for grid nodes.
    #[must_use]
    pub fn with_cache(mut self, bytes: u64) -> Self {
        self.cache_cap = bytes;
        self
    }

    /// Bytes at most an index of `triangles` triangles holds without its cache: their
    /// corners, and at most one node a triangle (leaves hold two to four).
    #[must_use]
    pub fn bytes_for(triangles: usize) -> u64 {
        (triangles * (std::mem::size_of::<[Vec3; 3]>() + std::mem::size_of::<Node>())) as u64
    }

    /// Bytes the index holds, its cache full.
    #[must_use]
    pub fn bytes(&self) -> u64 {
        (self.tris.len() * std::mem::size_of::<[Vec3; 3]>()
            + self.nodes.len() * std::mem::size_of::<Node>()) as u64
            + self.cache_cap
    }

    /// [`SurfaceIndex::nearest_within`]`(node, RADIUS, hint)` for grid node `node`
    /// (x, y, z), from the cache when it holds the node.
    #[must_use]
    pub fn nearest_node(&self, node: [i64; 3], hint: Option<u32>) -> Answer {
        // 21 bits a coordinate, offset so that halo nodes before the grid fit.
        debug_assert!(node.iter().all(|c| c.abs() < 1 << 20), "{node:?}");
        let key = node
            .iter()
            .fold(0u64, |k, &c| k << 21 | ((c + (1 << 20)) as u64 & 0x1f_ffff));
        let p = Vec3::new(node[0] as f64, node[1] as f64, node[2] as f64);
        if self.cache_cap == 0 {
            return self.nearest_within(p, RADIUS, hint);
        }
        let shard = &self.cache[(key.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 58) as usize];
        if let Some(a) = shard.lock().expect("cache lock").get(&key) {
            return *a;
        }
        let a = self.nearest_within(p, RADIUS, hint);
        if self.cached.fetch_add(CACHE_ENTRY_BYTES, Ordering::Relaxed) + CACHE_ENTRY_BYTES
            <= self.cache_cap
        {
            shard.lock().expect("cache lock").insert(key, a);
        }
        a
    }

    /// The nearest point of the surface to `p` (voxel coordinates x, y, z), if one lies
    /// within [`RADIUS`].
    #[must_use]
    pub fn nearest(&self, p: Vec3) -> Option<Nearest> {
        self.nearest_within(p, RADIUS, None).map(|(n, _)| n)
    }

    /// The nearest point of the surface to `p` within `radius` (at most [`RADIUS`]),
    /// and the triangle it lies on. `hint`, a triangle that is likely near (the answer
    /// for a neighbouring point), bounds the search from the start; the answer does not
    /// depend on it: of equally near triangles, the one first in the tree's order wins.
    #[must_use]
    pub fn nearest_within(
        &self,
        p: Vec3,
        radius: f64,
        hint: Option<u32>,
    ) -> Option<(Nearest, u32)> {
        // The best so far: squared distance, triangle, point.
        let mut best: Option<(f64, u32, Vec3)> = None;
        let r = radius.min(RADIUS);
        let mut limit2 = r * r;
        let offer = |k: u32, best: &mut Option<(f64, u32, Vec3)>, limit2: &mut f64| {
            let q = closest_on_triangle(p, self.tris[k as usize]);
            let d2 = (q - p).length_squared();
            let better = match *best {
                None => d2 <= *limit2,
                // An exact tie goes to the triangle first in the tree.
                #[allow(clippy::float_cmp)]
                Some((b, bk, _)) => d2 < b || (d2 == b && k < bk),
            };
            if better {
                *best = Some((d2, k, q));
                *limit2 = d2;
            }
        };
        if let Some(k) = hint.filter(|&k| (k as usize) < self.tris.len()) {
            offer(k, &mut best, &mut limit2);
        }
        let mut stack = [0u32; 64];
        let mut top = usize::from(!self.nodes.is_empty());
        while top > 0 {
            top -= 1;
            let at = stack[top];
            let node = self.nodes[at as usize];
            if box_distance2(p, node.lo, node.hi) > limit2 {
                continue;
            }
            if node.count > 0 {
                for k in node.first..node.first + node.count {
                    offer(k, &mut best, &mut limit2);
                }
                continue;
            }
            // The nearer child is opened first: it is pushed last.
            let (left, right) = (at + 1, node.first);
            let (l, r) = (self.nodes[left as usize], self.nodes[right as usize]);
            let (dl, dr) = (box_distance2(p, l.lo, l.hi), box_distance2(p, r.lo, r.hi));
            let (far, near) = if dl <= dr {
                (right, left)
            } else {
                (left, right)
            };
            stack[top] = far;
            stack[top + 1] = near;
            top += 2;
        }
        best.map(|(d2, k, point)| {
            (
                Nearest {
                    distance: d2.sqrt(),
                    point,
                },
                k,
            )
        })
    }
}

/// Build the subtree of `tris[start..end]` at the end of `nodes` (reordering those
/// triangles): split at the median centroid along the box's longest axis.
fn build(tris: &mut [[Vec3; 3]], start: usize, end: usize, nodes: &mut Vec<Node>) {
    let (mut lo, mut hi) = (Vec3::splat(f64::INFINITY), Vec3::splat(f64::NEG_INFINITY));
    for t in &tris[start..end] {
        for v in t {
            lo = lo.min(*v);
            hi = hi.max(*v);
        }
    }
    let at = nodes.len();
    nodes.push(Node {
        lo,
        hi,
        first: start as u32,
        count: (end - start) as u32,
    });
    if end - start <= LEAF {
        return;
    }
    let e = hi - lo;
    let axis = if e.x >= e.y && e.x >= e.z {
        0
    } else if e.y >= e.z {
        1
    } else {
        2
    };
    let key = |t: &[Vec3; 3]| (t[0] + t[1] + t[2])[axis];
    let mid = start + (end - start) / 2;
    tris[start..end].select_nth_unstable_by(mid - start, |a, b| key(a).total_cmp(&key(b)));
    build(tris, start, mid, nodes);
    let right = nodes.len() as u32;
    build(tris, mid, end, nodes);
    nodes[at].first = right;
    nodes[at].count = 0;
}

/// The point of triangle `t` nearest to `p` (Ericson, "Real-Time Collision Detection",
/// 5.1.5: by the Voronoi regions of the vertices, the edges and the face).
#[must_use]
#[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
pub fn closest_on_triangle(p: Vec3, t: [Vec3; 3]) -> Vec3 {
    let [a, b, c] = t;
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The nearest point by brute force over every triangle.
    fn brute(v: &[Vec3], t: &[[u32; 3]], p: Vec3) -> Option<f64> {
        t.iter()
            .map(|t| (closest_on_triangle(p, t.map(|i| v[i as usize])) - p).length())
            .filter(|&d| d <= RADIUS)
            .min_by(f64::total_cmp)
    }

    #[test]
    fn closest_points_lie_in_each_voronoi_region() {
        let t = [Vec3::ZERO, Vec3::X * 2.0, Vec3::Y * 2.0];
        let cases = [
            (Vec3::new(0.5, 0.5, 3.0), Vec3::new(0.5, 0.5, 0.0)), // face
            (Vec3::new(-1.0, -1.0, 1.0), Vec3::ZERO),             // vertex a
            (Vec3::new(3.0, -0.5, 0.0), Vec3::X * 2.0),           // vertex b
            (Vec3::new(-0.5, 3.0, 0.0), Vec3::Y * 2.0),           // vertex c
            (Vec3::new(1.0, -1.0, 0.0), Vec3::X),                 // edge ab
            (Vec3::new(-1.0, 1.0, 0.0), Vec3::Y),                 // edge ac
            (Vec3::new(2.0, 2.0, 1.0), Vec3::new(1.0, 1.0, 0.0)), // edge bc
        ];
        for (p, want) in cases {
            let got = closest_on_triangle(p, t);
            assert!((got - want).length() < 1e-12, "{p}: {got} != {want}");
        }
    }

    #[test]
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn index_agrees_with_brute_force() {
        // An octahedron of radius 6 around (10, 11, 12), each face split in four, and
        // points on a lattice through and around it.
        let c = Vec3::new(10.0, 11.0, 12.0);
        let mut v: Vec<Vec3> = [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z]
            .iter()
            .map(|&d| c + d * 6.0)
            .collect();
        let faces = [
            [0, 2, 4],
            [2, 1, 4],
            [1, 3, 4],
            [3, 0, 4],
            [2, 0, 5],
            [1, 2, 5],
            [3, 1, 5],
            [0, 3, 5],
        ];
        let mut t = Vec::new();
        for f in faces {
            let m: Vec<u32> = (0..3)
                .map(|e| {
                    v.push((v[f[e]] + v[f[(e + 1) % 3]]) * 0.5);
                    (v.len() - 1) as u32
                })
                .collect();
            let f = f.map(|i| i as u32);
            t.extend([
                [f[0], m[0], m[2]],
                [m[0], f[1], m[1]],
                [m[2], m[1], f[2]],
                [m[0], m[1], m[2]],
            ]);
        }
        let index = SurfaceIndex::new(&v, &t);
        assert!(index.bytes() <= SurfaceIndex::bytes_for(t.len()));
        let mut found = 0;
        for z in 0..25 {
            for y in 0..25 {
                for x in 0..25 {
                    let p = Vec3::new(f64::from(x), f64::from(y), f64::from(z)) * 0.93
                        + Vec3::splat(-0.4);
                    let got = index.nearest_within(p, RADIUS, None);
                    assert_eq!(got.map(|n| n.0.distance), brute(&v, &t, p), "at {p}");
                    // Whatever triangle is offered first, the same answer.
                    for hint in [0, 7, 100, 255] {
                        assert_eq!(index.nearest_within(p, RADIUS, Some(hint)), got, "at {p}");
                        let near = index.nearest_within(p, 1.0, Some(hint));
                        assert_eq!(near, got.filter(|n| n.0.distance <= 1.0), "at {p}");
                    }
                    let got = got.map(|n| n.0.distance);
                    found += usize::from(got.is_some());
                }
            }
        }
        // Both outcomes were exercised.
        assert!(found > 1000 && found < 15_000, "{found}");
    }

    /// The tree has at most one node a triangle, whatever the count, and the index
    /// holds no more than [`SurfaceIndex::bytes_for`] says.
    #[test]
    fn the_tree_has_at_most_a_node_a_triangle() {
        for n in 1..300u32 {
            let v: Vec<Vec3> = (0..n + 2)
                .map(|i| {
                    let t = f64::from(i);
                    Vec3::new(t, (t * 0.7).sin() * 3.0, (t * 1.3).cos() * 2.0)
                })
                .collect();
            let t: Vec<[u32; 3]> = (0..n).map(|i| [i, i + 1, i + 2]).collect();
            let index = SurfaceIndex::new(&v, &t);
            assert_eq!(index.tris.len(), n as usize);
            assert!(
                index.nodes.len() <= n as usize,
                "{n}: {}",
                index.nodes.len()
            );
            let held = (index.tris.capacity() * std::mem::size_of::<[Vec3; 3]>()
                + index.nodes.capacity() * std::mem::size_of::<Node>())
                as u64;
            assert!(held <= SurfaceIndex::bytes_for(t.len()), "{n}");
        }
    }

    /// Answers from the cache are those computed; a full cache still answers.
    #[test]
    fn cached_answers_are_the_computed_ones() {
        let v = vec![
            Vec3::ZERO,
            Vec3::X * 4.0,
            Vec3::Y * 4.0,
            Vec3::new(0.0, 0.0, 4.0),
        ];
        let t = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
        let plain = SurfaceIndex::new(&v, &t);
        let small = SurfaceIndex::new(&v, &t).with_cache(10 * CACHE_ENTRY_BYTES);
        for round in 0..2 {
            for z in -3..7 {
                for y in -3..7 {
                    for x in -3..7 {
                        let p = Vec3::new(f64::from(x), f64::from(y), f64::from(z));
                        let want = plain.nearest_within(p, RADIUS, None);
                        let hint = (round == 1).then_some(2);
                        assert_eq!(small.nearest_node([x, y, z].map(i64::from), hint), want);
                    }
                }
            }
        }
        let held: usize = small.cache.iter().map(|s| s.lock().unwrap().len()).sum();
        assert_eq!(held, 10);
    }

    #[test]
    fn bad_triangles_are_left_out() {
        let v = vec![
            Vec3::ZERO,
            Vec3::X,
            Vec3::Y,
            Vec3::splat(f64::NAN),
            Vec3::X * 2.0,
        ];
        // A NaN corner, an index out of range, a repeated corner, collinear corners.
        let t = [[0, 1, 2], [0, 1, 3], [0, 1, 9], [0, 0, 1], [0, 1, 4]];
        let index = SurfaceIndex::new(&v, &t);
        let n = index.nearest(Vec3::new(0.2, 0.2, 1.0)).expect("found");
        assert!((n.distance - 1.0).abs() < 1e-12);
        // Only the good triangle is left: nothing within reach past its corner b.
        assert!(index.nearest(Vec3::new(3.5, 0.0, 0.0)).is_none());
        assert!(SurfaceIndex::new(&[], &[]).nearest(Vec3::ZERO).is_none());
    }
}
