//! Re-embedding the tangles that local moves leave ([`super::untangle`]): each tangle's
//! region, grown ring by ring, embedded inside its fixed boundary.

use std::collections::{HashMap, HashSet};

use glam::{DVec2, DVec3};

use super::solvers::{bicgstab, cg};
use super::{orient, stored, UntangleReport, Untangler, RETURN_SWEEPS};
use crate::trace::metrics::orientation;

/// Re-embedding of the tangles that local moves leave: the bad triangles are grouped
/// into tangles (sharing vertices), and each tangle's region (its vertices' stars,
/// grown ring by ring) gets an embedding inside its fixed boundary.
///
/// Behavior:
/// - A region is tried when it is a disk (one boundary loop through distinct vertices,
///   Euler characteristic 1, every half-edge once), its boundary points reached, lie
///   within a hemisphere and wind counter-clockwise seen from outside.
/// - Its inner vertices (those whose triangles are all in the region) are placed, on the
///   gnomonic projection at the boundary's mean direction, where each is a weighted
///   mean of its neighbours ([`Weights`]; positive weights, the boundary fixed), solved
///   by conjugate gradients or BiCGSTAB. With a convex boundary this is an embedding
///   (Tutte 1963, Floater 2003); a region's boundary is not always convex, so the
///   result is kept only when it leaves fewer bad triangles in the region, as stored,
///   than there were; otherwise the next weights, then a ring more, are tried.
/// - Projection and embedding are affine-invariant, so a map squeezed 10^4 times is
///   re-embedded as well as an unsqueezed one.
/// - Only inner vertices move, so triangles outside the region keep their points bit
///   for bit. Unreached inner vertices are placed for the solve but keep no point.
pub(super) struct Reembedder<'u, 'a> {
    u: &'u Untangler<'a>,
    /// A triangle's stamp: equal to `stamp` when it is in the current region.
    tri_stamp: Vec<u32>,
    /// A vertex's stamp and its unknown's index in the current region.
    vert_stamp: Vec<u32>,
    vert_index: Vec<u32>,
    stamp: u32,
}

/// Rings around a tangle that its re-embedded region may take, at most.
pub const MAX_REGION_RINGS: u32 = 16;

/// The share of the surface's triangles a re-embedded region may take, at most: a
/// region is a disk on one side of its boundary, and its points must lie in a
/// hemisphere.
const MAX_REGION_SHARE: f64 = 0.25;

impl<'u, 'a> Reembedder<'u, 'a> {
    pub(super) fn new(u: &'u Untangler<'a>) -> Self {
        Self {
            u,
            tri_stamp: vec![0; u.triangles.len()],
            vert_stamp: vec![0; u.offsets.len() - 1],
            vert_index: vec![0; u.offsets.len() - 1],
            stamp: 0,
        }
    }

