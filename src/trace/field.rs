//! The direction field of a tile: node directions of steepest descent of phi,
//! approximated between the nodes by a quadratic B-spline.
//!
//! The gradient of the trilinear interpolant of phi (the paper's eq. 6) jumps across cell
//! faces, which an adaptive integrator pays for with rejected steps at every face. So
//! the direction is taken at the grid nodes. At a node it is grad(u)/|grad(u)| for
//! u = 1 - phi (central differences of the f64 u, one-sided where a neighbour has no
//! value), so -grad(phi) whatever its size: down a thin arm |grad(phi)| falls to 1e-22
//! and below, which a stored gradient would flush to zero but a unit vector keeps. The
//! differences read the boundary nodes' sub-voxel values, and exterior nodes next to the
//! solid take the smoothed surface's normal ([`super::surface`]).
//!
//! Between the nodes, the field is the tensor-product quadratic B-spline of the node
//! directions over the 3 x 3 x 3 nodes nearest the point ([`Tile::direction`]). It is
//! C1: its derivative is continuous too, where trilinear interpolation of the same
//! nodes has a kink at every cell face. On a kink an RK45 step's error shrinks like h^2,
//! not h^5, so the step control rejected a third of its steps there (near the center,
//! where the directions turn fastest, and just below the surface). With the spline, on
//! the 256^3 ball with 50,000 seeds, rejections fell from 1.84 million to 0.12 million
//! and field evaluations by 45%, with the same arrival angles (docs/trace.md). Like any
//! B-spline it reproduces linear fields exactly; it approximates the node values rather
//! than passing through them (at a node it weighs the node 0.42 and its neighbours the
//! rest), so it smooths over one node more than the trilinear interpolant. Where one of
//! the 27 nodes has no value (beyond the exterior layers, or off the grid) the
//! trilinear interpolant is used, which tells a point that has left the domain.
//!
//! A node's direction depends only on u within [`U_MARGIN`] nodes of it, so every tile
//! that holds a node holds the same value; a tile's halo holds every node the spline
//! reads for the points its streamlines evaluate, so a streamline does not depend on the
//! tiling.

use glam::{DVec3, Vec4};

mod levels;

use super::nearest::SurfaceIndex;
use super::surface::{self, REACH};
use crate::grid::Block;
use crate::math::floor;

/// The field, as recorded with a trace (`stages.trace.result.field`).
pub const FIELD: &str = "unit node directions of grad(u), quadratic B-spline";

/// Nodes of u a tile is built from beyond its own box on every side: one for the
/// central differences, and the reach of the boundary nodes' sub-voxel values.
pub const U_MARGIN: usize = REACH + 1;

/// Why the field has no direction at a point.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NoDirection {
    /// A corner of the point's cell has no phi (outside the solved region or the grid).
    Outside,
    /// The interpolated gradient vanishes.
    Flat,
}

/// Node values of one tile and its halo: the unit direction of descent of phi (x, y,
/// z; zero where it vanishes) and u, or NaN u where a node has no value.
pub struct Tile {
    /// Grid index `[z, y, x]` of the first node held.
    pub origin: [i64; 3],
    /// Nodes held, `[z, y, x]`.
    pub shape: [usize; 3],
    nodes: Vec<Vec4>,
}

impl Tile {
    /// Node directions over the box `[origin, origin + shape)` from `u` = 1 - phi, which
    /// must hold that box with [`U_MARGIN`] more nodes on every side (NaN where there is
    /// no value). The differences read the boundary nodes' sub-voxel values
    /// ([`super::surface`]); the u the tile keeps is the stored one.
    #[must_use]
    pub fn from_u(
        u: &Block<f64>,
        origin: [i64; 3],
        shape: [usize; 3],
        mesh: Option<&SurfaceIndex>,
    ) -> Self {
        Self::from_u_in(u, origin, shape, mesh, Vec::new())
    }

