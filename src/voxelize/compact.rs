//! The whole-grid cut at a few bytes a solid voxel, for grids too large for
//! [`super::repair`] (24 bytes a voxel of the grid): the same growth through simple
//! points from the deepest voxel outward within the solid, deepest first, without any
//! closing, so that a handle loses a one-voxel-thick sheet where it is thinnest however
//! wide its tunnel is.
//!
//! What it holds: the solid and the growing set as bit maps of the grid (a bit a voxel
//! each, and a 32-bit count of the solid's voxels before every word, for an index into
//! what follows), and for each solid voxel only its depth (4 bytes) and growth state
//! (1 byte); the queue holds at most one entry (8 bytes) a solid voxel. The depth is
//! the exact squared distance transform ([`super::closing::edt_sq`]'s), computed slice
//! by slice and then along z a plane at a time, on the solid voxels alone; for a mesh,
//! the distance to the mesh where it is less ([`super::windows::mesh_band`], a slab of
//! slices at a time). So the peak is [`BYTES_PER_GRID_VOXEL`] a voxel of the grid plus
//! [`BYTES_PER_SOLID_VOXEL`] a solid voxel: about 240 MiB for 7pbl at 0.25 Angstrom
//! (118 Mi voxels, 16 Mi solid), where the grid-wide repair would need 2.8 GiB.
//!
//! Only the cut: the fill grows through the background, which is most of a molecule's
//! grid. Ties of depth are broken by the linear voxel index and the growth is one
//! sequential pass, so the result does not depend on threads or on where the grid is
//! stored; on the same solid it is exactly [`super::repair`]'s cut.
// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

use std::collections::{BTreeMap, BinaryHeap};

use super::closing::dt1d;
use super::repair::{Flat, Region, ALL, FACES};
use super::simple::is_simple;
use super::windows::{depth_of, mesh_band};
use crate::grid::{BlockStore, GridSpec};
use crate::input::TriMesh;
use crate::math::Idx3;
use crate::progress::Progress;

/// Bytes a voxel of the grid takes at the peak (two bit maps and the rank words).
pub const BYTES_PER_GRID_VOXEL: f64 = 0.3125;

/// Bytes a solid voxel takes at the peak (depth, state, the queue at its largest).
pub const BYTES_PER_SOLID_VOXEL: u64 = 13;

/// Slices of the grid whose distances to the mesh are measured at once.
const MESH_SLAB: usize = 8;

/// Queued.
const QUEUED: u8 = 2;
/// Popped while not simple: looked at again when its neighbourhood changes.
const WAITING: u8 = 4;

/// A bit map of the grid with the count of set bits before each word.
struct Bits {
    words: Vec<u64>,
    rank: Vec<u32>,
}

impl Bits {
    fn new(voxels: usize) -> Self {
        Self {
            words: vec![0; voxels.div_ceil(64)],
            rank: Vec::new(),
        }
    }

    fn get(&self, i: usize) -> bool {
        self.words[i >> 6] >> (i & 63) & 1 == 1
    }

    fn set(&mut self, i: usize) {
        self.words[i >> 6] |= 1 << (i & 63);
    }

    /// Count the set bits before each word; returns the total.
    fn index(&mut self) -> usize {
        let mut n = 0u32;
        self.rank = self
            .words
            .iter()
            .map(|w| {
                let r = n;
                n += w.count_ones();
                r
            })
            .collect();
        n as usize
    }

    /// Set bits before `i` (the index of `i` among them when it is set).
    fn rank(&self, i: usize) -> usize {
        let w = i >> 6;
        self.rank[w] as usize + (self.words[w] & ((1u64 << (i & 63)) - 1)).count_ones() as usize
    }
}

/// The memory the cut of a grid of `voxels` voxels, `solid` of them solid, holds.
#[must_use]
pub fn bytes_needed(voxels: u64, solid: u64) -> u64 {
    (voxels as f64 * BYTES_PER_GRID_VOXEL) as u64 + solid * BYTES_PER_SOLID_VOXEL
}

/// What the cut did.
#[derive(Debug, Default)]
pub struct Outcome {
    /// Voxels taken out of the solid.
    pub removed: u64,
    /// The connected regions of removed voxels (26-connected), largest first.
    pub regions: Vec<Region>,
}

