//! One visit of a block: every voxel of the block (and the first layer of its halo)
//! without a direction whose upwind neighbours have theirs, in decreasing u, in chunks
//! of memory order.

use glam::DVec3;
use rayon::prelude::*;

use super::directions::{is_target, known};
use super::rule::{mean_of_neighbours, upwind, Region, Upwind};
use super::{Ctx, Rule, Visit, Visited, HALO, REACH};
use crate::grid::{Block, GridError};
use crate::math::{volume, Idx3};
use crate::trace::field::Tile;
use crate::trace::surface::REACH as SURFACE_REACH;

impl Ctx<'_> {
    /// Visit block `b`: compute every target voxel without a direction whose upwind
    /// neighbours have theirs (in decreasing u, so neighbours inside the block come first).
    #[allow(clippy::too_many_lines)]
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    pub(super) fn visit(
        &self,
        b: Idx3,
        rule: Rule,
        parallel: bool,
        write: bool,
    ) -> Result<Visited, GridError> {
        let (u, dirs, ball) = (self.u, self.dirs, self.ball);
        let spec = u.spec();
        let start = spec.block_start(b);
        let shape = spec.block_shape(b);
        let h = HALO as usize;
        // u is read once, with the margin the tile's boundary values need; the visit's
        // own arrays keep the halo of HALO.
        let wide = u.read_block_halo(b, h + SURFACE_REACH, f64::NAN)?;
        let hs = shape.map(|c| c as usize + 2 * h);
        let ub = Block {
            origin: wide.origin.map(|o| o + SURFACE_REACH as i64),
            shape: hs,
            data: wide.crop([SURFACE_REACH; 3], hs),
        };
        let lb = self.labels.read_block_halo(b, h, 0)?;
        let mut d = dirs.read_halo(b)?;
        let strides = [hs[1] * hs[2], hs[2], 1];
        let at = |z: usize, y: usize, x: usize| (z * hs[1] + y) * hs[2] + x;
        // Upwind voxels are computed in the halo too (all but its outer layer, whose
        // neighbours are not read), so chains of dependencies that zig-zag across the face
        // of the block resolve in one visit; only the core is written.
        let reach = if rule == Rule::Upwind { REACH } else { 0 };
        let in_core = |l: [usize; 3]| (0..3).all(|a| l[a] >= h && l[a] < h + shape[a] as usize);
        // The voxels to compute, each as one u128: decreasing u, then increasing index
        // (sorting packed keys moves a third of the bytes a tuple would).
        let mut todo: Vec<u128> = Vec::new();
        let mut v = Visit::default();
        for z in h - reach..h + shape[0] as usize + reach {
            for y in h - reach..h + shape[1] as usize + reach {
                for x in h - reach..h + shape[2] as usize + reach {
                    let i = at(z, y, x);
                    if is_target(lb.data[i]) && !known(&d, i) {
                        todo.push(pack(ub.data[i], i));
                    }
                }
            }
        }
        if todo.is_empty() {
            // No target voxel in the core (a block is due only with voxels left).
            if let Some(sink) = self.sink {
                let none = || vec![0.0; volume(shape) as usize];
                sink(b, &core(&lb.data, hs, h, shape), &[none(), none(), none()])?;
            }
            return Ok((v, None));
        }
        // The tile covers the block's halo but its last node; the boundary nodes' values
        // need SURFACE_REACH more nodes of u around that.
        let tile = Tile::from_u(
            &wide,
            ub.origin.map(|o| o + 1),
            [hs[0] - 2, hs[1] - 2, hs[2] - 2],
            self.boundary,
        );
        drop(wide);
        let region = Region {
            u: &ub.data,
            lab: &lb.data,
            hs,
            origin: ub.origin,
            tile: &tile,
            ball,
        };
        // (32-bit divisions: a visit's block with its halo holds far fewer than 2^32
        // voxels, and they are much faster than 64-bit ones.)
        let (plane, row) = ((hs[1] * hs[2]) as u32, hs[2] as u32);
        let local = |i: usize| {
            let i = i as u32;
            [i / plane, i / row % hs[1] as u32, i % row].map(|c| c as usize)
        };
        // What voxel `i` gets from the directions known so far, and whether it is in the
        // block's core.
        let eval = |d: &[[f32; 3]], i: usize, fill: bool| -> (Upwind, bool) {
            let (ux, local) = (ub.data[i], local(i));
            let own = in_core(local);
            let g: [f64; 3] =
                std::array::from_fn(|a| start[2 - a] as f64 + local[2 - a] as f64 - h as f64);
            let p = DVec3::from_array(g);
            let r = p - ball.center;
            let n = r.length();
            if n <= ball.radius {
                return (Upwind::Ball(if n > 1e-12 { r / n } else { DVec3::Z }), own);
            }
            let step = match region.follow(d, p, ux) {
                Upwind::Flat => upwind(&ub.data, &lb.data, d, i, ux, strides),
                other => other,
            };
            let value = match step {
                Upwind::Wait | Upwind::Flat if fill && own => {
                    mean_of_neighbours(&lb.data, d, i, strides).map_or(Upwind::Flat, Upwind::Filled)
                }
                other => other,
            };
            (value, own)
        };
        let mut changed = false;
        let mut apply = |d: &mut [[f32; 3]], i: usize, (value, own): (Upwind, bool)| {
            let (dir, count) = match value {
                Upwind::Value(dir) => (dir, &mut v.computed),
                Upwind::Ball(dir) => (dir, &mut v.ball),
                Upwind::Filled(dir) => (dir, &mut v.filled),
                _ => {
                    v.pending += u64::from(own);
                    return;
                }
            };
            d[i] = dir.as_vec3().to_array();
            if own {
                changed = true;
                *count += 1;
            }
        };
        // In chunks of decreasing u, each visited in memory order: the chunk's voxels are
        // a thin shell, and memory order keeps u, the tile and the directions in cache where
        // the order of u would jump across the block. A voxel that waits for one of its own
        // chunk is retried after the chunk, in the order of u, when all those above it are
        // done. Every value is the unique one of the dependency graph, so the result is the
        // same as one voxel after the other in the order of u.
        let (starts, members) = chunks_of(&todo);
        let mut retry: Vec<u128> = Vec::new();
        let fill = rule == Rule::Fill;
        for w in starts.windows(2) {
            let chunk = &members[w[0]..w[1]];
            retry.clear();
            if parallel && !fill {
                // Against the directions known before the chunk, spread over the threads.
                let first: Vec<(Upwind, bool)> = chunk
                    .par_iter()
                    .map(|&i| eval(&d, i as usize, false))
                    .collect();
                for (&i, value) in chunk.iter().zip(first) {
                    match value {
                        (Upwind::Wait, _) => retry.push(pack(ub.data[i as usize], i as usize)),
                        value => apply(&mut d, i as usize, value),
                    }
                }
            } else {
                // When filling, only upwind values are final out of order: what a voxel
                // fills from its neighbours depends on which of them are done.
                for (j, &i) in chunk.iter().enumerate() {
                    if let Some(&n) = chunk.get(j + PREFETCH) {
                        prefetch(&ub.data, n as usize);
                        prefetch(&d, n as usize);
                        prefetch(&lb.data, n as usize);
                    }
                    let i = i as usize;
                    match eval(&d, i, false) {
                        (Upwind::Wait, _) => retry.push(pack(ub.data[i], i)),
                        value @ (Upwind::Value(_) | Upwind::Ball(_), _) => apply(&mut d, i, value),
                        _ if fill => retry.push(pack(ub.data[i], i)),
                        value => apply(&mut d, i, value),
                    }
                }
            }
            retry.sort_unstable();
            for &t in &retry {
                let value = eval(&d, index(t), fill);
                apply(&mut d, index(t), value);
            }
        }
        let sink = self.sink.filter(|_| v.pending == 0);
        if !changed && sink.is_none() {
            return Ok((v, None));
        }
        let out = components(&d, hs, h, shape);
        if let Some(sink) = sink {
            sink(b, &core(&lb.data, hs, h, shape), &out)?;
        }
        if !changed {
            return Ok((v, None));
        }
        if !write {
            return Ok((v, Some(out)));
        }
        for (store, comp) in dirs.c.iter().zip(&out) {
            store.write_block(b, comp)?;
        }
        Ok((v, None))
    }
}