    /// [`Tile::from_u`], with the nodes written into `buf` (the nodes of a tile no longer
    /// needed: memory already faulted in, where a fresh allocation costs the kernel a
    /// page fault and a page of zeros per 4 KiB).
    #[must_use]
    pub fn from_u_in(
        u: &Block<f64>,
        origin: [i64; 3],
        shape: [usize; 3],
        mesh: Option<&SurfaceIndex>,
        mut buf: Vec<Vec4>,
    ) -> Self {
        debug_assert!((u.origin, u.shape) == Self::u_box(origin, shape));
        let corr = surface::corrections(u, origin, shape, mesh);
        // u with the boundary nodes' sub-voxel values, one node beyond the tile.
        let cu = &corr.u;
        let [_, sy, sx] = cu.shape;
        let nx = shape[2];
        // Every node is written below (row by row): a reused buffer keeps its length
        // without being cleared first.
        let len = shape[0] * shape[1] * nx;
        if buf.len() >= len {
            buf.truncate(len);
        } else {
            buf.clear();
            buf.resize(len, Vec4::ZERO);
        }
        let mut nodes = buf;
        for z in 0..shape[0] {
            for y in 0..shape[1] {
                let o = cu.offset(z + 1, y + 1, 1);
                let s = u.offset(z + U_MARGIN, y + U_MARGIN, U_MARGIN);
                let out = &mut nodes[(z * shape[1] + y) * nx..][..nx];
                row_directions(
                    RowNeighbours {
                        c: &cu.data[o..][..nx],
                        x: [&cu.data[o - 1..][..nx], &cu.data[o + 1..][..nx]],
                        y: [&cu.data[o - sx..][..nx], &cu.data[o + sx..][..nx]],
                        z: [&cu.data[o - sy * sx..][..nx], &cu.data[o + sy * sx..][..nx]],
                    },
                    &u.data[s..][..nx],
                    out,
                );
            }
        }
        // On the exterior layers (where phi only keeps streamlines in), the staircase
        // would point along the axes: a node that shares a cell with the solid (as the
        // corners of the cells that surface seeds start in do) goes along the surface's
        // inward normal instead (the mesh's or the smoothed solid's, as
        // [`surface::corrections`] found it). corrections() gives normals only at the
        // tile's own nodes (one inside the corrected box), where u has a value.
        for &(o, d) in &corr.normals {
            let o = o as usize;
            let l = [o / (sy * sx), o / sx % sy, o % sx];
            debug_assert!((0..3).all(|a| l[a] >= 1 && l[a] <= shape[a]));
            let n = &mut nodes[((l[0] - 1) * shape[1] + l[1] - 1) * nx + l[2] - 1];
            debug_assert!(!n.w.is_nan());
            *n = Vec4::new(d[0], d[1], d[2], n.w);
        }
        Self {
            origin,
            shape,
            nodes,
        }
    }

    /// The tile's node buffer, for [`Tile::from_u_in`].
    #[must_use]
    pub fn into_nodes(self) -> Vec<Vec4> {
        self.nodes
    }

    /// The box of u a tile of `shape` nodes from `origin` is built from: [`U_MARGIN`]
    /// more nodes on every side.
    #[must_use]
    pub fn u_box(origin: [i64; 3], shape: [usize; 3]) -> ([i64; 3], [usize; 3]) {
        (
            origin.map(|o| o - U_MARGIN as i64),
            shape.map(|s| s + 2 * U_MARGIN),
        )
    }

    /// Bytes a tile of `shape` nodes holds.
    #[must_use]
    pub fn bytes(shape: [usize; 3]) -> u64 {
        (shape[0] * shape[1] * shape[2] * std::mem::size_of::<[f32; 4]>()) as u64
    }

    /// Bytes building a tile of `shape` nodes holds besides the tile: the u block with
    /// its margin and what [`surface::corrections`] holds.
    #[must_use]
    pub fn build_bytes(shape: [usize; 3]) -> u64 {
        let (_, b) = Self::u_box([0; 3], shape);
        (b[0] * b[1] * b[2] * 8) as u64 + surface::bytes(shape)
    }

    /// The local index of the cell of `p` (voxel coordinates x, y, z) if the tile holds
    /// all eight of its nodes.
    #[inline]
    fn cell(&self, p: DVec3) -> Option<[usize; 3]> {
        let c = [floor(p.z), floor(p.y), floor(p.x)];
        let mut l = [0usize; 3];
        for a in 0..3 {
            let v = c[a] - self.origin[a];
            if v < 0 || v + 1 >= self.shape[a] as i64 {
                return None;
            }
            l[a] = v as usize;
        }
        Some(l)
    }

    /// Whether the cell of `p` (voxel coordinates x, y, z) lies inside this tile's nodes.
    #[inline]
    #[must_use]
    pub fn holds(&self, p: DVec3) -> bool {
        self.cell(p).is_some()
    }