/// Cut the solid `{v == 1}` of `store` (one piece, no cavity) to a genus-0 piece in
/// place, from its deepest voxel. `surface`: the input mesh and the grid, when the
/// input is one. The caller checks the topology afterwards.
pub fn cut(
    store: &dyn BlockStore<u8>,
    surface: Option<(&TriMesh, &GridSpec)>,
    progress: &dyn Progress,
) -> Result<Outcome, crate::Error> {
    let spec = store.spec().clone();
    let n = spec.shape.map(|c| c as usize);
    let total = n.iter().product::<usize>();
    if total as u64 >= u64::from(u32::MAX) {
        return Err(super::VoxelizeError::Options(format!(
            "the topology repair takes grids of fewer than {} voxels; this one has {total}: use a coarser grid, or --topology strict / --allow-genus",
            u32::MAX
        ))
        .into());
    }
    let mut solid = Bits::new(total);
    for b in spec.block_indices() {
        let st = spec.block_start(b).map(|c| c as usize);
        let sh = spec.block_shape(b).map(|c| c as usize);
        let data = store.read_block(b)?;
        let mut k = 0;
        for z in st[0]..st[0] + sh[0] {
            for y in st[1]..st[1] + sh[1] {
                let row = (z * n[1] + y) * n[2];
                for x in st[2]..st[2] + sh[2] {
                    if data[k] == 1 {
                        solid.set(row + x);
                    }
                    k += 1;
                }
            }
        }
    }
    let count = solid.index();
    let depth = depths(&solid, count, n, surface);
    let flat = Flat::new(n);
    let seed = (0..total)
        .filter(|&i| solid.get(i))
        .max_by_key(|&i| (depth[solid.rank(i)], std::cmp::Reverse(i)))
        .ok_or_else(|| {
            crate::Error::from(super::VoxelizeError::Options(
                "no solid voxel to repair".into(),
            ))
        })?;
    progress.start("voxelize: repair: compact cut", count as u64);
    let kept = grow(&flat, &solid, &depth, count, seed, progress)?;
    progress.finish();
    drop(depth);

    // Removed: solid and not kept, in C order.
    let mut removed: Vec<u32> = Vec::new();
    for (w, (&s, &k)) in solid.words.iter().zip(&kept.words).enumerate() {
        let mut bits = s & !k;
        while bits != 0 {
            removed.push((w * 64 + bits.trailing_zeros() as usize) as u32);
            bits &= bits - 1;
        }
    }
    drop((solid, kept));
    let mut regions = regions_of(&flat, &removed);
    regions.sort_by_key(|r| std::cmp::Reverse(r.voxels));

    // Write back the blocks that changed.
    let mut by_block: BTreeMap<Idx3, Vec<usize>> = BTreeMap::new();
    for &i in &removed {
        let v = flat.zyx(i as usize);
        let b = [0, 1, 2].map(|a| v[a] as u64 / spec.chunk[a]);
        let st = spec.block_start(b);
        let sh = spec.block_shape(b);
        let l = [0, 1, 2].map(|a| v[a] as u64 - st[a]);
        by_block
            .entry(b)
            .or_default()
            .push(((l[0] * sh[1] + l[1]) * sh[2] + l[2]) as usize);
    }
    for (b, local) in by_block {
        let mut data = store.read_block(b)?;
        for k in local {
            data[k] = 0;
        }
        store.write_block(b, &data)?;
    }
    Ok(Outcome {
        removed: removed.len() as u64,
        regions,
    })
}

