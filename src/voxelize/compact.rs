//! The whole-grid cut of the topology repair, out of core, for grids too large for
//! [`super::repair`] (24 bytes a voxel of the grid): the same growth through simple
//! points from the deepest voxel outward within the solid, deepest first, without any
//! closing, so that a handle loses a one-voxel-thick sheet where it is thinnest however
//! wide its tunnel is.
//!
//! What it holds: each voxel of the grid is one 32-bit record (solid, kept, queued and
//! waiting flags, and the depth), stored in bricks of 16^3 voxels; a brick without a
//! solid voxel is not stored at all. The bricks live in memory when they all fit in
//! what `--mem` leaves, else in a scratch file behind a cache of bricks (clock
//! replacement) that takes what is left. The growth front moves through the solid by
//! depth, so the bricks it touches at once are those of a shell: its area times a
//! brick's edge, a few tens of MiB for a ball of 10^9 voxels. The depth is the exact
//! squared distance transform ([`super::closing::edt_sq`]'s), computed slice by slice
//! (a layer of 16 slices at a time) and then along z a column of bricks at a time; for
//! a mesh, the distance to the mesh where it is less ([`super::windows::mesh_band`], a
//! layer at a time). Besides the cache: [`BYTES_PER_SLICE_VOXEL`] a voxel of one slice
//! (the layers), 8 bytes a brick of the grid (where each is), and the queue, 8 bytes a
//! voxel of the growth front.
//!
//! Only the cut: the fill grows through the background, which is most of a molecule's
//! grid. Ties of depth are broken by the linear voxel index and the growth is one
//! sequential pass, so the result depends neither on threads, nor on where the grid is
//! stored, nor on the cache's size; on the same solid it is exactly
//! [`super::repair`]'s cut.
// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

use std::collections::{BTreeMap, BinaryHeap};
use std::path::Path;

use super::bricks::{Bricks, BRICK, BRICK_BYTES, EDGE, MIN_CACHE, SHIFT};
use super::closing::dt1d;
use super::repair::{Flat, Region, ALL, FACES};
use super::simple::is_simple;
use super::windows::{depth_of, mesh_band};
use crate::grid::{human, BlockStore, GridError, GridSpec};
use crate::input::TriMesh;
use crate::math::Idx3;
use crate::progress::Progress;

/// A record's flags: a solid voxel; one of the growing set; in the queue; popped
/// while not simple (looked at again when its neighbourhood changes).
const SOLID: u32 = 1 << 31;
const KEPT: u32 = 1 << 30;
const QUEUED: u32 = 1 << 29;
const WAITING: u32 = 1 << 28;
/// A record's depth bits. Depths are below 2^28: the deepest voxel of a grid of fewer
/// than 2^32 voxels is at most 813 voxels deep, 42 Mi in the depths' units.
const DEPTH: u32 = WAITING - 1;
/// Bytes a voxel of one slice of the grid takes in the depth passes: a layer of 16
/// slices of labels (1 byte) and records (4 bytes), one slice of the distance
/// transform (8 bytes), or a layer of distances to the mesh (4 bytes).
pub const BYTES_PER_SLICE_VOXEL: u64 = (EDGE as u64) * 5 + 8;

/// Bytes a voxel of one column of bricks (`EDGE` by `EDGE` lines along z) takes in the
/// z pass: its record (4 bytes) and its distance (8 bytes).
const BYTES_PER_COLUMN_VOXEL: u64 = 12;

/// The least memory the cut of a grid `spec` holds: the depth passes, where each brick
/// is, and the smallest cache.
#[must_use]
pub fn bytes_needed(spec: &GridSpec) -> u64 {
    let [nz, ny, nx] = spec.shape;
    let bricks = [nz, ny, nx]
        .map(|c| c.div_ceil(EDGE as u64))
        .iter()
        .product::<u64>();
    let column = nz * (EDGE * EDGE) as u64 * BYTES_PER_COLUMN_VOXEL;
    (ny * nx * BYTES_PER_SLICE_VOXEL).max(column) + bricks * 8 + MIN_CACHE as u64 * BRICK_BYTES
}