    /// Re-embed the tangles of `bad` (sorted), recording moved vertices' first points in
    /// `moved`. Returns the bad triangles left, sorted.
    pub(super) fn run(
        &mut self,
        sphere: &mut [Option<DVec3>],
        mut bad: Vec<u32>,
        moved: &mut Vec<(u32, DVec3)>,
        report: &mut UntangleReport,
    ) -> Vec<u32> {
        let mut left: Vec<u32> = Vec::new();
        bad.sort_unstable();
        // Bad triangles already taken (by a tangle or a re-embedded region): `bad` less
        // these is what is still to do, the smallest first.
        let mut taken = vec![false; self.u.triangles.len()];
        let mut next = 0;
        loop {
            while next < bad.len() && taken[bad[next] as usize] {
                next += 1;
            }
            let Some(&first) = bad.get(next) else { break };
            if self.u.exhausted() {
                // Out of work: what is left stays bad.
                left.extend(bad[next..].iter().copied().filter(|&t| !taken[t as usize]));
                break;
            }
            let tangle = self.tangle(&bad, &taken, first);
            // The smallest region whose embedding leaves fewer bad triangles than it
            // holds now.
            let mut found: Option<Found> = None;
            'rings: for rings in 0..MAX_REGION_RINGS {
                for weights in [Weights::MeanValue, Weights::InverseLength, Weights::Uniform] {
                    match self.try_region(sphere, &tangle, rings, weights) {
                        Attempt::Grow => {}
                        // The other weights would find the same.
                        Attempt::Reshape => break,
                        Attempt::Stop => break 'rings,
                        Attempt::Placed {
                            region,
                            placed,
                            bad_before,
                            bad_after,
                        } => {
                            if bad_after < bad_before {
                                found = Some((rings, region, placed));
                                break 'rings;
                            }
                        }
                    }
                }
            }
            if let Some((rings, region, placed)) = found {
                for (v, p) in placed {
                    if let Some(old) = sphere[v as usize].filter(|&old| old != p) {
                        moved.push((v, old));
                        sphere[v as usize] = Some(p);
                        report.region_seeds += 1;
                    }
                }
                report.regions += 1;
                report.region_rings = report.region_rings.max(u64::from(rings));
                // The region's bad triangles are those of its embedding.
                for &t in &region {
                    taken[t as usize] = true;
                }
                left.extend(region.iter().copied().filter(|&t| {
                    orient(sphere, self.u.triangles[t as usize]).is_some_and(|o| o <= 0.0)
                }));
            }
            for &t in &tangle {
                taken[t as usize] = true;
            }
            left.extend_from_slice(&tangle);
        }
        left.sort_unstable();
        left.dedup();
        // Triangles of a tangle whose region was re-embedded later may be good now.
        left.retain(|&t| orient(sphere, self.u.triangles[t as usize]).is_some_and(|o| o <= 0.0));
        left
    }

    /// Move the re-embedded vertices `before` (each with its point before the
    /// embedding) back toward those points, all the way or by halves of the way down to
    /// a 32nd, wherever none of their triangles that is positive turns bad: what the
    /// embedding moved and need not have stays where the streamlines put it.
    pub(super) fn go_back(&self, sphere: &mut [Option<DVec3>], before: &[(u32, DVec3)]) {
        let u = self.u;
        let positive = |sphere: &[Option<DVec3>], v: u32| -> Vec<bool> {
            u.around(v)
                .iter()
                .map(|&t| orient(sphere, u.triangles[t as usize]).is_some_and(|o| o > 0.0))
                .collect()
        };
        for _ in 0..RETURN_SWEEPS {
            let mut changed = false;
            for &(v, old) in before {
                let now = sphere[v as usize].expect("placed points are reached");
                if now == old {
                    continue;
                }
                let keep = positive(sphere, v);
                for halvings in 0..6 {
                    let p = if halvings == 0 {
                        old
                    } else {
                        stored(now.lerp(old, 0.5f64.powi(halvings)).normalize())
                    };
                    if p == now || !p.is_finite() {
                        break;
                    }
                    sphere[v as usize] = Some(p);
                    let ok = positive(sphere, v)
                        .iter()
                        .zip(&keep)
                        .all(|(&after, &was)| after || !was);
                    if ok {
                        changed = true;
                        break;
                    }
                    sphere[v as usize] = Some(now);
                }
            }
            if !changed {
                break;
            }
        }
    }

    /// The bad triangles (of `bad`, sorted, less those `taken`) that share vertices with
    /// `first`, directly or through others, sorted.
    fn tangle(&mut self, bad: &[u32], taken: &[bool], first: u32) -> Vec<u32> {
        let u = self.u;
        self.stamp += 1;
        let stamp = self.stamp;
        let is_bad = |t: u32| !taken[t as usize] && bad.binary_search(&t).is_ok();
        let mut out = vec![first];
        self.tri_stamp[first as usize] = stamp;
        let mut i = 0;
        while i < out.len() {
            let t = out[i];
            i += 1;
            for v in u.triangles[t as usize] {
                for &w in u.around(v) {
                    if self.tri_stamp[w as usize] != stamp && is_bad(w) {
                        self.tri_stamp[w as usize] = stamp;
                        out.push(w);
                    }
                }
            }
        }
        out.sort_unstable();
        out
    }

    /// Try the region of the vertices within `rings` rings of the `tangle`'s.
    #[allow(clippy::too_many_lines)] // one pass of checks, in the order of the doc
    #[allow(clippy::many_single_char_names)] // u the index, c the direction, v w vertices, q points, x the unknowns
    fn try_region(
        &mut self,
        sphere: &[Option<DVec3>],
        tangle: &[u32],
        rings: u32,
        weights: Weights,
    ) -> Attempt {
        let u = self.u;
        // The region: the stars of the vertices within `rings` rings of the tangle's.
        let mut core = corners(u, tangle);
        self.stamp += 1;
        let stamp = self.stamp;
        let mut frontier = core.clone();
        for &v in &core {
            self.vert_stamp[v as usize] = stamp;
        }
        for _ in 0..rings {
            let mut next = Vec::new();
            for &v in &frontier {
                for &t in u.around(v) {
                    for w in u.triangles[t as usize] {
                        if self.vert_stamp[w as usize] != stamp {
                            self.vert_stamp[w as usize] = stamp;
                            next.push(w);
                        }
                    }
                }
            }
            core.extend_from_slice(&next);
            frontier = next;
        }
        let mut region: Vec<u32> = core.iter().flat_map(|&v| u.around(v)).copied().collect();
        region.sort_unstable();
        region.dedup();
        if region.len() as f64 > MAX_REGION_SHARE * u.triangles.len() as f64
            || !u.spend(region.len() as u64)
        {
            return Attempt::Stop;
        }
        // Its half-edges, each once (a manifold region), and its boundary.
        let mut half: HashSet<(u32, u32)> = HashSet::with_capacity(region.len() * 3);
        for &t in &region {
            self.tri_stamp[t as usize] = stamp;
            let [a, b, c] = u.triangles[t as usize];
            if a == b || b == c || c == a {
                return Attempt::Stop;
            }
            for e in [(a, b), (b, c), (c, a)] {
                if !half.insert(e) {
                    return Attempt::Stop;
                }
            }
        }
        let mut next: HashMap<u32, u32> = HashMap::new();
        let mut boundary_edges = 0usize;
        for &(a, b) in &half {
            if !half.contains(&(b, a)) {
                boundary_edges += 1;
                if next.insert(a, b).is_some() {
                    return Attempt::Reshape; // the boundary touches itself at a
                }
            }
        }
        if boundary_edges < 3 {
            return Attempt::Stop;
        }
        // One loop through every boundary vertex.
        let start = *next.keys().min().expect("a boundary");
        let mut lp = vec![start];
        let mut v = next[&start];
        while v != start {
            if lp.len() > boundary_edges {
                return Attempt::Reshape;
            }
            lp.push(v);
            v = match next.get(&v) {
                Some(&w) => w,
                None => return Attempt::Reshape,
            };
        }
        if lp.len() != boundary_edges {
            return Attempt::Reshape; // more than one loop: holes
        }
        // Vertices: inner (all triangles in the region) and boundary.
        let verts = corners(u, &region);
        // 3 F = 2 E_inner + E_boundary.
        let edges = usize::midpoint(3 * region.len(), boundary_edges);
        if verts.len() + region.len() != edges + 1 {
            return Attempt::Reshape; // not a disk
        }
        self.stamp += 1;
        let vstamp = self.stamp;
        for &v in &lp {
            self.vert_stamp[v as usize] = vstamp;
        }
        let inner: Vec<u32> = verts
            .iter()
            .copied()
            .filter(|&v| self.vert_stamp[v as usize] != vstamp)
            .collect();
        if inner.is_empty() {
            return Attempt::Reshape;
        }
        // An inner vertex has every triangle in the region; one that does not (a pinched
        // vertex with a fan outside) would move triangles outside it.
        if !inner.iter().all(|&v| {
            u.around(v)
                .iter()
                .all(|&t| self.tri_stamp[t as usize] == stamp)
        }) {
            return Attempt::Reshape;
        }
        // The boundary's points, projected at their mean direction.
        let mut sum = DVec3::ZERO;
        let mut bpts = Vec::with_capacity(lp.len());
        for &v in &lp {
            match sphere[v as usize] {
                Some(p) => {
                    sum += p;
                    bpts.push(p);
                }
                None => return Attempt::Reshape,
            }
        }
        let Some(c) = sum.try_normalize() else {
            return Attempt::Stop;
        };
        if bpts.iter().any(|p| p.dot(c) <= 0.1) {
            return Attempt::Stop;
        }
        let e1 = c.any_orthonormal_vector();
        let e2 = c.cross(e1);
        let project = |p: DVec3| DVec2::new(p.dot(e1), p.dot(e2)) / p.dot(c);
        let bq: Vec<DVec2> = bpts.iter().map(|&p| project(p)).collect();
        let area: f64 = (0..bq.len())
            .map(|i| bq[i].perp_dot(bq[(i + 1) % bq.len()]))
            .sum();
        if area.is_nan() || area <= 0.0 {
            return Attempt::Reshape;
        }
        // Tutte: deg(i) x_i - sum of inner neighbours x_j = sum of boundary neighbours q_j.
        for (k, &v) in inner.iter().enumerate() {
            self.vert_index[v as usize] = k as u32;
        }
        let mut bq_of: HashMap<u32, DVec2> = HashMap::with_capacity(lp.len());
        for (&v, &q) in lp.iter().zip(&bq) {
            bq_of.insert(v, q);
        }
        let n = inner.len();
        let mean = bq.iter().copied().sum::<DVec2>() / bq.len() as f64;
        let now: Vec<Option<DVec2>> = inner
            .iter()
            .map(|&v| sphere[v as usize].filter(|p| p.dot(c) > 0.1).map(project))
            .collect();
        let at = |w: u32| -> Option<DVec2> {
            bq_of.get(&w).copied().or_else(|| {
                if self.vert_stamp[w as usize] == vstamp {
                    None
                } else {
                    now[self.vert_index[w as usize] as usize]
                }
            })
        };
        // The lengths of the region's edges in the map as it is, for a floor: a
        // millionth of their median, so that edges that are points (or unknown) keep
        // the weights finite.
        let mut ls: Vec<f64> = Vec::new();
        for (k, &v) in inner.iter().enumerate() {
            for &t in u.around(v) {
                for w in u.triangles[t as usize] {
                    if let (Some(a), Some(b)) = (now[k], at(w)) {
                        let d = a.distance(b);
                        if d > 0.0 && d.is_finite() {
                            ls.push(d);
                        }
                    }
                }
            }
        }
        ls.sort_by(f64::total_cmp);
        let Some(&median) = ls.get(ls.len() / 2) else {
            return Attempt::Reshape;
        };
        let floor = median * 1e-6;
        // Each inner vertex's neighbours and weights (positive in every mode).
        let mut nbr_off = vec![0usize; n + 1];
        let mut nbr: Vec<(u32, f64)> = Vec::new();
        let mut rhs = vec![DVec2::ZERO; n];
        let mut deg = vec![0.0f64; n];
        let mut row: Vec<(u32, f64)> = Vec::new();
        for (k, &v) in inner.iter().enumerate() {
            row.clear();
            for &t in u.around(v) {
                let tri = u.triangles[t as usize];
                let i = tri.iter().position(|&x| x == v).expect("v is a corner");
                let (a, b) = (tri[(i + 1) % 3], tri[(i + 2) % 3]);
                match (weights, now[k], at(a), at(b)) {
                    (Weights::MeanValue, Some(o), Some(qa), Some(qb)) => {
                        // Floater's mean value weights, from the unsigned angle at v.
                        let (da, db) = (qa - o, qb - o);
                        let (la, lb) = (da.length().max(floor), db.length().max(floor));
                        let cos = (da.dot(db) / (la * lb)).clamp(-1.0, 1.0);
                        let half = (0.5 * cos.acos()).tan().min(1e8);
                        row.push((a, half / la));
                        row.push((b, half / lb));
                    }
                    (Weights::MeanValue | Weights::InverseLength, Some(o), _, _) => {
                        for w in [a, b] {
                            let d = at(w).map_or(median, |q| q.distance(o).max(floor));
                            row.push((w, 0.5 / d));
                        }
                    }
                    _ => {
                        row.push((a, 0.5 / median));
                        row.push((b, 0.5 / median));
                    }
                }
            }
            row.sort_unstable_by_key(|&(w, _)| w);
            let mut m = 0;
            while m < row.len() {
                let w = row[m].0;
                let mut x = 0.0;
                while m < row.len() && row[m].0 == w {
                    x += row[m].1;
                    m += 1;
                }
                if let Some(q) = bq_of.get(&w) {
                    rhs[k] += x * *q;
                } else {
                    nbr.push((self.vert_index[w as usize], x));
                }
                deg[k] += x;
            }
            nbr_off[k + 1] = nbr.len();
        }
        if deg.iter().any(|d| !(d.is_finite() && *d > 0.0)) {
            return Attempt::Grow;
        }
        let apply = |x: &[DVec2], y: &mut [DVec2]| {
            for k in 0..n {
                let mut s = deg[k] * x[k];
                for &(j, w) in &nbr[nbr_off[k]..nbr_off[k + 1]] {
                    s -= w * x[j as usize];
                }
                y[k] = s;
            }
        };
        let mut x: Vec<DVec2> = now.iter().map(|q| q.unwrap_or(mean)).collect();
        let iterations = if weights == Weights::MeanValue {
            bicgstab(&apply, &deg, &rhs, &mut x)
        } else {
            cg(&apply, &deg, &rhs, &mut x)
        };
        // The solve's work (the embedding is judged all the same; the bound stops the
        // next attempt).
        let _ = u.spend((iterations * n) as u64);
        let placed: Vec<(u32, DVec3)> = inner
            .iter()
            .zip(&x)
            .map(|(&v, q)| (v, stored((c + q.x * e1 + q.y * e2).normalize())))
            .collect();
        if placed.iter().any(|(_, p)| !p.is_finite()) {
            return Attempt::Grow;
        }
        // Its bad triangles as stored, before and after.
        let point = |w: u32| -> Option<DVec3> {
            if self.vert_stamp[w as usize] == vstamp {
                sphere[w as usize]
            } else {
                sphere[w as usize].map(|_| placed[self.vert_index[w as usize] as usize].1)
            }
        };
        let (mut bad_before, mut bad_after) = (0, 0);
        for &t in &region {
            let [a, b, cc] = u.triangles[t as usize];
            if orient(sphere, [a, b, cc]).is_some_and(|o| o <= 0.0) {
                bad_before += 1;
            }
            if let (Some(pa), Some(pb), Some(pc)) = (point(a), point(b), point(cc)) {
                if orientation(pa, pb, pc) <= 0.0 {
                    bad_after += 1;
                }
            }
        }
        Attempt::Placed {
            region,
            placed,
            bad_before,
            bad_after,
        }
    }
}