/// The x, y and z components of the core of a visit's directions `d` (a block of
/// `shape` with a halo of `h`, `hs` in all), in one pass.
fn components(d: &[[f32; 3]], hs: [usize; 3], h: usize, shape: Idx3) -> [Vec<f32>; 3] {
    let n = volume(shape) as usize;
    let mut out = [
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    ];
    for z in h..h + shape[0] as usize {
        for y in h..h + shape[1] as usize {
            let row = (z * hs[1] + y) * hs[2] + h;
            for c in &d[row..row + shape[2] as usize] {
                for (o, &v) in out.iter_mut().zip(c) {
                    o.push(v);
                }
            }
        }
    }
    out
}

/// The core of a visit's array `data` (a block of `shape` with a halo of `h`, `hs` in
/// all).
fn core<T: Copy>(data: &[T], hs: [usize; 3], h: usize, shape: Idx3) -> Vec<T> {
    let mut out = Vec::with_capacity(volume(shape) as usize);
    for z in h..h + shape[0] as usize {
        for y in h..h + shape[1] as usize {
            let row = (z * hs[1] + y) * hs[2] + h;
            out.extend_from_slice(&data[row..row + shape[2] as usize]);
        }
    }
    out
}

/// Voxels of a visit taken together, in memory order, about (see [`Ctx::visit`]).
const CHUNK: usize = 4096;