/// What the cut did.
#[derive(Debug, Default)]
pub struct Outcome {
    /// Voxels taken out of the solid.
    pub removed: u64,
    /// The connected regions of removed voxels (26-connected), largest first.
    pub regions: Vec<Region>,
    /// Whether the bricks lived in a scratch file (else all in memory).
    pub spilled: bool,
    /// Bricks read from the scratch file by the growth (cache misses).
    pub brick_reads: u64,
}

/// Cut the solid `{v == 1}` of `store` (one piece, no cavity) to a genus-0 piece in
/// place, from its deepest voxel, holding at most about `room` bytes (at least
/// [`bytes_needed`]); a scratch file goes in `scratch` if the bricks do not fit.
/// `surface`: the input mesh and the grid, when the input is one. The caller checks
/// the topology afterwards.
pub fn cut(
    store: &dyn BlockStore<u8>,
    surface: Option<(&TriMesh, &GridSpec)>,
    scratch: &Path,
    room: u64,
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
    let need = bytes_needed(&spec);
    let slices = (n[1] * n[2]) as u64 * BYTES_PER_SLICE_VOXEL;
    let column = (n[0] * EDGE * EDGE) as u64 * BYTES_PER_COLUMN_VOXEL;
    let tables = need - slices.max(column) - MIN_CACHE as u64 * BRICK_BYTES;
    // A quarter of what is left for the queue (it holds the growth front), the rest for
    // the bricks.
    // The first pass's slices and the z pass's brick columns on as many threads as
    // what the budget leaves holds their work arrays (one of each is in `need`): a
    // slice's plane of f64, a column's records (u32) and its f64 copy.
    let plane = (n[1] * n[2]) as u64 * 8;
    let per_worker = plane.max(column).max(1);
    let workers =
        rayon::current_num_threads().min(1 + (room.saturating_sub(need) / 2 / per_worker) as usize);
    let extra = (workers as u64 - 1) * per_worker;
    let left = room.saturating_sub(tables + extra);
    let queue_room = left / 4;
    let brick_room = left - queue_room;
    let all_bricks = n.map(|c| c.div_ceil(EDGE) as u64).iter().product::<u64>();
    let in_memory = all_bricks * BRICK_BYTES + slices <= brick_room;
    let mut bricks = Bricks::new(n, (!in_memory).then_some(scratch))?;
    let count = records(store, &mut bricks, workers)?;
    let seed = depths(&mut bricks, surface, workers)?;
    let Some(seed) = seed else {
        return Err(super::VoxelizeError::Options("no solid voxel to repair".into()).into());
    };
    let spilled = bricks.spilled();
    bricks.open_cache((brick_room / BRICK_BYTES) as usize);
    progress.start("voxelize: repair: compact cut", count);
    let grown = grow(&mut bricks, seed, (queue_room / 8).max(1 << 16), progress);
    progress.finish();
    grown?;
    bricks.flush()?;

    let removed = removed(&bricks)?;
    let brick_reads = bricks.reads;
    // Removes the scratch file.
    drop(bricks);
    let flat = Flat::new(n);
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
        spilled,
        brick_reads,
    })
}

/// The voxels solid and not kept, as sorted linear indices (the cache flushed first).
fn removed(bricks: &Bricks) -> Result<Vec<u32>, GridError> {
    let [_, ny, nx] = bricks.n;
    let mut removed: Vec<u32> = Vec::new();
    let mut buf = vec![0u32; BRICK];
    for bz in 0..bricks.nb[0] {
        for (b, p) in bricks.layer(bz) {
            bricks.read_raw(p, &mut buf)?;
            for (l, &r) in buf.iter().enumerate() {
                if r & SOLID != 0 && r & KEPT == 0 {
                    let [z, y, x] = Bricks::voxel(b, l);
                    removed.push(((z * ny + y) * nx + x) as u32);
                }
            }
        }
    }
    removed.sort_unstable();
    Ok(removed)
}

