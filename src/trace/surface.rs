//! Sub-voxel values of u at the boundary nodes, for the direction field.
//!
//! The solve holds phi = 1 (u = 0) on the boundary voxels: the voxelized surface, a
//! staircase. The true surface passes up to a voxel outside them. Central differences
//! at and next to a boundary node then see a plateau: on the ball's poles, a node at
//! the edge of the flat top gets a direction straight down the axis instead of along
//! its radius, and its streamline arrives up to 0.7 degrees off (docs/trace.md).
//!
//! For the direction field only, each boundary node b takes instead the value the
//! surface implies. With the surface's outward normal n and the depth d of b below it,
//! u falls linearly from u(b - n) to 0 at the surface, d voxels beyond b:
//!
//! `u(b) = d / (1 + d) * u(b - n)`, with u(b - n) interpolated trilinearly over the solid
//! corners of its cell (their stored values).
//!
//! And the exterior nodes that share a cell with the solid (the corners of the cells
//! surface seeds start in) point along the surface's inward normal, where the layers'
//! staircase would point along the axes.
//!
//! Which surface ([`Boundary`]):
//! - the run's input surface, when it has one (a triangle mesh or the built-in
//!   starfish): d is the distance from b to its nearest point of the mesh and n the
//!   direction to it ([`super::nearest`]), for nodes within a voxel of the mesh (an
//!   exterior node: within [`super::nearest::RADIUS`]). At a horn's base a few voxels
//!   across, the smoothed solid below bends the field along the surface, and surface
//!   seeds there fold the sphere map (spot at resolution 128: 14 flipped triangles;
//!   with the mesh, none);
//! - otherwise (label volumes, molecules), and for the nodes the mesh does not explain:
//!   the 1/2 level of the solid indicator smoothed with a Gaussian of [`SIGMA`] voxels.
//!   n and d come from one Newton step, `n = -grad s / |grad s|` and
//!   `d = (s(b) - 1/2) / |grad s|`. Where that is not well defined, b keeps u = 0: a
//!   depth outside [0, 1] (thin parts, whose smoothed indicator stays below 1/2, and
//!   sharp edges), a gradient of s under 1e-3, or a cell at b - n with less than half
//!   its weight on solid nodes.
//!
//! A corrected value depends only on the mesh and the nodes within [`REACH`] of b, read
//! with fixed sums in a fixed order, so every tile that holds b computes the same bits.

use std::sync::OnceLock;

use super::nearest::SurfaceIndex;
use crate::grid::Block;
use crate::math::Vec3;

pub use super::boundary::{Boundary, BOUNDARY_MESH, BOUNDARY_SMOOTHED};

/// Width (voxels) of the Gaussian that smooths the solid indicator.
const SIGMA: f64 = 2.0;
/// Below this |grad s| the smoothed surface has no normal (a thin sheet's midplane).
const MIN_GRADIENT: f64 = 1e-3;
/// Radius (voxels) of the kernel: 3 sigma.
const RADIUS: usize = 6;
/// Width of the kernel.
const WIDTH: usize = 2 * RADIUS + 1;
/// How far from a boundary node its corrected value reads: the kernel's radius (the
/// cell at b - n lies within one node).
pub const REACH: usize = RADIUS;

/// The kernel `k` (normalized) and its derivative weights `t k(t) / sigma^2`, at
/// t = -RADIUS ..= RADIUS; and for every pattern of WIDTH solid bits along x, the
/// sums of both over the set bits.
struct Kernel {
    k: [f64; WIDTH],
    dk: [f64; WIDTH],
    sum: Vec<f64>,
    dsum: Vec<f64>,
}

fn kernel() -> &'static Kernel {
    static K: OnceLock<Kernel> = OnceLock::new();
    K.get_or_init(|| {
        let mut k = [0.0; WIDTH];
        for (i, v) in k.iter_mut().enumerate() {
            let t = i as f64 - RADIUS as f64;
            *v = (-t * t / (2.0 * SIGMA * SIGMA)).exp();
        }
        let total: f64 = k.iter().sum();
        for v in &mut k {
            *v /= total;
        }
        let dk: [f64; WIDTH] =
            std::array::from_fn(|i| (i as f64 - RADIUS as f64) / (SIGMA * SIGMA) * k[i]);
        let (mut sum, mut dsum) = (vec![0.0; 1 << WIDTH], vec![0.0; 1 << WIDTH]);
        for p in 0..1usize << WIDTH {
            for i in 0..WIDTH {
                if p >> i & 1 == 1 {
                    sum[p] += k[i];
                    dsum[p] += dk[i];
                }
            }
        }
        Kernel { k, dk, sum, dsum }
    })
}