/// One key in this many, in memory order, chooses where the chunks split.
const SAMPLE: usize = 16;

/// Split the [`pack`]ed keys `todo` (in memory order) into chunks of consecutive keys,
/// about [`CHUNK`] each: every key of a chunk sorts before every key of the next (higher
/// u), and a chunk keeps memory order. Returns the voxel indices, chunk after chunk, and
/// the bounds of the chunks in them (chunk k is `starts[k]..starts[k + 1]`).
fn chunks_of(todo: &[u128]) -> (Vec<usize>, Vec<u32>) {
    // Splitting keys from a sorted sample: far cheaper than sorting all the keys, and the
    // chunks need not be equal.
    let mut sample: Vec<u128> = todo.iter().step_by(SAMPLE).copied().collect();
    sample.sort_unstable();
    let mut splits: Vec<u128> = sample
        .iter()
        .skip(CHUNK / SAMPLE)
        .step_by(CHUNK / SAMPLE)
        .copied()
        .collect();
    splits.dedup();
    let chunk: Vec<u32> = todo
        .iter()
        .map(|t| splits.partition_point(|s| s <= t) as u32)
        .collect();
    // Chunk k (of splits.len() + 1) is counted at k + 2, so that after the prefix sums
    // starts[k + 1] is where it begins.
    let mut starts = vec![0usize; splits.len() + 3];
    for &k in &chunk {
        starts[k as usize + 2] += 1;
    }
    for k in 2..starts.len() {
        starts[k] += starts[k - 1];
    }
    // Filling moves starts[k + 1] to chunk k's end: chunk k is starts[k]..starts[k + 1]
    // (the last window is empty).
    let mut members = vec![0u32; todo.len()];
    for (t, &k) in todo.iter().zip(&chunk) {
        let k = k as usize;
        members[starts[k + 1]] = index(*t) as u32;
        starts[k + 1] += 1;
    }
    (starts, members)
}

/// The sort key of voxel `i` with u = `u`: ascending keys go by decreasing u, ties by
/// increasing index; the low 64 bits are `i`.
fn pack(u: f64, i: usize) -> u128 {
    (u128::from(!ordered(u)) << 64) | i as u128
}