/// Squared distances as stored between the passes (`u32::MAX`: none found yet).
fn to_u32(x: f64) -> u32 {
    if x.is_finite() {
        x as u32
    } else {
        u32::MAX
    }
}

fn from_u32(x: u32) -> f64 {
    if x == u32::MAX {
        f64::INFINITY
    } else {
        f64::from(x)
    }
}

/// The work arrays of the one-dimensional distance transform of a line of up to `m`
/// values.
struct Lines {
    f: Vec<f64>,
    d: Vec<f64>,
    v: Vec<usize>,
    zs: Vec<f64>,
}

impl Lines {
    fn new(m: usize) -> Self {
        Self {
            f: vec![0.0; m],
            d: vec![0.0; m],
            v: vec![0; m],
            zs: vec![0.0; m + 1],
        }
    }
}

/// The work arrays of one slice's distance transform: the slice, and a line's.
struct SliceWork {
    plane: Vec<f64>,
    lines: Lines,
}

impl SliceWork {
    fn new(ny: usize, nx: usize) -> Self {
        Self {
            plane: vec![0.0; ny * nx],
            lines: Lines::new(nx.max(ny)),
        }
    }

    /// The squared distance transform (along x, then y) of the slice of labels `lab`
    /// into `out`: each solid voxel's (rounded to its record) and 0 elsewhere. Returns
    /// the solid voxels.
    fn slice(&mut self, lab: &[u8], out: &mut [u32], ny: usize, nx: usize) -> u64 {
        let Self { plane, lines } = self;
        for (p, &l) in plane.iter_mut().zip(lab) {
            *p = if l == 1 { f64::INFINITY } else { 0.0 };
        }
        for y in 0..ny {
            line(plane, y * nx, 1, nx, lines);
        }
        for x in 0..nx {
            line(plane, x, nx, ny, lines);
        }
        let mut count = 0;
        for ((r, &p), &l) in out.iter_mut().zip(plane.iter()).zip(lab) {
            *r = if l == 1 { to_u32(p) } else { 0 };
            count += u64::from(l == 1);
        }
        count
    }
}

/// The first pass: each slice's squared distance transform (along x, then y) into the
/// records of the solid voxels (0 for the others), a layer of bricks at a time, the
/// slices of a layer on `workers` threads (each with its own [`SliceWork`]); returns
/// the solid voxels. A solid voxel's distance is at least 1, so a record is non-zero
/// exactly at the solid.
fn records(
    store: &dyn BlockStore<u8>,
    bricks: &mut Bricks,
    workers: usize,
) -> Result<u64, crate::Error> {
    use rayon::prelude::*;
    let [nz, ny, nx] = bricks.n;
    let nb = bricks.nb;
    let slice = ny * nx;
    let mut work: Vec<SliceWork> = (0..workers.clamp(1, EDGE))
        .map(|_| SliceWork::new(ny, nx))
        .collect();
    let mut layer = vec![0u32; EDGE * slice];
    let mut rec = vec![0u32; BRICK];
    let mut count = 0u64;
    for bz in 0..nb[0] {
        let z0 = bz * EDGE;
        let h = EDGE.min(nz - z0);
        let labels = store.read_region([z0 as i64, 0, 0], [h, ny, nx], 0)?.data;
        // Each worker takes a run of whole slices.
        let per = h.div_ceil(work.len());
        count += layer[..h * slice]
            .par_chunks_mut(per * slice)
            .zip(labels.par_chunks(per * slice))
            .zip(work.par_iter_mut())
            .with_max_len(1)
            .map(|((out, lab), w)| {
                out.chunks_mut(slice)
                    .zip(lab.chunks(slice))
                    .map(|(o, l)| w.slice(l, o, ny, nx))
                    .sum::<u64>()
            })
            .sum::<u64>();
        for by in 0..nb[1] {
            for bx in 0..nb[2] {
                rec.fill(0);
                let mut any = false;
                for lz in 0..h {
                    for ly in 0..EDGE.min(ny - by * EDGE) {
                        let row = (lz * ny + by * EDGE + ly) * nx + bx * EDGE;
                        let w = EDGE.min(nx - bx * EDGE);
                        let dst = &mut rec[(lz << (2 * SHIFT)) | (ly << SHIFT)..][..w];
                        dst.copy_from_slice(&layer[row..row + w]);
                        any |= dst.iter().any(|&r| r != 0);
                    }
                }
                if any {
                    bricks.append([bz, by, bx], &rec)?;
                }
            }
        }
    }
    Ok(count)
}