    /// The interpolated node directions (not unit length between nodes) and u at `p`,
    /// the hot path of tracing: trilinear in f32 on four lanes. A corner without a value
    /// makes u NaN: Outside.
    #[inline]
    pub fn interpolate(&self, p: DVec3) -> Result<(DVec3, f64), NoDirection> {
        // Per lane a + (b - a) t: four lanes at once (SSE on x86-64).
        #[inline]
        fn lerp(a: Vec4, b: Vec4, t: f32) -> Vec4 {
            a + (b - a) * t
        }
        let [lz, ly, lx] = self.cell(p).ok_or(NoDirection::Outside)?;
        let tx = (p.x - (lx as i64 + self.origin[2]) as f64) as f32;
        let ty = (p.y - (ly as i64 + self.origin[1]) as f64) as f32;
        let tz = (p.z - (lz as i64 + self.origin[0]) as f64) as f32;
        let (sy, sx) = (self.shape[1], self.shape[2]);
        let b0 = (lz * sy + ly) * sx + lx;
        let b1 = b0 + sy * sx;
        let n = &self.nodes;
        let y0 = lerp(
            lerp(n[b0], n[b0 + 1], tx),
            lerp(n[b0 + sx], n[b0 + sx + 1], tx),
            ty,
        );
        let y1 = lerp(
            lerp(n[b1], n[b1 + 1], tx),
            lerp(n[b1 + sx], n[b1 + sx + 1], tx),
            ty,
        );
        let v = lerp(y0, y1, tz);
        if v.w.is_nan() {
            return Err(NoDirection::Outside);
        }
        Ok((
            DVec3::new(f64::from(v.x), f64::from(v.y), f64::from(v.z)),
            f64::from(v.w),
        ))
    }

    /// The direction at node `g` (grid index z, y, x), if the tile holds it and it does
    /// not vanish: the node value [`Tile::direction`]'s spline is built on (the spline
    /// does not pass through it).
    #[inline]
    #[must_use]
    pub fn node(&self, g: [i64; 3]) -> Option<DVec3> {
        let l: [i64; 3] = std::array::from_fn(|a| g[a] - self.origin[a]);
        if (0..3).any(|a| l[a] < 0 || l[a] >= self.shape[a] as i64) {
            return None;
        }
        let n = self.nodes
            [(l[0] as usize * self.shape[1] + l[1] as usize) * self.shape[2] + l[2] as usize];
        if n.w.is_nan() || (n.x == 0.0 && n.y == 0.0 && n.z == 0.0) {
            return None;
        }
        // Stored unit length (to f32 rounding, or a surface normal made unit in f64 and
        // rounded): not normalized again, which was a square root and a division on the
        // upwind map's chain of dependent operations per voxel.
        Some(DVec3::new(f64::from(n.x), f64::from(n.y), f64::from(n.z)))
    }

    /// The field's vector at `p`, not unit length: the quadratic B-spline of the node
    /// directions ([`Tile::spline`]), or their trilinear interpolant where a node of
    /// the spline has no value (Outside where a corner of the cell has none).
    #[inline]
    pub fn vector(&self, p: DVec3) -> Result<DVec3, NoDirection> {
        match self.spline(p) {
            Some(g) => Ok(g),
            None => Ok(self.interpolate(p)?.0),
        }
    }

    /// The unit direction of descent of phi at `p`: [`Tile::vector`], normalized. Flat
    /// where the node directions around `p` cancel (a ridge between two basins) or
    /// vanish.
    #[inline]
    pub fn direction(&self, p: DVec3) -> Result<DVec3, NoDirection> {
        let g = self.vector(p)?;
        let n2 = g.length_squared();
        if n2 > 1e-12 {
            return Ok(g * (1.0 / n2.sqrt()));
        }
        // The node directions around p disagree (streamlines converging onto the
        // midplane of a thin part from both sides, where the flow turns along it): the
        // gradient of the trilinear interpolant of u itself (the paper's eq. 6) still
        // points along the part.
        let t = self.trilinear_gradient(p)?;
        let m = t.length();
        if m > 0.0 && m.is_finite() {
            Ok(t / m)
        } else {
            Err(NoDirection::Flat)
        }
    }

    /// Offsets between neighbouring nodes along z, y and x in `nodes`.
    #[inline]
    fn strides(&self) -> [usize; 3] {
        [self.shape[1] * self.shape[2], self.shape[2], 1]
    }