/// Each solid voxel's depth (in C order of the solid voxels): the squared distance to
/// the nearest background voxel (a voxel outside the grid is none), or to the mesh where
/// that is less, as [`super::windows::depths`] makes it.
fn depths(
    solid: &Bits,
    count: usize,
    n: [usize; 3],
    surface: Option<(&TriMesh, &GridSpec)>,
) -> Vec<u32> {
    const INF: f64 = f64::INFINITY;
    let [nz, ny, nx] = n;
    let m = nx.max(ny).max(nz);
    let (mut f, mut d) = (vec![0.0; m], vec![0.0; m]);
    let (mut v, mut zs) = (vec![0usize; m], vec![0.0; m + 1]);
    let mut line = |g: &mut [f64], start: usize, stride: usize, len: usize| {
        for (q, fq) in f[..len].iter_mut().enumerate() {
            *fq = g[start + q * stride];
        }
        dt1d(&f[..len], &mut d[..len], &mut v, &mut zs);
        for (q, dq) in d[..len].iter().enumerate() {
            g[start + q * stride] = *dq;
        }
    };
    let to_u32 = |x: f64| if x.is_finite() { x as u32 } else { u32::MAX };
    let from_u32 = |x: u32| if x == u32::MAX { INF } else { f64::from(x) };
    // Each slice (x, then y), kept for the solid voxels.
    let mut e = vec![0u32; count];
    let mut plane = vec![0.0f64; ny * nx];
    for z in 0..nz {
        let base = z * ny * nx;
        for (k, p) in plane.iter_mut().enumerate() {
            *p = if solid.get(base + k) { INF } else { 0.0 };
        }
        for y in 0..ny {
            line(&mut plane, y * nx, 1, nx);
        }
        for x in 0..nx {
            line(&mut plane, x, nx, ny);
        }
        let mut r = solid.rank(base);
        for (k, &p) in plane.iter().enumerate() {
            if solid.get(base + k) {
                e[r] = to_u32(p);
                r += 1;
            }
        }
    }
    // Along z, a plane of fixed y at a time.
    let mut plane = vec![0.0f64; nz * nx];
    for y in 0..ny {
        for z in 0..nz {
            let row = (z * ny + y) * nx;
            let mut r = solid.rank(row);
            for x in 0..nx {
                plane[z * nx + x] = if solid.get(row + x) {
                    r += 1;
                    from_u32(e[r - 1])
                } else {
                    0.0
                };
            }
        }
        for x in 0..nx {
            line(&mut plane, x, nx, nz);
        }
        for z in 0..nz {
            let row = (z * ny + y) * nx;
            let mut r = solid.rank(row);
            for x in 0..nx {
                if solid.get(row + x) {
                    e[r] = to_u32(plane[z * nx + x]);
                    r += 1;
                }
            }
        }
    }
    // Squared distances to depths, with the mesh's distance where it is less.
    let mut z0 = 0;
    while z0 < nz {
        let h = MESH_SLAB.min(nz - z0);
        let near = surface.map_or_else(Vec::new, |(mesh, grid)| {
            mesh_band(mesh, grid, [z0 as u64, 0, 0], [h, ny, nx])
        });
        let base = z0 * ny * nx;
        let mut r = solid.rank(base);
        for k in 0..h * ny * nx {
            if solid.get(base + k) {
                e[r] = depth_of(e[r], near.get(k).copied().unwrap_or(f32::INFINITY));
                r += 1;
            }
        }
        z0 += h;
    }
    e
}

/// Grow the kept set from `seed` through the solid, adding a voxel only when it is
/// simple for the set (6-connected, background 26-connected): highest depth first, then
/// lowest index. The same growth as [`super::repair`]'s `grow` for an object.
fn grow(
    flat: &Flat,
    solid: &Bits,
    depth: &[u32],
    count: usize,
    seed: usize,
    progress: &dyn Progress,
) -> Result<Bits, crate::Error> {
    let mut kept = Bits::new(solid.words.len() * 64);
    let mut state = vec![0u8; count];
    let mut heap: BinaryHeap<u64> = BinaryHeap::new();
    // Highest depth, then lowest index, first.
    let key = |d: u32, i: usize| u64::from(d) << 32 | u64::from(u32::MAX - i as u32);
    kept.set(seed);
    for j in flat.neighbours(seed, &FACES) {
        if solid.get(j) {
            let r = solid.rank(j);
            state[r] = QUEUED;
            heap.push(key(depth[r], j));
        }
    }
    let mut joined = 0u64;
    while let Some(k) = heap.pop() {
        let i = (u32::MAX - (k & 0xffff_ffff) as u32) as usize;
        let r = solid.rank(i);
        state[r] &= !QUEUED;
        if !is_simple(flat.mask(i, false, |j| kept.get(j))) {
            state[r] |= WAITING;
            continue;
        }
        state[r] = 0;
        kept.set(i);
        joined += 1;
        if joined.is_multiple_of(1 << 20) {
            progress.advance(1 << 20);
            crate::progress::check_interrupt(progress)?;
        }
        for j in flat.neighbours(i, &ALL) {
            if kept.get(j) || !solid.get(j) {
                continue;
            }
            let rj = solid.rank(j);
            let s = state[rj];
            if s & QUEUED != 0 {
                continue;
            }
            // A new candidate must touch the set through a face; a waiting one may have
            // become simple whichever neighbour joined.
            let touches = s & WAITING != 0
                || FACES
                    .iter()
                    .any(|&b| (i as isize - flat.offset(b)) as usize == j);
            if touches {
                state[rj] = QUEUED;
                heap.push(key(depth[rj], j));
            }
        }
    }
    Ok(kept)
}