/// One line of `g` (`len` values from `start`, `stride` apart) through the
/// one-dimensional squared distance transform, with its work arrays.
fn line(g: &mut [f64], start: usize, stride: usize, len: usize, Lines { f, d, v, zs }: &mut Lines) {
    for (q, fq) in f[..len].iter_mut().enumerate() {
        *fq = g[start + q * stride];
    }
    dt1d(&f[..len], &mut d[..len], v, zs);
    for (q, dq) in d[..len].iter().enumerate() {
        g[start + q * stride] = *dq;
    }
}

/// The distance transform along z of one column of bricks (`[by, bx]`, its stored
/// bricks with their layers), in place in their records.
fn z_pass(column: &mut [(usize, u32, Vec<u32>)], [by, bx]: [usize; 2], [nz, ny, nx]: [usize; 3]) {
    if column.is_empty() {
        return;
    }
    let mut lines = Lines::new(nz);
    let mut col = vec![0.0f64; nz * EDGE * EDGE];
    for (bz, _, rec) in column.iter() {
        for (l, &r) in rec.iter().enumerate() {
            let z = bz * EDGE + (l >> (2 * SHIFT));
            if z < nz && r != 0 {
                col[z * EDGE * EDGE + (l & (EDGE * EDGE - 1))] = from_u32(r);
            }
        }
    }
    for ly in 0..EDGE.min(ny - by * EDGE) {
        for lx in 0..EDGE.min(nx - bx * EDGE) {
            line(&mut col, (ly << SHIFT) | lx, EDGE * EDGE, nz, &mut lines);
        }
    }
    for (bz, _, rec) in column.iter_mut() {
        for (l, r) in rec.iter_mut().enumerate() {
            let z = *bz * EDGE + (l >> (2 * SHIFT));
            if z < nz && *r != 0 {
                *r = to_u32(col[z * EDGE * EDGE + (l & (EDGE * EDGE - 1))]);
            }
        }
    }
}