/// Whether a value of u belongs to the solid (boundary, interior or center).
#[inline]
fn solid(v: f64) -> bool {
    v >= 0.0
}

/// The solid indicator of a block as bit rows (bit x of row (z, y)).
struct Bits {
    words: usize,
    shape: [usize; 3],
    rows: Vec<u64>,
}

impl Bits {
    fn of(u: &Block<f64>) -> Self {
        let shape = u.shape;
        let words = shape[2].div_ceil(64) + 1;
        let mut bits = vec![0u64; shape[0] * shape[1] * words];
        for (row, out) in u
            .data
            .chunks_exact(shape[2])
            .zip(bits.chunks_exact_mut(words))
        {
            for (chunk, word) in row.chunks(64).zip(out.iter_mut()) {
                *word = chunk
                    .iter()
                    .enumerate()
                    .fold(0, |w, (b, &v)| w | u64::from(solid(v)) << b);
            }
        }
        Self {
            words,
            shape,
            rows: bits,
        }
    }

    /// The WIDTH bits of row (z, y) from x - RADIUS (x >= RADIUS).
    #[inline]
    fn window(&self, z: usize, y: usize, x: usize) -> usize {
        (self.bits_from(z, y, x - RADIUS) & ((1 << WIDTH) - 1)) as usize
    }

    /// The bits of row (z, y) from x on (at least 64 of them, zero beyond the row).
    #[inline]
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn bits_from(&self, z: usize, y: usize, x: usize) -> u64 {
        let row = &self.rows[(z * self.shape[1] + y) * self.words..];
        let (w, b) = (x / 64, x % 64);
        let lo = row[w] >> b;
        if b == 0 {
            lo
        } else {
            lo | (row[w + 1] << (64 - b))
        }
    }

    /// Whether any of the 3 x 3 x 3 nodes around (z, y, x) is solid (all three at least
    /// 1).
    #[inline]
    fn any_around(&self, z: usize, y: usize, x: usize) -> bool {
        (z - 1..=z + 1).any(|z| (y - 1..=y + 1).any(|y| self.bits_from(z, y, x - 1) & 7 != 0))
    }
}

/// What a tile's direction field takes from the smoothed surface.
pub struct Corrections {
    /// u over the box `[origin - 1, origin + shape + 1)`: the stored values, with every
    /// boundary node (u = 0 next to a node outside the solid) given its sub-voxel value.
    pub u: Block<f64>,
    /// The unit inward normal (x, y, z) at each node of the box outside the solid that
    /// shares a cell with it, by offset into `u`, in increasing offset.
    pub normals: Vec<(u32, [f32; 3])>,
}

/// Bytes [`corrections`] holds at most for a box of `shape` nodes, besides its input:
/// the corrected copy, the bit rows, and one query and one normal per node.
#[must_use]
pub fn bytes(shape: [usize; 3]) -> u64 {
    let c: [usize; 3] = shape.map(|s| s + 2);
    let b: [usize; 3] = shape.map(|s| s + 2 * (REACH + 1));
    let nodes = (c[0] * c[1] * c[2]) as u64;
    let bits = (b[0] * b[1] * (b[2].div_ceil(64) + 1) * 8) as u64;
    let query = std::mem::size_of::<([u16; 3], Query)>() as u64;
    let normal = std::mem::size_of::<(u32, [f32; 3])>() as u64;
    nodes * (8 + query + normal) + bits
}

/// The kinds of node the smoothed surface is evaluated at.
#[derive(Clone, Copy, PartialEq)]
enum Query {
    /// A boundary node: its sub-voxel value.
    Boundary,
    /// An exterior node next to the solid: its inward normal.
    Outside,
}