/// The 26-connected regions of the voxels `changed` (sorted linear indices), all
/// removed, in C order of their first voxel.
fn regions_of(flat: &Flat, changed: &[u32]) -> Vec<Region> {
    let mut seen = vec![false; changed.len()];
    let mut stack = Vec::new();
    let mut regions = Vec::new();
    for s in 0..changed.len() {
        if seen[s] {
            continue;
        }
        seen[s] = true;
        stack.push(s);
        let mut voxels = 0u64;
        while let Some(k) = stack.pop() {
            voxels += 1;
            for j in flat.neighbours(changed[k] as usize, &ALL) {
                if let Ok(t) = changed.binary_search(&(j as u32)) {
                    if !seen[t] {
                        seen[t] = true;
                        stack.push(t);
                    }
                }
            }
        }
        regions.push(Region {
            added: false,
            voxels,
            voxel: flat.zyx(changed[s] as usize).map(|c| c as u64),
        });
    }
    regions
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::MmapStore;
    use crate::progress::Silent;

    fn store_with(
        dir: &tempfile::TempDir,
        name: &str,
        shape: [u64; 3],
        solid: &(impl Fn(u64, u64, u64) -> bool + Sync + Send),
    ) -> MmapStore<u8> {
        let spec = GridSpec {
            shape,
            origin: [0.0; 3],
            spacing: 1.0,
            chunk: [4, 4, 4],
            unit: None,
        };
        let s = MmapStore::<u8>::create(&dir.path().join(name), spec).unwrap();
        crate::grid::fill_with(&s, 1, |[z, y, x]| u8::from(solid(z, y, x))).unwrap();
        s
    }

    fn all(s: &MmapStore<u8>) -> Vec<u8> {
        let n = s.spec().shape.map(|c| c as usize);
        s.read_region([0, 0, 0], n, 0).unwrap().data
    }

    /// Two square rings, 2 voxels thick, fused at a corner and crossing block edges
    /// (genus 2; cutting each tube is far smaller than plugging its hole): the compact
    /// cut removes the same voxels as the whole-grid repair's cut, and leaves one
    /// genus-0 piece.
    #[test]
    fn the_same_cut_as_the_whole_grid_repair() {
        let ring = |z: u64, y: u64, x: u64, o: u64| {
            (3..5).contains(&z)
                && (o..o + 12).contains(&y)
                && (o..o + 12).contains(&x)
                && !((o + 2..o + 10).contains(&y) && (o + 2..o + 10).contains(&x))
        };
        let shape = |z: u64, y: u64, x: u64| {
            ring(z, y, x, 1) || ring(z, y, x, 11) || z == 4 && y == 12 && x == 12
        };
        let dir = tempfile::tempdir().unwrap();
        let a = store_with(&dir, "a", [9, 25, 26], &shape);
        let b = store_with(&dir, "b", [9, 25, 26], &shape);
        assert_eq!(
            super::super::euler::euler_characteristic(&a, 1).unwrap(),
            -1
        );
        let whole = super::super::repair::repair(&a, None).unwrap();
        assert_eq!(whole.method, "cut");
        let o = cut(&b, None, &Silent).unwrap();
        assert_eq!(o.removed, whole.removed);
        assert!(o.removed > 0 && o.removed < 20, "{}", o.removed);
        assert_eq!(o.regions, whole.regions);
        assert!(all(&a) == all(&b), "the compact cut differs");
        assert_eq!(super::super::euler::euler_characteristic(&b, 1).unwrap(), 1);
    }
}