/// The passes after the first: the distance transform along z, a column of bricks at a
/// time, and then each solid voxel's depth (the squared distance to the nearest
/// background voxel, a voxel outside the grid being none, or to the mesh where that is
/// less, as [`super::windows::depths`] makes it) packed with its SOLID flag, a layer
/// at a time. Returns the deepest voxel (the lowest index among the deepest).
fn depths(
    bricks: &mut Bricks,
    surface: Option<(&TriMesh, &GridSpec)>,
    workers: usize,
) -> Result<Option<usize>, crate::Error> {
    use rayon::prelude::*;
    let [nz, ny, nx] = bricks.n;
    let nb = bricks.nb;
    let columns: Vec<[usize; 2]> = (0..nb[1])
        .flat_map(|by| (0..nb[2]).map(move |bx| [by, bx]))
        .collect();
    // `workers` columns at a time: their bricks read, transformed on the threads,
    // written back.
    for group in columns.chunks(workers.max(1)) {
        let mut work = Vec::with_capacity(group.len());
        for &[by, bx] in group {
            let mut column = Vec::new();
            for bz in 0..nb[0] {
                if let Some(p) = bricks.stored([bz, by, bx]) {
                    let mut rec = vec![0u32; BRICK];
                    bricks.read_raw(p, &mut rec)?;
                    column.push((bz, p, rec));
                }
            }
            work.push(([by, bx], column));
        }
        work.par_iter_mut()
            .with_max_len(1)
            .for_each(|(b, column)| z_pass(column, *b, [nz, ny, nx]));
        for (_, column) in &work {
            for (_, p, rec) in column {
                bricks.write_raw(*p, rec)?;
            }
        }
    }
    // Depths, with the mesh's distance where it is less; the deepest voxel.
    let mut best: Option<(u32, usize)> = None;
    for bz in 0..nb[0] {
        let z0 = bz * EDGE;
        let h = EDGE.min(nz - z0);
        let near = surface.map_or_else(Vec::new, |(mesh, grid)| {
            mesh_band(mesh, grid, [z0 as u64, 0, 0], [h, ny, nx])
        });
        let mut rec = vec![0u32; BRICK];
        let layer: Vec<_> = bricks.layer(bz).collect();
        for (b, p) in layer {
            bricks.read_raw(p, &mut rec)?;
            for (l, r) in rec.iter_mut().enumerate() {
                if *r == 0 {
                    continue;
                }
                let [z, y, x] = Bricks::voxel(b, l);
                let k = ((z - z0) * ny + y) * nx + x;
                let depth = depth_of(*r, near.get(k).copied().unwrap_or(f32::INFINITY));
                let depth = depth.min(DEPTH);
                *r = SOLID | depth;
                let i = (z * ny + y) * nx + x;
                if best.is_none_or(|(bd, bi)| depth > bd || depth == bd && i < bi) {
                    best = Some((depth, i));
                }
            }
            bricks.write_raw(p, &rec)?;
        }
    }
    Ok(best.map(|b| b.1))
}