/// The corrections of the box `[origin, origin + shape)` from `u`, which holds that box
/// with `REACH + 1` more nodes on every side.
#[must_use]
#[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
pub fn corrections(
    u: &Block<f64>,
    origin: [i64; 3],
    shape: [usize; 3],
    mesh: Option<&SurfaceIndex>,
) -> Corrections {
    let m = REACH + 1;
    debug_assert!((0..3).all(|a| u.origin[a] == origin[a] - m as i64));
    debug_assert!((0..3).all(|a| u.shape[a] == shape[a] + 2 * m));
    let inner: [usize; 3] = shape.map(|s| s + 2);
    let mut out = Block::filled(origin.map(|o| o - 1), inner, f64::NAN);
    let [_, sy, sx] = u.shape;
    let strides = [sy * sx, sx, 1];
    // The nodes to evaluate, as local indices of `u` (z, y, x).
    // Local indices fit in u16: a block is far smaller than 65536 nodes a side.
    let mut queries: Vec<([u16; 3], Query)> = Vec::new();
    let bits = Bits::of(u);
    for z in 0..inner[0] {
        for y in 0..inner[1] {
            let src = u.offset(z + REACH, y + REACH, REACH);
            let dst = out.offset(z, y, 0);
            let row = &u.data[src..src + inner[2]];
            out.data[dst..dst + inner[2]].copy_from_slice(row);
            // Most rows hold neither a boundary node (u = 0) nor an exterior layer
            // (u < 0): interior (u > 0) and unsolved (NaN) nodes need nothing.
            if !row.iter().any(|&v| v <= 0.0) {
                continue;
            }
            for x in 0..inner[2] {
                let o = src + x;
                let v = u.data[o];
                let l = [z + REACH, y + REACH, x + REACH];
                if v == 0.0 {
                    let open = strides
                        .iter()
                        .any(|&s| !solid(u.data[o - s]) || !solid(u.data[o + s]));
                    if open {
                        queries.push((l.map(|c| c as u16), Query::Boundary));
                    }
                } else if v < 0.0 {
                    // Only the box itself needs directions.
                    let in_box = [z, y, x]
                        .iter()
                        .zip(&inner)
                        .all(|(&c, &n)| c > 0 && c + 1 < n);
                    // The 3 x 3 x 3 nodes around it: all the nodes its cells have.
                    if in_box && bits.any_around(l[0], l[1], l[2]) {
                        queries.push((l.map(|c| c as u16), Query::Outside));
                    }
                }
            }
        }
    }
    // By column (y, x), then z: the smoothed solid's row sums along y are shared down a
    // column, and the mesh's nearest triangles change little.
    queries.sort_unstable_by_key(|(l, _)| (l[1], l[2], l[0]));
    let mut normals = Vec::new();
    if let Some(mesh) = mesh {
        // The nodes the mesh explains take its values; the others, the smoothed solid's.
        // (Queries go down columns: each starts from its predecessor's triangle.)
        let mut hint = None;
        queries.retain(|&(l, kind)| {
            let l = l.map(usize::from);
            let o = out.offset(l[0] - REACH, l[1] - REACH, l[2] - REACH);
            match from_mesh(u, mesh, l, kind, &mut hint) {
                Some(MeshValue::U(v)) => out.data[o] = v,
                Some(MeshValue::Normal(n)) => normals.push((o as u32, n)),
                None => return true,
            }
            false
        });
    }
    if queries.is_empty() {
        normals.sort_unstable_by_key(|n| n.0);
        return Corrections { u: out, normals };
    }
    let mut column = Column::default();
    for &(l, kind) in &queries {
        let l = l.map(usize::from);
        let (s, g) = column.smoothed(&bits, l);
        let o = out.offset(l[0] - REACH, l[1] - REACH, l[2] - REACH);
        let norm = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
        if norm < MIN_GRADIENT {
            continue;
        }
        match kind {
            Query::Boundary => {
                if let Some(v) = boundary_value(u, l, s, g, norm) {
                    out.data[o] = v;
                }
            }
            // The tile stores directions in f32: (c / norm) as f32 is what it would
            // compute from the f64 normal.
            Query::Outside => normals.push((o as u32, g.map(|c| (c / norm) as f32))),
        }
    }
    normals.sort_unstable_by_key(|n| n.0);
    Corrections { u: out, normals }
}