/// The voxel index a [`pack`]ed key holds.
fn index(key: u128) -> usize {
    key as u64 as usize
}

/// A u64 whose order is the order of the f64 `x` (total order, as `f64::total_cmp`).
fn ordered(x: f64) -> u64 {
    let b = x.to_bits();
    if b >> 63 == 1 {
        !b
    } else {
        b | (1 << 63)
    }
}

/// How many voxels ahead the voxel loop asks for a voxel's u, label and direction.
const PREFETCH: usize = 8;

/// Ask the processor to bring `data[i]` into its caches (a hint; nothing on other
/// targets). The voxels of a chunk lie scattered over the block (a thin shell of u), so
/// each misses the caches; asked for ahead, their loads overlap the work on the voxels
/// before them.
#[inline]
fn prefetch<T>(data: &[T], i: usize) {
    #[cfg(target_arch = "x86_64")]
    if i < data.len() {
        // SAFETY: a prefetch reads nothing and cannot fault; the pointer lies in `data`.
        unsafe {
            use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
            _mm_prefetch::<_MM_HINT_T0>(data.as_ptr().add(i).cast());
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (data, i);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Keys as a visit makes them: u in memory order, with runs of equal u (flat sheets)
    /// and a spread of magnitudes.
    fn keys(n: usize) -> Vec<u128> {
        let mut x = 0x2545_f491_4f6c_dd1d_u64;
        (0..n)
            .map(|i| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                let u = if i % 7 == 0 {
                    0.0
                } else {
                    (x >> 11) as f64 / (1u64 << 53) as f64 * 10f64.powi(-((x % 5) as i32))
                };
                pack(u, i)
            })
            .collect()
    }

    #[test]
    fn chunks_split_by_u_and_keep_memory_order() {
        for n in [0, 1, 100, CHUNK - 1, CHUNK, 10 * CHUNK + 17, 50_000] {
            let todo = keys(n);
            let (starts, members) = chunks_of(&todo);
            assert_eq!(members.len(), n);
            assert_eq!(starts.first(), Some(&0));
            assert_eq!(starts.last(), Some(&n));
            // Every voxel once.
            let mut seen = members.clone();
            seen.sort_unstable();
            assert!(seen.iter().enumerate().all(|(i, &m)| m as usize == i));
            let key = |m: u32| todo[m as usize];
            let mut before: Option<u128> = None;
            for w in starts.windows(2) {
                let chunk = &members[w[0]..w[1]];
                // Memory order within a chunk.
                assert!(chunk.windows(2).all(|p| p[0] < p[1]));
                // Every key of a chunk after every key of the chunks before it.
                if let (Some(b), Some(lo)) = (before, chunk.iter().map(|&m| key(m)).min()) {
                    assert!(lo > b, "n = {n}: chunks overlap in u");
                }
                if let Some(hi) = chunk.iter().map(|&m| key(m)).max() {
                    before = Some(hi);
                }
                assert!(
                    chunk.len() <= 4 * CHUNK,
                    "n = {n}: a chunk of {}",
                    chunk.len()
                );
            }
            if n >= 10 * CHUNK {
                let chunks = starts.windows(2).filter(|w| w[1] > w[0]).count();
                assert!(chunks >= n / CHUNK / 2, "n = {n}: only {chunks} chunks");
            }
        }
    }

    #[test]
    fn packed_keys_go_by_decreasing_u_then_index() {
        let us = [1.0, 0.5, 0.5, 1e-300, 0.0, -0.0, -1e-3, f64::NAN];
        let mut k: Vec<(u128, usize)> = us
            .iter()
            .enumerate()
            .map(|(i, &u)| (pack(u, i), i))
            .collect();
        k.sort_unstable();
        let order: Vec<usize> = k.iter().map(|&(_, i)| i).collect();
        assert_eq!(order, [7, 0, 1, 2, 3, 4, 5, 6]);
        assert!(k.iter().all(|&(key, i)| index(key) == i));
    }
}