/// Grow the kept set from `seed` through the solid, adding a voxel only when it is
/// simple for the set (6-connected, background 26-connected): highest depth first, then
/// lowest index. The same growth as [`super::repair`]'s `grow` for an object. The queue
/// may hold `queue_max` voxels.
fn grow(
    bricks: &mut Bricks,
    seed: usize,
    queue_max: u64,
    progress: &dyn Progress,
) -> Result<(), crate::Error> {
    let [_, ny, nx] = bricks.n;
    let mut heap: BinaryHeap<u64> = BinaryHeap::new();
    // Highest depth, then lowest index, first.
    let key = |r: u32, i: usize| u64::from(r & DEPTH) << 32 | u64::from(u32::MAX - i as u32);
    // The linear index of neighbour `b` of voxel `i` (in the grid).
    let at = |i: usize, b: usize| {
        ((i + (b / 9) * ny * nx + ((b / 3) % 3) * nx + b % 3) - ny * nx - nx) - 1
    };
    let hood = bricks.hood(seed)?;
    bricks.set(seed, hood[13] | KEPT)?;
    for &b in &FACES {
        if hood[b] & SOLID != 0 {
            let j = at(seed, b);
            bricks.set(j, hood[b] | QUEUED)?;
            heap.push(key(hood[b], j));
        }
    }
    let mut joined = 0u64;
    while let Some(k) = heap.pop() {
        let i = (u32::MAX - (k & 0xffff_ffff) as u32) as usize;
        let hood = bricks.hood(i)?;
        let r = hood[13] & !QUEUED;
        let mask = hood
            .iter()
            .enumerate()
            .fold(0u32, |m, (b, &h)| m | u32::from(h & KEPT != 0) << b);
        if !is_simple(mask) {
            bricks.set(i, r | WAITING)?;
            continue;
        }
        bricks.set(i, (r & !WAITING) | KEPT)?;
        joined += 1;
        if joined.is_multiple_of(1 << 20) {
            progress.advance(1 << 20);
            crate::progress::check_interrupt(progress)?;
        }
        for &b in &ALL {
            let s = hood[b];
            if s & KEPT != 0 || s & SOLID == 0 || s & QUEUED != 0 {
                continue;
            }
            // A new candidate must touch the set through a face; a waiting one may have
            // become simple whichever neighbour joined.
            if s & WAITING != 0 || FACES.contains(&b) {
                let j = at(i, b);
                bricks.set(j, (s & !WAITING) | QUEUED)?;
                heap.push(key(s, j));
            }
        }
        if heap.len() as u64 > queue_max {
            return Err(super::VoxelizeError::Topology(format!(
                "the topology repair's growth front holds {} voxels, {} in its queue, more than the {} --mem leaves for it; give more --mem, or use --topology strict / --allow-genus",
                heap.len(),
                human(heap.len() as u64 * 8),
                human(queue_max * 8)
            ))
            .into());
        }
    }
    Ok(())
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
    use crate::grid::FileStore;
    use crate::progress::Silent;

    fn store_with(
        dir: &tempfile::TempDir,
        name: &str,
        shape: [u64; 3],
        solid: &(impl Fn(u64, u64, u64) -> bool + Sync + Send),
    ) -> FileStore<u8> {
        let spec = GridSpec {
            shape,
            origin: [0.0; 3],
            spacing: 1.0,
            chunk: [4, 4, 4],
            unit: None,
        };
        let s = FileStore::<u8>::create(&dir.path().join(name), spec).unwrap();
        crate::grid::fill_with(&s, 1, |[z, y, x]| u8::from(solid(z, y, x))).unwrap();
        s
    }

    fn all(s: &FileStore<u8>) -> Vec<u8> {
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
        let o = cut(&b, None, dir.path(), 1 << 30, &Silent).unwrap();
        assert!(!o.spilled);
        assert_eq!(o.removed, whole.removed);
        assert!(o.removed > 0 && o.removed < 20, "{}", o.removed);
        assert_eq!(o.regions, whole.regions);
        assert!(all(&a) == all(&b), "the compact cut differs");
        assert_eq!(super::super::euler::euler_characteristic(&b, 1).unwrap(), 1);
    }

    /// Two fused rings crossing many bricks (genus 2), cut with the records all in
    /// memory and with a scratch file behind the smallest cache (8 bricks of the 30
    /// stored, so that bricks are evicted dirty and read back all the time): the same
    /// voxels removed, the same regions, the same labels, and one genus-0 piece.
    #[test]
    fn a_scratch_file_behind_a_small_cache_cuts_the_same_voxels() {
        let ring = |z: u64, y: u64, x: u64, c: [f64; 2]| {
            let (dy, dx) = (y as f64 - c[0], x as f64 - c[1]);
            let r = (dy * dy + dx * dx).sqrt();
            let dz = z as f64 - 16.0;
            (r - 14.0).powi(2) + dz * dz < 9.0
        };
        let shape =
            |z: u64, y: u64, x: u64| ring(z, y, x, [20.0, 20.0]) || ring(z, y, x, [20.0, 47.0]);
        let dir = tempfile::tempdir().unwrap();
        let a = store_with(&dir, "a", [40, 40, 68], &shape);
        let b = store_with(&dir, "b", [40, 40, 68], &shape);
        assert_eq!(
            super::super::euler::euler_characteristic(&a, 1).unwrap(),
            -1
        );
        let big = cut(&a, None, dir.path(), 1 << 30, &Silent).unwrap();
        // Less than the caller allows, for the smallest cache.
        let small_room = bytes_needed(a.spec()) / 2;
        let small = cut(&b, None, &dir.path().join("s"), small_room, &Silent).unwrap();
        assert!(!big.spilled && small.spilled);
        // Far more reads than the bricks stored: the cache evicted and read back.
        assert!(small.brick_reads > 100, "{}", small.brick_reads);
        assert!(big.removed > 0);
        assert_eq!(big.removed, small.removed);
        assert_eq!(big.regions, small.regions);
        assert!(all(&a) == all(&b), "the spilled cut differs");
        assert_eq!(super::super::euler::euler_characteristic(&b, 1).unwrap(), 1);
        // The scratch file is gone.
        assert!(!dir.path().join("s").join("cut.bricks").exists());
    }
}