/// The weights of a region's embedding, tried in this order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Weights {
    /// Floater's mean value weights from the map as it is: where a vertex's ring is
    /// laid down well, the solve leaves it where it is, so the embedding moves the map
    /// near its folds only. Not symmetric.
    MeanValue,
    /// The inverse of each edge's length in the map as it is.
    InverseLength,
    /// Tutte's: every neighbour alike.
    Uniform,
}

/// A kept region: its rings, its triangles (sorted) and its inner vertices' new points.
type Found = (u32, Vec<u32>, Vec<(u32, DVec3)>);

/// The distinct vertices of the triangles `tris`, sorted.
fn corners(u: &Untangler<'_>, tris: &[u32]) -> Vec<u32> {
    let mut v: Vec<u32> = tris.iter().flat_map(|&t| u.triangles[t as usize]).collect();
    v.sort_unstable();
    v.dedup();
    v
}

/// What one region came to.
enum Attempt {
    /// Not a region to embed in (whatever the weights): try a ring more.
    Reshape,
    /// Its embedding with these weights failed: try the next weights, then a ring more.
    Grow,
    /// No larger region will do.
    Stop,
    /// The region's triangles (sorted), the inner vertices' new points, and the
    /// region's bad triangles before and after.
    Placed {
        region: Vec<u32>,
        placed: Vec<(u32, DVec3)>,
        bad_before: usize,
        bad_after: usize,
    },
}