    /// The quadratic B-spline's nodes at `p`: the index of the first of the 3 x 3 x 3
    /// nodes around the node nearest `p`, and `p`'s offset from that node along z, y and
    /// x (in [-1/2, 1/2)), if the tile holds all 27.
    #[inline]
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn stencil(&self, p: DVec3) -> Option<(usize, [f64; 3])> {
        let c = [p.z, p.y, p.x];
        let strides = self.strides();
        let mut base = 0usize;
        let mut t = [0.0; 3];
        for a in 0..3 {
            let n = floor(c[a] + 0.5);
            let l = n - self.origin[a];
            if l < 1 || l + 1 >= self.shape[a] as i64 {
                return None;
            }
            base += (l as usize - 1) * strides[a];
            t[a] = c[a] - n as f64;
        }
        Some((base, t))
    }

    /// The tensor-product quadratic B-spline of the node directions at `p` (not unit
    /// length), if the tile holds the 3 x 3 x 3 nodes around the node nearest `p` and
    /// all have a value. Per axis, with t = p - n in [-1/2, 1/2) from the nearest node n,
    /// nodes n - 1, n, n + 1 weigh (1/2 - t)^2 / 2, 3/4 - t^2 and (1/2 + t)^2 / 2: C1
    /// across the midplanes where n changes, and exact for linear fields. In f32 on four
    /// lanes, like the trilinear interpolant.
    #[inline]
    #[must_use]
    pub fn spline(&self, p: DVec3) -> Option<DVec3> {
        let (base, t) = self.stencil(p)?;
        let [sz, sy, _] = self.strides();
        let [wz, wy, wx] = t.map(|t| {
            let t = t as f32;
            let (lo, hi) = (0.5 - t, 0.5 + t);
            [0.5 * lo * lo, 0.75 - t * t, 0.5 * hi * hi]
        });
        // One bounds check for the 27 nodes: the last is base + 2 sz + 2 sy + 2.
        let n = &self.nodes[base..=base + 2 * sz + 2 * sy + 2];
        let term = |dz: usize, dy: usize| {
            let o = dz * sz + dy * sy;
            let row = &n[o..o + 3];
            (row[0] * wx[0] + row[1] * wx[1] + row[2] * wx[2]) * (wz[dz] * wy[dy])
        };
        let acc = ((term(0, 0) + term(0, 1)) + (term(0, 2) + term(1, 0)))
            + ((term(1, 1) + term(1, 2)) + (term(2, 0) + term(2, 1)))
            + term(2, 2);
        // A node without a value (NaN u) makes the sum's u NaN, whatever its weight.
        if acc.w.is_nan() {
            return None;
        }
        Some(DVec3::new(
            f64::from(acc.x),
            f64::from(acc.y),
            f64::from(acc.z),
        ))
    }

    /// The nearest node within `r` nodes of the cell of `p` (a cube) whose u exceeds u at
    /// every corner of that cell (ties: the first in C order), if any. The cube must lie
    /// in the tile (`r + 1` within its halo), so the answer is the same in every tile.
    #[must_use]
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    pub fn escape(&self, p: DVec3, r: i64) -> Option<DVec3> {
        let c = [floor(p.z), floor(p.y), floor(p.x)];
        let (sy, sx) = (self.shape[1], self.shape[2]);
        let at = |g: [i64; 3]| -> Option<f32> {
            let l: [i64; 3] = std::array::from_fn(|a| g[a] - self.origin[a]);
            if (0..3).any(|a| l[a] < 0 || l[a] >= self.shape[a] as i64) {
                return None;
            }
            let v = self.nodes[(l[0] as usize * sy + l[1] as usize) * sx + l[2] as usize].w;
            (!v.is_nan()).then_some(v)
        };
        let mut top = f32::NEG_INFINITY;
        for dz in 0..2 {
            for dy in 0..2 {
                for dx in 0..2 {
                    top = top.max(at([c[0] + dz, c[1] + dy, c[2] + dx])?);
                }
            }
        }
        let mut best: Option<(f64, DVec3)> = None;
        for z in c[0] - r..=c[0] + 1 + r {
            for y in c[1] - r..=c[1] + 1 + r {
                for x in c[2] - r..=c[2] + 1 + r {
                    let Some(v) = at([z, y, x]) else { continue };
                    if v <= top {
                        continue;
                    }
                    let q = DVec3::new(x as f64, y as f64, z as f64);
                    let d = (q - p).length_squared();
                    if best.is_none_or(|b| d < b.0) {
                        best = Some((d, q));
                    }
                }
            }
        }
        best.map(|b| b.1)
    }