/// The sums along y of the row sums along x for one column (y, x) of nodes, by z:
/// (sum k T, sum k dT, sum dk T) with T the kernel's sum over a row's solid bits and dT
/// its derivative's. Computed once per z, whichever nodes of the column need them.
#[derive(Default)]
struct Column {
    at: Option<(usize, usize)>,
    /// Per z: the column the sums were computed for (a count), and the sums.
    sums: Vec<(u64, [f64; 3])>,
    count: u64,
}

impl Column {
    /// s and grad s (x, y, z) at local node `l` ([`REACH`] inside the block).
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn smoothed(&mut self, bits: &Bits, l: [usize; 3]) -> (f64, [f64; 3]) {
        if self.at != Some((l[1], l[2])) {
            self.at = Some((l[1], l[2]));
            self.count += 1;
            if self.sums.len() < bits.shape[0] {
                self.sums.resize(bits.shape[0], (0, [0.0; 3]));
            }
        }
        let k = kernel();
        let (mut s, mut g) = (0.0f64, [0.0f64; 3]);
        for (i, (kz, dkz)) in k.k.iter().zip(&k.dk).enumerate() {
            let z = l[0] + i - RADIUS;
            let slot = &mut self.sums[z];
            if slot.0 != self.count {
                let mut r = [0.0f64; 3];
                for (j, (ky, dky)) in k.k.iter().zip(&k.dk).enumerate() {
                    let p = bits.window(z, l[1] + j - RADIUS, l[2]);
                    if p == 0 {
                        continue;
                    }
                    let (t, dt) = (k.sum[p], k.dsum[p]);
                    r[0] += ky * t;
                    r[1] += ky * dt;
                    r[2] += dky * t;
                }
                *slot = (self.count, r);
            }
            let [a, b, c] = slot.1;
            s += kz * a;
            g[0] += kz * b;
            g[1] += kz * c;
            g[2] += dkz * a;
        }
        (s, g)
    }
}

/// The sub-voxel value of the boundary node at local index `l` of `u`, from the smoothed
/// indicator `s` there and its gradient `g` (x, y, z) of length `norm`, if defined.
#[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
fn boundary_value(u: &Block<f64>, l: [usize; 3], s: f64, g: [f64; 3], norm: f64) -> Option<f64> {
    // grad s points inward; the depth below the 1/2 level along the outward normal:
    let d = (s - 0.5) / norm;
    if !(0.0..=1.0).contains(&d) {
        return None;
    }
    // The point one voxel inward, b - n = b + grad s / |grad s|, as an offset from b
    // (z, y, x): the same bits wherever b sits in the block.
    let q = [g[2] / norm, g[1] / norm, g[0] / norm];
    let inward = interpolate_solid(u, l, q)?;
    Some(d / (1.0 + d) * inward)
}

/// What the mesh gives a node.
enum MeshValue {
    /// A boundary node's sub-voxel u.
    U(f64),
    /// An exterior node's inward normal (x, y, z).
    Normal([f32; 3]),
}

/// A node's value from the input mesh (see the module's notes), if the mesh explains it:
/// a boundary node within a voxel of the surface (its depth d and outward normal n, the
/// direction to its nearest surface point: `u = d / (1 + d) * u(b - n)`, as from the
/// smoothed solid), an exterior node within [`nearest::RADIUS`](crate::trace::nearest::RADIUS) (its inward normal, the
/// direction to its nearest surface point).
#[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
fn from_mesh(
    u: &Block<f64>,
    mesh: &SurfaceIndex,
    l: [usize; 3],
    kind: Query,
    hint: &mut Option<u32>,
) -> Option<MeshValue> {
    let g: [i64; 3] = std::array::from_fn(|a| u.origin[a] + l[a] as i64);
    let p = Vec3::new(g[2] as f64, g[1] as f64, g[0] as f64);
    let (near, triangle) = mesh.nearest_node([g[2], g[1], g[0]], *hint)?;
    *hint = Some(triangle);
    let d = near.distance;
    match kind {
        // On the surface: u = 0, as stored.
        Query::Boundary if d == 0.0 => Some(MeshValue::U(0.0)),
        Query::Boundary if d <= 1.0 => {
            let n = (near.point - p) / d;
            let inward = interpolate_solid(u, l, [-n.z, -n.y, -n.x])?;
            Some(MeshValue::U(d / (1.0 + d) * inward))
        }
        Query::Outside if d > 0.0 => {
            let n = (near.point - p) / d;
            Some(MeshValue::Normal([n.x as f32, n.y as f32, n.z as f32]))
        }
        // A boundary node deeper than a voxel is left to the smoothed solid.
        _ => None,
    }
}