    /// The trilinear interpolant of the stored u at `p` and its gradient, in f64, if every
    /// corner of the cell has a value: u between the nodes as the map's and the inverse
    /// map's rows give it (at a node, the node's own u).
    #[must_use]
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    pub fn u_trilinear(&self, p: DVec3) -> Option<(f64, DVec3)> {
        let [lz, ly, lx] = self.cell(p)?;
        let t = [
            p.x - (lx as i64 + self.origin[2]) as f64,
            p.y - (ly as i64 + self.origin[1]) as f64,
            p.z - (lz as i64 + self.origin[0]) as f64,
        ];
        let (sy, sx) = (self.shape[1], self.shape[2]);
        let base = (lz * sy + ly) * sx + lx;
        let (mut u, mut g) = (0.0, DVec3::ZERO);
        for c in 0..8usize {
            let [dx, dy, dz] = [c & 1, (c >> 1) & 1, c >> 2];
            let v = f64::from(self.nodes[base + dz * sy * sx + dy * sx + dx].w);
            // Per axis: weight t or 1 - t, derivative +1 or -1.
            let w = |a: usize, d: usize| if d == 1 { t[a] } else { 1.0 - t[a] };
            let s = |d: usize| if d == 1 { 1.0 } else { -1.0 };
            let (wx, wy, wz) = (w(0, dx), w(1, dy), w(2, dz));
            u += wx * wy * wz * v;
            g += DVec3::new(s(dx) * wy * wz, wx * s(dy) * wz, wx * wy * s(dz)) * v;
        }
        (!u.is_nan()).then_some((u, g))
    }

    /// The gradient of the trilinear interpolant of u at `p`.
    fn trilinear_gradient(&self, p: DVec3) -> Result<DVec3, NoDirection> {
        let [lz, ly, lx] = self.cell(p).ok_or(NoDirection::Outside)?;
        let tx = p.x - (lx as i64 + self.origin[2]) as f64;
        let ty = p.y - (ly as i64 + self.origin[1]) as f64;
        let tz = p.z - (lz as i64 + self.origin[0]) as f64;
        let (sy, sx) = (self.shape[1], self.shape[2]);
        let base = (lz * sy + ly) * sx + lx;
        let c = |dz: usize, dy: usize, dx: usize| {
            f64::from(self.nodes[base + dz * sy * sx + dy * sx + dx].w)
        };
        let lerp = |a: f64, b: f64, t: f64| a + (b - a) * t;
        let gx = lerp(
            lerp(c(0, 0, 1) - c(0, 0, 0), c(0, 1, 1) - c(0, 1, 0), ty),
            lerp(c(1, 0, 1) - c(1, 0, 0), c(1, 1, 1) - c(1, 1, 0), ty),
            tz,
        );
        let gy = lerp(
            lerp(c(0, 1, 0) - c(0, 0, 0), c(0, 1, 1) - c(0, 0, 1), tx),
            lerp(c(1, 1, 0) - c(1, 0, 0), c(1, 1, 1) - c(1, 0, 1), tx),
            tz,
        );
        let gz = lerp(
            lerp(c(1, 0, 0) - c(0, 0, 0), c(1, 0, 1) - c(0, 0, 1), tx),
            lerp(c(1, 1, 0) - c(0, 1, 0), c(1, 1, 1) - c(0, 1, 1), tx),
            ty,
        );
        Ok(DVec3::new(gx, gy, gz))
    }
}

/// One row of nodes (along x) of the (corrected) u and its six neighbouring rows:
/// `x`, `y` and `z` hold the rows shifted by -1 and +1 along that axis.
#[derive(Clone, Copy)]
struct RowNeighbours<'a> {
    c: &'a [f64],
    x: [&'a [f64]; 2],
    y: [&'a [f64]; 2],
    z: [&'a [f64]; 2],
}

/// The node values of one row: the unit direction of ascent of u from its differences
/// (central, one-sided next to a node without a value) and the stored u (`stored`), or
/// NaN u where the node has none. A node on a ridge of u (a one-voxel sheet between two
/// exterior layers) has central differences that cancel: it goes up the steepest
/// one-sided difference instead. The row and its neighbours are contiguous slices, so
/// the loop does no index arithmetic per node (the tile's build took a third less time
/// than the loop over offsets it replaces; the same bits).
#[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
fn row_directions(r: RowNeighbours<'_>, stored: &[f64], out: &mut [Vec4]) {
    let n = out.len();
    let (c, stored) = (&r.c[..n], &stored[..n]);
    let pairs = [r.x, r.y, r.z].map(|[m, p]| (&m[..n], &p[..n]));
    for i in 0..n {
        let p0 = c[i];
        let w = stored[i] as f32;
        if p0.is_nan() {
            out[i] = Vec4::new(0.0, 0.0, 0.0, f32::NAN);
            continue;
        }
        let mut g = [0.0f64; 3];
        let mut top = 0.0f64;
        for (ga, (m, p)) in g.iter_mut().zip(pairs) {
            let (m, p) = (m[i], p[i]);
            // Both: (p - m) / 2; one: the one-sided difference; none: 0.
            let hi = if p.is_nan() { p0 } else { p };
            let lo = if m.is_nan() { p0 } else { m };
            let half = if p.is_nan() || m.is_nan() { 1.0 } else { 0.5 };
            *ga = (hi - lo) * half;
            // max ignores NaN.
            top = top.max(p - p0).max(m - p0);
        }
        let mut len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
        if top > 0.0 && (len.is_nan() || len <= 1e-3 * top) {
            // The first steepest neighbour in the order -x, +x, -y, +y, -z, +z.
            let mut best = 0.0f64;
            for (a, (m, p)) in pairs.iter().enumerate() {
                for (sign, q) in [(-1.0, m[i]), (1.0, p[i])] {
                    if q - p0 > best {
                        best = q - p0;
                        g = [0.0; 3];
                        g[a] = sign;
                    }
                }
            }
            len = 1.0;
        }
        out[i] = if len > 0.0 && len.is_finite() {
            let inv = 1.0 / len;
            Vec4::new(
                (g[0] * inv) as f32,
                (g[1] * inv) as f32,
                (g[2] * inv) as f32,
                w,
            )
        } else {
            Vec4::new(0.0, 0.0, 0.0, w)
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// u at the nodes a tile of `n` nodes from the origin is built from: `f(x, y, z)` at
    /// node (x, y, z).
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn grid(n: usize, f: impl Fn(f64, f64, f64) -> f64) -> Block<f64> {
        let m = U_MARGIN as i64;
        let mut u = Block::filled([-m; 3], [n + 2 * U_MARGIN; 3], 0.0f64);
        for z in 0..u.shape[0] {
            for y in 0..u.shape[1] {
                for x in 0..u.shape[2] {
                    let o = u.offset(z, y, x);
                    let c = [x, y, z].map(|v| (v as i64 - m) as f64);
                    u.data[o] = f(c[0], c[1], c[2]);
                }
            }
        }
        u
    }

    /// A tile built into another tile's node buffer (longer, and holding other values)
    /// is the tile built afresh, node for node, NaN u included.
    #[test]
    fn a_reused_buffer_builds_the_same_tile() {
        let ball = |x: f64, y: f64, z: f64| {
            let r = ((x - 6.0).powi(2) + (y - 5.0).powi(2) + (z - 7.0).powi(2)).sqrt();
            if r < 5.0 {
                1.0 - r / 5.0
            } else {
                f64::NAN
            }
        };
        let old = Tile::from_u(&grid(14, |x, y, z| 0.1 * x + y - z), [0; 3], [14; 3], None);
        let buf = old.into_nodes();
        assert!(buf.len() > 12 * 12 * 12);
        let u = grid(12, ball);
        let fresh = Tile::from_u(&u, [0; 3], [12; 3], None);
        let reused = Tile::from_u_in(&u, [0; 3], [12; 3], None, buf);
        assert_eq!(fresh.nodes.len(), reused.nodes.len());
        assert!(fresh.nodes.iter().any(|n| n.w.is_nan()));
        for (a, b) in fresh.nodes.iter().zip(&reused.nodes) {
            assert_eq!(
                a.to_array().map(f32::to_bits),
                b.to_array().map(f32::to_bits)
            );
        }
    }

    /// A tile of `n` nodes a side from the origin whose node values are `f(x, y, z)`.
    fn tile_of(n: usize, mut f: impl FnMut(f32, f32, f32) -> Vec4) -> Tile {
        let mut nodes = Vec::with_capacity(n * n * n);
        for z in 0..n {
            for y in 0..n {
                for x in 0..n {
                    nodes.push(f(x as f32, y as f32, z as f32));
                }
            }
        }
        Tile {
            origin: [0; 3],
            shape: [n; 3],
            nodes,
        }
    }

    /// Node values from a fixed pseudo-random sequence (a linear congruential generator).
    fn noisy(n: usize) -> Tile {
        let mut s = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            s = s
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (s >> 40) as f32 / (1u64 << 24) as f32 - 0.5
        };
        tile_of(n, |_, _, _| Vec4::new(next(), next(), next(), 1.0))
    }

    /// The spline reproduces node values that are linear in the position.
    #[test]
    fn spline_is_exact_for_linear_node_values() {
        let f = |x: f32, y: f32, z: f32| {
            Vec4::new(
                0.3 + 0.5 * x - 0.25 * z,
                -0.125 * y + 0.0625 * x,
                1.0 + 0.2 * z,
                2.0,
            )
        };
        let t = tile_of(8, f);
        for p in [
            DVec3::new(3.3, 2.7, 5.9),
            DVec3::new(1.5, 1.5, 1.5),
            DVec3::new(4.0, 2.49, 3.51),
        ] {
            let want = f(p.x as f32, p.y as f32, p.z as f32);
            let g = t.spline(p).unwrap();
            let want = DVec3::new(f64::from(want.x), f64::from(want.y), f64::from(want.z));
            assert!((g - want).length() < 1e-5, "{p}: {g} against {want}");
        }
        // Its 27 nodes must be held: the nearest node of p needs a neighbour each side.
        assert!(t.spline(DVec3::new(0.4, 3.0, 3.0)).is_none());
        assert!(t.spline(DVec3::new(6.6, 3.0, 3.0)).is_none());
        assert!(t.spline(DVec3::new(6.4, 3.0, 3.0)).is_some());
    }

    /// Across the midplane between two nodes, where the nearest node and so the 27 nodes
    /// change, the spline and its derivative are continuous; the trilinear
    /// interpolant's derivative jumps at the cell face.
    #[test]
    fn spline_is_c1_where_its_nodes_change() {
        let t = noisy(8);
        // Central differences on either side of the plane, not reaching across it. With
        // node values in [-1/2, 1/2] the spline's second derivative is at most 2 per
        // component, so the two derivatives differ by at most about 2 * 2e * 2 = 8e-4
        // (per component), plus f32 round-off of ~1e-7 / 2e = 5e-4: 2e-3 bounds them.
        // The trilinear interpolant's derivative jumps by the nodes' differences, O(0.1).
        let e = 1e-4;
        let d = |f: &dyn Fn(DVec3) -> DVec3, p: DVec3| {
            (f(p + DVec3::X * e) - f(p - DVec3::X * e)) / (2.0 * e)
        };
        let spline = |p: DVec3| t.spline(p).unwrap();
        let trilinear = |p: DVec3| t.interpolate(p).unwrap().0;
        let mut kink = 0.0f64;
        for (y, z) in [(3.2, 3.7), (2.6, 4.1), (4.45, 3.0)] {
            // Midplane x = 3.5 for the spline, cell face x = 4 for the trilinear.
            let (lo, hi) = (
                DVec3::new(3.5 - 1.5 * e, y, z),
                DVec3::new(3.5 + 1.5 * e, y, z),
            );
            let mid = DVec3::new(3.5, y, z);
            assert!((spline(mid - DVec3::X * 1e-9) - spline(mid)).length() < 1e-5);
            assert!(
                (d(&spline, lo) - d(&spline, hi)).abs().max_element() < 2e-3,
                "derivative jumps at ({y}, {z}): {} against {}",
                d(&spline, lo),
                d(&spline, hi)
            );
            let (lo, hi) = (
                DVec3::new(4.0 - 1.5 * e, y, z),
                DVec3::new(4.0 + 1.5 * e, y, z),
            );
            kink = kink.max((d(&trilinear, lo) - d(&trilinear, hi)).length());
        }
        assert!(kink > 0.1, "the trilinear derivative should jump: {kink}");
    }

    /// A node without a value among the spline's 27 but not at a corner of the cell:
    /// the trilinear interpolant is used.
    #[test]
    fn trilinear_u_is_exact_for_linear_u_and_the_node_value_at_a_node() {
        let u = |x: f64, y: f64, z: f64| 0.3 + 0.02 * x - 0.05 * y + 0.01 * z;
        let tile = Tile::from_u(&grid(12, u), [0; 3], [12; 3], None);
        for p in [
            DVec3::new(4.0, 5.0, 6.0),
            DVec3::new(4.3, 5.9, 6.45),
            DVec3::new(7.99, 2.01, 3.5),
        ] {
            let (v, g) = tile.u_trilinear(p).unwrap();
            // The tile keeps u in f32.
            assert!((v - u(p.x, p.y, p.z)).abs() < 1e-7, "{p}: {v}");
            assert!(
                (g - DVec3::new(0.02, -0.05, 0.01)).length() < 1e-7,
                "{p}: {g}"
            );
        }
        let n = DVec3::new(4.0, 5.0, 6.0);
        let node = tile.u_trilinear(n).unwrap().0;
        assert_eq!(node.to_bits(), f64::from(u(n.x, n.y, n.z) as f32).to_bits());
        assert!(tile.u_trilinear(DVec3::new(11.5, 1.0, 1.0)).is_none());
    }

    #[test]
    fn a_missing_spline_node_falls_back_to_trilinear() {
        let mut t = noisy(8);
        let p = DVec3::new(3.4, 3.3, 3.2); // nearest node (3, 3, 3), cell (3, 3, 3)
        assert!(t.spline(p).is_some());
        t.nodes[(2 * 8 + 2) * 8 + 2].w = f32::NAN; // node (2, 2, 2): spline only
        assert!(t.spline(p).is_none());
        let want = t.interpolate(p).unwrap().0.normalize();
        assert!((t.direction(p).unwrap() - want).length() < 1e-12);
    }

    /// u linear in x, y and z and positive (no boundary, no exterior): every node
    /// direction is the normalized gradient.
    #[test]
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn linear_u_has_its_exact_direction() {
        let n = 8usize;
        let u = grid(n, |x, y, z| 0.5 * x - 0.25 * y + 0.125 * z);
        let t = Tile::from_u(&u, [0, 0, 0], [n; 3], None);
        let p = DVec3::new(3.3, 2.7, 5.9);
        assert!(t.holds(p));
        let (g, v) = t.interpolate(p).unwrap();
        let want = DVec3::new(0.5, -0.25, 0.125).normalize();
        assert!((g - want).length() < 1e-6);
        let exact = 0.5 * p.x - 0.25 * p.y + 0.125 * p.z;
        assert!((v - exact).abs() < 1e-5);
        assert!((t.direction(p).unwrap() - want).length() < 1e-6);
        assert!(
            !t.holds(DVec3::new(7.5, 1.0, 1.0)),
            "cell past the last node"
        );
    }

    /// Down a thin arm u falls to 1e-22 and less: the direction must survive.
    #[test]
    fn tiny_gradients_keep_their_direction() {
        let n = 6usize;
        let u = grid(n, |x, y, _| 1e-30 * (-x).exp() * (1.0 + 0.1 * y));
        let t = Tile::from_u(&u, [0, 0, 0], [n; 3], None);
        let d = t.direction(DVec3::new(2.5, 2.5, 2.5)).unwrap();
        assert!(d.x < -0.9 && d.y > 0.0, "{d}");
    }

    #[test]
    fn missing_corners_and_flat_regions_give_no_direction() {
        let n = 6usize;
        let mut u = grid(n, |_, _, _| 0.25);
        let o = u.offset(3 + U_MARGIN, 3 + U_MARGIN, 3 + U_MARGIN);
        u.data[o] = f64::NAN; // node (3, 3, 3)
        let t = Tile::from_u(&u, [0, 0, 0], [n; 3], None);
        assert_eq!(
            t.direction(DVec3::new(2.5, 2.5, 2.5)),
            Err(NoDirection::Outside)
        );
        assert_eq!(
            t.direction(DVec3::new(0.5, 0.5, 0.5)),
            Err(NoDirection::Flat)
        );
    }

    /// A flat sheet (u = 0) with one node of positive u two voxels away: the escape goes
    /// to it; with nothing higher around, there is none.
    #[test]
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn escapes_go_to_the_nearest_higher_node() {
        let n = 10usize;
        let mut u = grid(n, |_, _, _| 0.0);
        let o = u.offset(5 + U_MARGIN, 4 + U_MARGIN, 7 + U_MARGIN); // node (x 7, y 4, z 5)
        u.data[o] = 1e-20;
        let t = Tile::from_u(&u, [0, 0, 0], [n; 3], None);
        let q = t.escape(DVec3::new(5.2, 4.5, 5.0), 3).unwrap();
        assert_eq!(q, DVec3::new(7.0, 4.0, 5.0));
        assert!(t.escape(DVec3::new(5.2, 4.5, 5.0), 0).is_none());
        let flat = Tile::from_u(&grid(n, |_, _, _| 0.0), [0; 3], [n; 3], None);
        assert!(flat.escape(DVec3::new(5.2, 4.5, 5.0), 3).is_none());
    }
}