/// u at `l + q` (local node `l`, offset `q` within one node; z, y, x) interpolated
/// trilinearly over the solid corners of its cell, if they carry at least half the
/// weight.
#[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
fn interpolate_solid(u: &Block<f64>, l: [usize; 3], q: [f64; 3]) -> Option<f64> {
    let c = q.map(f64::floor);
    let t: [f64; 3] = std::array::from_fn(|a| q[a] - c[a]);
    let c: [usize; 3] = std::array::from_fn(|a| (l[a] as i64 + c[a] as i64) as usize);
    let (mut sum, mut weight) = (0.0, 0.0);
    for dz in 0..2 {
        for dy in 0..2 {
            for dx in 0..2 {
                let w = crate::math::corner_weight(t, [dz, dy, dx]);
                let v = u.data[u.offset(c[0] + dz, c[1] + dy, c[2] + dx)];
                if solid(v) {
                    sum += w * v;
                    weight += w;
                }
            }
        }
    }
    (weight >= 0.5).then(|| sum / weight)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::{GridSpec, MemBudget};

    /// A ball of radius `r` around `c` in a block of `n` nodes from `origin`: u = 1 -
    /// r'/r inside (a cone), -1e-4 just outside (the first exterior layer), NaN beyond.
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn ball(n: usize, origin: i64, c: f64, r: f64) -> Block<f64> {
        let mut u = Block::filled([origin; 3], [n; 3], f64::NAN);
        for z in 0..n {
            for y in 0..n {
                for x in 0..n {
                    let p = [z, y, x].map(|v| v as f64 + origin as f64 - c);
                    let d = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                    let o = u.offset(z, y, x);
                    u.data[o] = if d <= r {
                        1.0 - d / r
                    } else if d <= r + 1.5 {
                        -1e-4
                    } else {
                        f64::NAN
                    };
                }
            }
        }
        // The staircase: phi = 1 on the solid nodes next to the outside.
        let b = u.clone();
        for z in 1..n - 1 {
            for y in 1..n - 1 {
                for x in 1..n - 1 {
                    let o = b.offset(z, y, x);
                    let s = [n * n, n, 1];
                    if solid(b.data[o])
                        && s.iter()
                            .any(|&s| !solid(b.data[o - s]) || !solid(b.data[o + s]))
                    {
                        u.data[o] = 0.0;
                    }
                }
            }
        }
        u
    }

    /// The mesh gives the boundary only where the solid is exactly its inside.
    #[test]
    fn a_closed_or_trimmed_solid_keeps_the_smoothed_boundary() {
        let with = |k: &str, v: u64| {
            let mut a = serde_json::json!({"stages": {"voxelize": {"result": {
                "cavity_voxels": 0, "closing_voxels": 0, "removed_voxels": 0}}}});
            a["stages"]["voxelize"]["result"][k] = v.into();
            a
        };
        assert!(Boundary::solid_is_the_mesh(&with("closing_voxels", 0)));
        for k in ["cavity_voxels", "closing_voxels", "removed_voxels"] {
            assert!(!Boundary::solid_is_the_mesh(&with(k, 12)), "{k}");
        }
        let star = serde_json::json!({"input": {"path": null, "builtin": "starfish"}});
        let spec = GridSpec {
            shape: [8; 3],
            origin: [0.0; 3],
            spacing: 1.0,
            chunk: [8; 3],
            unit: None,
        };
        let mut closed = with("closing_voxels", 3);
        closed["input"] = star["input"].clone();
        let b = Boundary::for_run(&closed, &spec, MemBudget::default());
        assert!(b.mesh.is_none() && b.problem.is_none());
        assert_eq!(b.name(), BOUNDARY_SMOOTHED);
        let mut open = with("closing_voxels", 0);
        open["input"] = star["input"].clone();
        assert_eq!(
            Boundary::for_run(&open, &spec, MemBudget::default()).name(),
            BOUNDARY_MESH
        );
        // A budget the mesh's index does not fit: the smoothed solid, saying why.
        let tight = MemBudget(crate::grid::BASE_BYTES + (1 << 20));
        let small = Boundary::for_run(&open, &spec, tight);
        assert_eq!(small.name(), BOUNDARY_SMOOTHED);
        assert!(small
            .problem
            .is_some_and(|p| p.contains("triangles need up to")));
    }

    /// A sphere of radius `r` around (c, c, c): an icosahedron split four times (5,120
    /// triangles, edges of about r / 16), its vertices on the sphere. The sphere is at
    /// most r (1 - cos 2 deg) ~ 6e-4 r inside the mesh's faces.
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn sphere_mesh(c: f64, r: f64) -> SurfaceIndex {
        let t = f64::midpoint(1.0, 5f64.sqrt());
        let mut v: Vec<Vec3> = [
            [-1.0, t, 0.0],
            [1.0, t, 0.0],
            [-1.0, -t, 0.0],
            [1.0, -t, 0.0],
            [0.0, -1.0, t],
            [0.0, 1.0, t],
            [0.0, -1.0, -t],
            [0.0, 1.0, -t],
            [t, 0.0, -1.0],
            [t, 0.0, 1.0],
            [-t, 0.0, -1.0],
            [-t, 0.0, 1.0],
        ]
        .map(|p| Vec3::from_array(p).normalize())
        .to_vec();
        let mut f: Vec<[u32; 3]> = vec![
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ];
        for _ in 0..4 {
            let mut mid = std::collections::HashMap::new();
            let mut split = |a: u32, b: u32, v: &mut Vec<Vec3>| {
                *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                    v.push(((v[a as usize] + v[b as usize]) * 0.5).normalize());
                    (v.len() - 1) as u32
                })
            };
            f = f
                .iter()
                .flat_map(|&[a, b, d]| {
                    let (ab, bd, da) = (
                        split(a, b, &mut v),
                        split(b, d, &mut v),
                        split(d, a, &mut v),
                    );
                    [[a, ab, da], [ab, b, bd], [da, bd, d], [ab, bd, da]]
                })
                .collect();
        }
        let v: Vec<Vec3> = v.iter().map(|&p| Vec3::splat(c) + p * r).collect();
        SurfaceIndex::new(&v, &f)
    }

    /// On a ball, the corrected boundary values are those of the linear profile the
    /// stored u implies, 1 - r'/r, to within a few percent of one voxel's fall; the
    /// interior and the outside are copied. From a mesh of the sphere they come closer.
    #[test]
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn boundary_values_of_a_ball_follow_its_profile() {
        let (n, r, c) = (48usize, 17.3, 23.6);
        let m = REACH as i64 + 1;
        let u = ball(n, -m, c - m as f64, r);
        let mesh = sphere_mesh(c - m as f64, r);
        // In units of one voxel's fall of u (1 / r).
        let smoothed = profile_error(&u, c - m as f64, r, None);
        let exact = profile_error(&u, c - m as f64, r, Some(&mesh));
        eprintln!("largest error: smoothed solid {smoothed:.3}, mesh {exact:.3} voxels");
        assert!(
            smoothed < 0.35,
            "smoothed solid: worst error {smoothed} voxels"
        );
        assert!(exact < 0.1, "mesh: worst error {exact} voxels");
    }

    /// The largest error of the corrected boundary values of `u`, the ball of radius `r`
    /// around (c, c, c), against its profile (voxels of u's fall).
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn profile_error(u: &Block<f64>, c: f64, r: f64, mesh: Option<&SurfaceIndex>) -> f64 {
        let n = u.shape[0];
        let shape = [n - 2 * (REACH + 1); 3];
        let out = corrections(u, [0; 3], shape, mesh).u;
        let (mut fixed, mut worst) = (0, 0.0f64);
        for z in 0..shape[0] + 2 {
            for y in 0..shape[1] + 2 {
                for x in 0..shape[2] + 2 {
                    let raw = u.data[u.offset(z + REACH, y + REACH, x + REACH)];
                    let v = out.data[out.offset(z, y, x)];
                    if raw != 0.0 {
                        assert!(v.to_bits() == raw.to_bits(), "only boundary nodes change");
                        continue;
                    }
                    let p = [z, y, x].map(|v| v as f64 - 1.0 - c);
                    let d = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                    let want = 1.0 - d / r;
                    worst = worst.max((v - want).abs() * r);
                    fixed += usize::from(v > 0.0);
                }
            }
        }
        assert!(fixed > 500, "{fixed} boundary nodes corrected");
        worst
    }

    /// The same node gets the same bits from boxes that hold it at different places.
    #[test]
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn values_do_not_depend_on_the_box() {
        let (n, r, c) = (48usize, 15.0, 23.0);
        let m = REACH as i64 + 1;
        let u = ball(n, -m, c - m as f64, r);
        let mesh = sphere_mesh(c - m as f64, r);
        for mesh in [None, Some(&mesh)] {
            same_values_in_two_boxes(&u, mesh);
        }
    }

    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn same_values_in_two_boxes(u: &Block<f64>, mesh: Option<&SurfaceIndex>) {
        let n = u.shape[0];
        let m = REACH as i64 + 1;
        let whole = corrections(u, [0; 3], [n - 2 * m as usize; 3], mesh);
        let sub_origin = [5i64, 9, 3];
        let sub_shape = [20usize, 17, 25];
        let mut part = Block::filled(
            sub_origin.map(|o| o - m),
            sub_shape.map(|s| s + 2 * m as usize),
            0.0,
        );
        for z in 0..part.shape[0] {
            for y in 0..part.shape[1] {
                for x in 0..part.shape[2] {
                    let g = [z, y, x].map(|v| v as i64);
                    let o = part.offset(z, y, x);
                    part.data[o] = u.data[u.offset(
                        (g[0] + part.origin[0] - u.origin[0]) as usize,
                        (g[1] + part.origin[1] - u.origin[1]) as usize,
                        (g[2] + part.origin[2] - u.origin[2]) as usize,
                    )];
                }
            }
        }
        let sub = corrections(&part, sub_origin, sub_shape, mesh);
        let global = |b: &Block<f64>, o: usize| {
            let [sy, sx] = [b.shape[1], b.shape[2]];
            let l = [o / (sy * sx), o / sx % sy, o % sx];
            std::array::from_fn::<i64, 3, _>(|a| b.origin[a] + l[a] as i64)
        };
        for z in 0..sub.u.shape[0] {
            for y in 0..sub.u.shape[1] {
                for x in 0..sub.u.shape[2] {
                    let g = [z, y, x].map(|v| v as i64);
                    let w = whole.u.data[whole.u.offset(
                        (g[0] + sub.u.origin[0] - whole.u.origin[0]) as usize,
                        (g[1] + sub.u.origin[1] - whole.u.origin[1]) as usize,
                        (g[2] + sub.u.origin[2] - whole.u.origin[2]) as usize,
                    )];
                    assert_eq!(sub.u.data[sub.u.offset(z, y, x)].to_bits(), w.to_bits());
                }
            }
        }
        // The normals of the nodes of the small box, as the whole box has them.
        let inside = |g: [i64; 3]| {
            (0..3).all(|a| g[a] >= sub_origin[a] && g[a] < sub_origin[a] + sub_shape[a] as i64)
        };
        let of = |c: &Corrections| -> Vec<([i64; 3], [u32; 3])> {
            c.normals
                .iter()
                .map(|&(o, n)| (global(&c.u, o as usize), n.map(f32::to_bits)))
                .filter(|(g, _)| inside(*g))
                .collect()
        };
        let (a, b) = (of(&sub), of(&whole));
        assert!(a.len() > 100, "{} normals in the small box", a.len());
        assert_eq!(a, b);
    }

    /// The column sums give the Gaussian's direct sum, also where a window straddles two
    /// words of a bit row (blocks wider than 64 nodes).
    #[test]
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn smoothed_sums_match_a_direct_sum_across_words() {
        let shape = [16usize, 16, 150];
        let mut u = Block::filled([0; 3], shape, f64::NAN);
        for z in 0..shape[0] {
            for y in 0..shape[1] {
                for x in 0..shape[2] {
                    // An irregular solid: a wavy slab and scattered nodes.
                    let wave = 8.0 + 3.0 * (x as f64 * 0.3).sin() + 2.0 * (y as f64 * 0.5).cos();
                    let speck = (x * 7 + y * 13 + z * 29) % 11 == 0;
                    let o = u.offset(z, y, x);
                    u.data[o] = if (z as f64) < wave || speck {
                        0.5
                    } else {
                        -1e-4
                    };
                }
            }
        }
        let bits = Bits::of(&u);
        let k = kernel();
        let mut column = Column::default();
        let mut checked = 0;
        for y in [RADIUS, RADIUS + 2] {
            for x in (RADIUS..shape[2] - RADIUS).step_by(3) {
                for z in RADIUS..shape[0] - RADIUS {
                    let (s, g) = column.smoothed(&bits, [z, y, x]);
                    let (mut ds, mut dg) = (0.0, [0.0; 3]);
                    for i in 0..WIDTH {
                        for j in 0..WIDTH {
                            for l in 0..WIDTH {
                                let v = u.data
                                    [u.offset(z + i - RADIUS, y + j - RADIUS, x + l - RADIUS)];
                                if !solid(v) {
                                    continue;
                                }
                                ds += k.k[i] * k.k[j] * k.k[l];
                                dg[0] += k.k[i] * k.k[j] * k.dk[l];
                                dg[1] += k.k[i] * k.dk[j] * k.k[l];
                                dg[2] += k.dk[i] * k.k[j] * k.k[l];
                            }
                        }
                    }
                    assert!((s - ds).abs() < 1e-12, "s at {z} {y} {x}: {s} vs {ds}");
                    for a in 0..3 {
                        assert!((g[a] - dg[a]).abs() < 1e-12, "grad s at {z} {y} {x}");
                    }
                    checked += 1;
                }
            }
        }
        assert!(checked > 100);
    }

    /// Outside the staircase of a ball, the smoothed surface's inward normal points at
    /// the center; the axis-aligned differences of the layers do not.
    #[test]
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn inward_normals_of_a_ball_point_at_its_center() {
        let (n, r, c) = (48usize, 17.3, 23.6);
        let m = REACH + 1;
        let u = ball(n, -(m as i64), c - m as f64, r);
        let mesh = sphere_mesh(c - m as f64, r);
        // From the mesh, a node's normal is that of its nearest face (or edge, or
        // vertex): the faces turn up to their angular radius, about 2.3 degrees, from the
        // sphere's radius.
        for (mesh, bound) in [(None, [2.0, 8.0]), (Some(&mesh), [1.5, 3.0])] {
            normals_point_at(&u, c - m as f64, mesh, bound);
        }
    }

    /// The exterior normals' angles to the center `c` (each axis), with median and max
    /// under `bound`.
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn normals_point_at(u: &Block<f64>, c: f64, mesh: Option<&SurfaceIndex>, bound: [f64; 2]) {
        let n = u.shape[0];
        let m = REACH + 1;
        let out = corrections(u, [0; 3], [n - 2 * m; 3], mesh);
        let mut angles = Vec::new();
        for &(o, g) in &out.normals {
            let (o, g) = (o as usize, g.map(f64::from));
            let [sy, sx] = [out.u.shape[1], out.u.shape[2]];
            let l = [o / (sy * sx), o / sx % sy, o % sx];
            assert!(out.u.data[o] < 0.0, "normals only outside the solid");
            // Node (z, y, x) of the box is local l + 1 of `out.u`.
            let to_c = [l[2], l[1], l[0]].map(|v| c - (v as f64 - 1.0));
            let len = (to_c[0].powi(2) + to_c[1].powi(2) + to_c[2].powi(2)).sqrt();
            let cos = (0..3).map(|a| g[a] * to_c[a] / len).sum::<f64>();
            angles.push(cos.clamp(-1.0, 1.0).acos().to_degrees());
        }
        assert!(out.normals.windows(2).all(|w| w[0].0 < w[1].0));
        angles.sort_by(f64::total_cmp);
        let (med, max) = (angles[angles.len() / 2], angles[angles.len() - 1]);
        eprintln!(
            "{} layer nodes: median {med:.2}, max {max:.2} degrees (mesh: {})",
            angles.len(),
            mesh.is_some()
        );
        assert!(angles.len() > 1000);
        assert!(med < bound[0] && max < bound[1], "median {med}, max {max}");
    }
}
