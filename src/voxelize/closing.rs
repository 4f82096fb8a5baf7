//! Morphological closing of the voxel solid by a ball, and where closing removes handles.
//!
//! Closing by radius `r` (dilation by the ball of radius `r`, then erosion by it) fills
//! gaps, grooves and tunnels narrower than about `2 r` and leaves the rest of the solid
//! as it was. Each block is read with a halo of `2 r` and closed with exact Euclidean
//! distances ([`edt_sq`], the separable transform of Felzenszwalb and Huttenlocher):
//! the dilation is `{d(v, S) <= r}`, the closing `{d(v, not dilation) > r}`, and the
//! solid itself is kept (near the grid's faces the erosion would otherwise eat it).
//!
//! The voxels closing adds fall into connected pieces. A piece that plugs a tunnel
//! raises the Euler characteristic by one, so [`handles`] measures, for the largest
//! pieces, the change of the Euler characteristic that each alone makes: that is where
//! the handles are.
// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

use super::components;
use crate::grid::BlockStore;
use crate::math::Idx3;
use crate::parallel::map_bounded;
use crate::progress::Progress;

/// Value written for a voxel that closing adds (1 is solid, 0 background).
pub const ADDED: u8 = 2;

/// Squared Euclidean distance (in voxels) from every voxel of a box of `shape` to the
/// nearest voxel where `feature` holds; `u32::MAX` when there is none.
#[must_use]
pub fn edt_sq(feature: &[bool], shape: [usize; 3]) -> Vec<u32> {
    let mut g: Vec<f64> = feature
        .iter()
        .map(|&f| if f { 0.0 } else { f64::INFINITY })
        .collect();
    edt_sq_in_place(&mut g, shape, false);
    g.iter()
        .map(|&x| if x.is_finite() { x as u32 } else { u32::MAX })
        .collect()
}

/// The transform of [`edt_sq`] in place: `g` is 0 at the features and infinite
/// elsewhere on entry, the squared distance (exact integers in f64; infinite where there
/// is no feature) on return. With `parallel`, the lines of each pass are transformed on
/// the pool's threads (the result is the same: each line is exact on its own).
pub(super) fn edt_sq_in_place(g: &mut [f64], shape: [usize; 3], parallel: bool) {
    use rayon::prelude::*;
    let [nz, ny, nx] = shape;
    let n = nx.max(ny).max(nz);
    // One line of `len` values from `start`, `stride` apart: gathered, transformed,
    // scattered back, with scratch `w` of four lines.
    let line = |g: &mut [f64], start: usize, stride: usize, len: usize, w: &mut Scratch| {
        for (q, fq) in w.f[..len].iter_mut().enumerate() {
            *fq = g[start + q * stride];
        }
        dt1d(&w.f[..len], &mut w.d[..len], &mut w.v, &mut w.z);
        for (q, dq) in w.d[..len].iter().enumerate() {
            g[start + q * stride] = *dq;
        }
    };
    let plane = ny * nx;
    // x then y, within each z plane.
    let planes = |g: &mut [f64], w: &mut Scratch| {
        for y in 0..ny {
            line(g, y * nx, 1, nx, w);
        }
        for x in 0..nx {
            line(g, x, nx, ny, w);
        }
    };
    if parallel {
        g.par_chunks_mut(plane)
            .for_each_init(|| Scratch::new(n), |w, p| planes(p, w));
    } else {
        let mut w = Scratch::new(n);
        for p in g.chunks_mut(plane) {
            planes(p, &mut w);
        }
    }
    // z, for each (y, x). In parallel: the nz x nx values of a few y at a time (two
    // for each thread, so that the copies stay small), gathered, transformed along z on
    // the threads and scattered back.
    if parallel {
        let batch = 2 * rayon::current_num_threads().max(1);
        for y0 in (0..ny).step_by(batch) {
            let ys: Vec<usize> = (y0..(y0 + batch).min(ny)).collect();
            let g_ref: &[f64] = g;
            let rows: Vec<Vec<f64>> = ys
                .par_iter()
                .map_init(
                    || Scratch::new(n),
                    |w, &y| {
                        let mut row = vec![0.0; nz * nx];
                        for z in 0..nz {
                            row[z * nx..(z + 1) * nx].copy_from_slice(
                                &g_ref[z * plane + y * nx..z * plane + (y + 1) * nx],
                            );
                        }
                        for x in 0..nx {
                            line(&mut row, x, nx, nz, w);
                        }
                        row
                    },
                )
                .collect();
            for (&y, row) in ys.iter().zip(&rows) {
                for z in 0..nz {
                    g[z * plane + y * nx..z * plane + (y + 1) * nx]
                        .copy_from_slice(&row[z * nx..(z + 1) * nx]);
                }
            }
        }
    } else {
        let mut w = Scratch::new(n);
        for y in 0..ny {
            for x in 0..nx {
                line(g, y * nx + x, plane, nz, &mut w);
            }
        }
    }
}

/// The line buffers of [`dt1d`].
struct Scratch {
    f: Vec<f64>,
    d: Vec<f64>,
    v: Vec<usize>,
    z: Vec<f64>,
}

impl Scratch {
    fn new(n: usize) -> Self {
        Self {
            f: vec![0.0; n],
            d: vec![0.0; n],
            v: vec![0; n],
            z: vec![0.0; n + 1],
        }
    }
}

/// One-dimensional squared distance transform of the sampled function `f` (lower
/// envelope of parabolas), into `d`.
pub(super) fn dt1d(f: &[f64], d: &mut [f64], v: &mut [usize], z: &mut [f64]) {
    let n = f.len();
    let mut k: isize = -1;
    for q in 0..n {
        if !f[q].is_finite() {
            continue;
        }
        loop {
            if k < 0 {
                k = 0;
                v[0] = q;
                z[0] = f64::NEG_INFINITY;
                z[1] = f64::INFINITY;
                break;
            }
            let p = v[k as usize];
            let s = ((f[q] + (q * q) as f64) - (f[p] + (p * p) as f64)) / (2.0 * (q - p) as f64);
            if s <= z[k as usize] {
                k -= 1;
                continue;
            }
            k += 1;
            v[k as usize] = q;
            z[k as usize] = s;
            z[k as usize + 1] = f64::INFINITY;
            break;
        }
    }
    if k < 0 {
        d.fill(f64::INFINITY);
        return;
    }
    let mut j = 0usize;
    for (q, dq) in d.iter_mut().enumerate() {
        while z[j + 1] < q as f64 {
            j += 1;
        }
        let p = v[j];
        let dist = q as f64 - p as f64;
        *dq = dist * dist + f[p];
    }
}

/// Close the solid (`{v == 1}` of `solid`) by a ball of `radius` voxels into `out`:
/// 1 where the solid is, [`ADDED`] where closing adds a voxel, 0 elsewhere. Returns the
/// voxels added.
///
/// Block by block on `workers` threads, each block read with a halo of `2 radius`; or,
/// when the whole grid padded by `radius` fits in `room` bytes ([`whole_bytes`]) and
/// is smaller than the blocks' boxes together, in one box of the whole grid, with the
/// transform's lines on the threads. The two give the same bytes: both distances are
/// exact, and every voxel that decides a voxel's value is in its box (the solid lies in
/// the grid, and the dilation outside the padded grid is empty within `radius` of it).
/// The halos make the blocks' boxes 60 times the grid for a closing by 48 in blocks of
/// 64 (adk_open at 0.25 A: 45 s against under 2 s whole).
pub fn close(
    solid: &dyn BlockStore<u8>,
    out: &dyn BlockStore<u8>,
    radius: u32,
    workers: usize,
    room: u64,
    progress: &dyn Progress,
) -> Result<u64, crate::Error> {
    let spec = solid.spec();
    let blocks = spec.block_indices();
    let r2 = radius * radius;
    let h = 2 * radius as usize;
    let boxes: u64 = blocks
        .iter()
        .map(|&b| {
            spec.block_shape(b)
                .iter()
                .map(|&c| c + 2 * h as u64)
                .product::<u64>()
        })
        .sum();
    let padded: u64 = spec
        .shape
        .iter()
        .map(|&c| c + 2 * u64::from(radius))
        .product();
    if padded < boxes && whole_bytes(spec, radius) <= room {
        return close_whole(solid, out, radius, workers, progress);
    }
    progress.start(
        &format!("voxelize: closing by {radius} voxels"),
        blocks.len() as u64,
    );
    let added = map_bounded(&blocks, workers, |&b| -> Result<u64, crate::Error> {
        // A stop request (Ctrl-C) ends the pass at the next block.
        crate::progress::check_interrupt(progress)?;
        let bx = solid.read_block_halo(b, h, 0)?;
        let s = bx.shape;
        let solid_box: Vec<bool> = bx.data.iter().map(|&v| v == 1).collect();
        let dil: Vec<bool> = edt_sq(&solid_box, s).iter().map(|&d| d <= r2).collect();
        let outside: Vec<bool> = dil.iter().map(|&d| !d).collect();
        let ero = edt_sq(&outside, s);
        let n = write_closed(out, b, |z, y, x| {
            let i = bx.offset(z + h, y + h, x + h);
            (solid_box[i], ero[i] > r2)
        })?;
        progress.advance(1);
        Ok(n)
    })?;
    progress.finish();
    Ok(added.iter().sum())
}

/// Bytes [`close`] holds to close the whole grid in one box: the padded grid's distances
/// (f64) and solid mask, the rows the parallel transform gathers, and a block per
/// worker.
#[must_use]
fn whole_bytes(spec: &crate::grid::GridSpec, radius: u32) -> u64 {
    let p = 2 * u64::from(radius);
    let [nz, ny, nx] = spec.shape.map(|c| c + p);
    let threads = rayon::current_num_threads().max(1) as u64;
    let c = spec.chunk.iter().product::<u64>();
    nz * ny * nx * 9 + 2 * threads * nz * nx * 8 + threads * c
}

/// [`close`] in one box of the whole grid padded by `radius`.
fn close_whole(
    solid: &dyn BlockStore<u8>,
    out: &dyn BlockStore<u8>,
    radius: u32,
    workers: usize,
    progress: &dyn Progress,
) -> Result<u64, crate::Error> {
    let spec = solid.spec();
    let blocks = spec.block_indices();
    let p = radius as usize;
    let [nz, ny, nx] = spec.shape.map(|c| c as usize);
    let shape = [nz + 2 * p, ny + 2 * p, nx + 2 * p];
    let at = |z: usize, y: usize, x: usize| ((z + p) * shape[1] + (y + p)) * shape[2] + (x + p);
    progress.start(
        &format!("voxelize: closing by {radius} voxels"),
        2 * blocks.len() as u64,
    );
    let mut is_solid = vec![false; shape.iter().product()];
    for &b in &blocks {
        crate::progress::check_interrupt(progress)?;
        let data = solid.read_block(b)?;
        let st = spec.block_start(b).map(|c| c as usize);
        let bs = spec.block_shape(b).map(|c| c as usize);
        let mut o = 0;
        for z in 0..bs[0] {
            for y in 0..bs[1] {
                let row = at(st[0] + z, st[1] + y, st[2]);
                for (x, s) in is_solid[row..row + bs[2]].iter_mut().enumerate() {
                    *s = data[o + x] == 1;
                }
                o += bs[2];
            }
        }
        progress.advance(1);
    }
    let r2 = f64::from(radius * radius);
    let mut g: Vec<f64> = is_solid
        .iter()
        .map(|&s| if s { 0.0 } else { f64::INFINITY })
        .collect();
    edt_sq_in_place(&mut g, shape, true);
    crate::progress::check_interrupt(progress)?;
    // The features of the second transform: the voxels the dilation leaves out.
    for d in &mut g {
        *d = if *d <= r2 { f64::INFINITY } else { 0.0 };
    }
    edt_sq_in_place(&mut g, shape, true);
    let (g, is_solid) = (&g, &is_solid);
    let added = map_bounded(&blocks, workers, |&b| -> Result<u64, crate::Error> {
        crate::progress::check_interrupt(progress)?;
        let st = spec.block_start(b).map(|c| c as usize);
        let n = write_closed(out, b, |z, y, x| {
            let i = at(st[0] + z, st[1] + y, st[2] + x);
            (is_solid[i], g[i] > r2)
        })?;
        progress.advance(1);
        Ok(n)
    })?;
    progress.finish();
    Ok(added.iter().sum())
}

/// Write block `b` of a closing into `out`: for each voxel (block coordinates z, y, x),
/// `voxel` says whether it is solid and whether the closing holds it; 1 for the solid,
/// [`ADDED`] for what the closing adds, 0 elsewhere. Returns the voxels added.
fn write_closed(
    out: &dyn BlockStore<u8>,
    b: Idx3,
    voxel: impl Fn(usize, usize, usize) -> (bool, bool),
) -> Result<u64, crate::Error> {
    let bs = out.spec().block_shape(b).map(|c| c as usize);
    let mut data = Vec::with_capacity(bs.iter().product());
    let mut n = 0u64;
    for z in 0..bs[0] {
        for y in 0..bs[1] {
            for x in 0..bs[2] {
                data.push(match voxel(z, y, x) {
                    (true, _) => 1,
                    (false, true) => {
                        n += 1;
                        ADDED
                    }
                    (false, false) => 0,
                });
            }
        }
    }
    out.write_block(b, &data)?;
    Ok(n)
}

/// A place where closing removes handles.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Handle {
    /// A voxel of the piece that closing adds there (`[z, y, x]`).
    pub voxel: Idx3,
    /// Its center in world coordinates (x, y, z).
    pub position: [f64; 3],
    /// Voxels in the piece.
    pub voxels: u64,
    /// Tunnels the piece closes: the rise of the Euler characteristic when it alone is
    /// added.
    pub closes: i64,
    /// The piece's bounding box, lowest and highest voxel (`[z, y, x]`); where the
    /// repair works on it.
    #[serde(skip, default)]
    pub lo: Idx3,
    /// See `lo`.
    #[serde(skip, default)]
    pub hi: Idx3,
}

/// The pieces that closing (as written by [`close`] into `out`) adds, the largest
/// `max_pieces` of them, with the handles each closes; those that close at least one,
/// largest first.
pub fn handles(
    out: &dyn BlockStore<u8>,
    max_pieces: usize,
    workers: usize,
    limit: u64,
    progress: &dyn Progress,
) -> Result<Vec<Handle>, crate::Error> {
    let spec = out.spec().clone();
    let comps = components::find(
        out,
        |v| v == ADDED,
        workers,
        limit,
        "voxelize: pieces added by closing",
        progress,
    )?;
    let mut order: Vec<u32> = (0..comps.sizes.len() as u32).collect();
    order.sort_by_key(|&c| (std::cmp::Reverse(comps.sizes[c as usize]), c));
    order.truncate(max_pieces);
    if order.is_empty() {
        return Ok(Vec::new());
    }
    let mut wanted = vec![usize::MAX; comps.sizes.len()];
    for (k, &c) in order.iter().enumerate() {
        wanted[c as usize] = k;
    }
    // Bounding box and first voxel of each wanted piece.
    let per_block = map_bounded(&spec.block_indices(), workers, |&b| {
        let data = out.read_block(b)?;
        let s = spec.block_shape(b).map(|c| c as usize);
        let (labels, _) = components::label_block(&data, s, |v| v == ADDED);
        let st = spec.block_start(b);
        let bl = spec.block_linear(b) as usize;
        let mut found: Vec<(usize, Idx3)> = Vec::new();
        let mut o = 0;
        for z in 0..s[0] {
            for y in 0..s[1] {
                for x in 0..s[2] {
                    let l = labels[o];
                    o += 1;
                    if l == 0 {
                        continue;
                    }
                    let k = wanted[comps.of(bl, l) as usize];
                    if k != usize::MAX {
                        found.push((k, [st[0] + z as u64, st[1] + y as u64, st[2] + x as u64]));
                    }
                }
            }
        }
        Ok::<_, crate::Error>(found)
    })?;
    let mut lo = vec![[u64::MAX; 3]; order.len()];
    let mut hi = vec![[0u64; 3]; order.len()];
    let mut first: Vec<Option<Idx3>> = vec![None; order.len()];
    for (k, v) in per_block.into_iter().flatten() {
        for a in 0..3 {
            lo[k][a] = lo[k][a].min(v[a]);
            hi[k][a] = hi[k][a].max(v[a]);
        }
        first[k].get_or_insert(v);
    }
    let mut out_handles = Vec::new();
    for (k, &c) in order.iter().enumerate() {
        let Some(seed) = first[k] else { continue };
        let closes = delta_euler(out, lo[k], hi[k], seed)?;
        if closes > 0 {
            out_handles.push(Handle {
                voxel: seed,
                position: spec.voxel_center(seed).to_array(),
                voxels: comps.sizes[c as usize],
                closes,
                lo: lo[k],
                hi: hi[k],
            });
        }
    }
    Ok(out_handles)
}

/// The Euler characteristic of `solid + the added piece holding seed` minus that of the
/// solid, over the piece's bounding box `[lo, hi]` with a margin of one voxel (every
/// cell the piece touches lies in it).
fn delta_euler(
    out: &dyn BlockStore<u8>,
    lo: Idx3,
    hi: Idx3,
    seed: Idx3,
) -> Result<i64, crate::Error> {
    let origin = lo.map(|v| v as i64 - 1);
    let shape = [0, 1, 2].map(|a| (hi[a] - lo[a] + 3) as usize);
    let bx = out.read_region(origin, shape, 0)?;
    let (labels, _) = components::label_block(&bx.data, shape, |v| v == ADDED);
    let l = |v: Idx3| {
        let i = [0, 1, 2].map(|a| (v[a] as i64 - origin[a]) as usize);
        (i[0] * shape[1] + i[1]) * shape[2] + i[2]
    };
    let mine = labels[l(seed)];
    let with: Vec<u8> = bx
        .data
        .iter()
        .zip(&labels)
        .map(|(&v, &lb)| u8::from(v == 1 || (lb == mine && lb != 0)))
        .collect();
    let without: Vec<u8> = bx.data.iter().map(|&v| u8::from(v == 1)).collect();
    Ok(box_euler(&with, shape) - box_euler(&without, shape))
}

/// Euler characteristic of `{v == 1}` in a box, cells counted at their lowest corner
/// (the cells at the box's high faces have no partner voxels and count as they are).
pub(super) fn box_euler(d: &[u8], shape: [usize; 3]) -> i64 {
    let [nz, ny, nx] = shape;
    let at = |z: usize, y: usize, x: usize| -> i64 {
        if z >= nz || y >= ny || x >= nx {
            0
        } else {
            i64::from(d[(z * ny + y) * nx + x] == 1)
        }
    };
    super::euler::cells_chi(shape, at)
}

/// Copy the closed solid back: every [`ADDED`] voxel of `out` becomes solid in `solid`.
pub fn apply(
    solid: &dyn BlockStore<u8>,
    out: &dyn BlockStore<u8>,
    workers: usize,
) -> Result<(), crate::Error> {
    map_bounded(&solid.spec().block_indices(), workers, |&b| {
        let o = out.read_block(b)?;
        if o.contains(&ADDED) {
            let mut s = solid.read_block(b)?;
            for (s, &o) in s.iter_mut().zip(&o) {
                if o == ADDED {
                    *s = 1;
                }
            }
            solid.write_block(b, &s)?;
        }
        Ok::<_, crate::Error>(())
    })?;
    Ok(())
}

/// Bytes one worker of [`close`] holds for blocks of edge `chunk`.
#[must_use]
pub fn worker_bytes(chunk: u64, radius: u32) -> u64 {
    let e = chunk + 4 * u64::from(radius);
    // The box, two boolean masks, two distance arrays (u32) and an f64 work array.
    e * e * e * (1 + 2 + 8 + 8) + chunk * chunk * chunk
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::{GridSpec, MemStore};
    use crate::progress::Silent;

    #[test]
    fn distance_transform_matches_brute_force() {
        let shape = [7usize, 9, 8];
        let n: usize = shape.iter().product();
        let feat: Vec<bool> = (0..n).map(|i| (i * 37) % 53 == 0).collect();
        let d = edt_sq(&feat, shape);
        let pos = |i: usize| {
            [
                i / (shape[1] * shape[2]),
                (i / shape[2]) % shape[1],
                i % shape[2],
            ]
            .map(|c| c as i64)
        };
        for (i, &di) in d.iter().enumerate() {
            let p = pos(i);
            let best = (0..n)
                .filter(|&j| feat[j])
                .map(|j| {
                    let q = pos(j);
                    (0..3).map(|a| (p[a] - q[a]).pow(2)).sum::<i64>() as u32
                })
                .min()
                .unwrap_or(u32::MAX);
            assert_eq!(di, best, "voxel {p:?}");
        }
    }

    /// A grid of unit voxels at the origin.
    fn unit_spec(shape: Idx3, chunk: u64) -> GridSpec {
        GridSpec {
            shape,
            origin: [0.0; 3],
            spacing: 1.0,
            chunk: [chunk; 3],
            unit: None,
        }
    }

    fn ring_spec(chunk: u64) -> GridSpec {
        unit_spec([24, 40, 40], chunk)
    }

    /// A thick ring (genus 1) whose hole is a slit 2 voxels wide.
    fn slit_ring(spec: &GridSpec) -> MemStore<u8> {
        let s = MemStore::new(spec.clone(), 0u8);
        crate::grid::fill_with(&s, 1, |[z, y, x]| {
            let slab = (8..16).contains(&z) && (6..34).contains(&y) && (6..34).contains(&x);
            let slit = (19..21).contains(&y) && (12..28).contains(&x);
            u8::from(slab && !slit)
        })
        .unwrap();
        s
    }

    #[test]
    fn closing_plugs_a_narrow_slit_and_reports_the_handle_there() {
        for chunk in [8, 16, 64] {
            let spec = ring_spec(chunk);
            let solid = slit_ring(&spec);
            let chi0 = super::super::euler::euler_characteristic(&solid, 2).unwrap();
            assert_eq!(chi0, 0, "a ring");
            let out = MemStore::new(spec.clone(), 0u8);
            let added = close(&solid, &out, 2, 2, 0, &Silent).unwrap();
            // Inside the slit (2 x 16 x 8 voxels), less its top and bottom layers,
            // which the ball does not fit over.
            assert!(added > 0 && added <= 2 * 16 * 8, "chunk {chunk}: {added}");
            let h = handles(&out, 10, 2, u64::MAX, &Silent).unwrap();
            assert_eq!(h.len(), 1);
            assert_eq!(h[0].closes, 1);
            let v = h[0].voxel;
            assert!(
                (8..16).contains(&v[0]) && (19..21).contains(&v[1]) && (12..28).contains(&v[2])
            );
            apply(&solid, &out, 2).unwrap();
            let chi1 = super::super::euler::euler_characteristic(&solid, 2).unwrap();
            assert_eq!(chi1, 1, "genus 0 after closing");
        }
    }

    #[test]
    fn the_whole_grid_closing_gives_the_blocks_bytes() {
        // A solid of scattered blobs and slabs reaching the grid's faces (where the
        // padding matters), closed in blocks of 8 (room 0) and whole (room unlimited).
        let spec = unit_spec([21, 30, 26], 8);
        let solid = MemStore::new(spec.clone(), 0u8);
        crate::grid::fill_with(&solid, 1, |[z, y, x]| {
            let h = (z * 73 + y * 151 + x * 37 + (z * y * x) % 11) % 97;
            let slab = (3..9).contains(&z) && y > 2 && x < 24;
            let pillar = (x as i64 - 20).pow(2) + (y as i64 - 5).pow(2) < 9;
            u8::from(h < 23 || (slab && h % 3 != 0) || pillar)
        })
        .unwrap();
        for radius in [1, 2, 3, 5] {
            let (a, b) = (
                MemStore::new(spec.clone(), 0u8),
                MemStore::new(spec.clone(), 0u8),
            );
            let na = close(&solid, &a, radius, 2, 0, &Silent).unwrap();
            let nb = close(&solid, &b, radius, 2, u64::MAX, &Silent).unwrap();
            assert!(na > 0, "radius {radius}: the case adds nothing");
            assert_eq!(na, nb, "radius {radius}");
            for blk in spec.block_indices() {
                assert_eq!(
                    a.read_block(blk).unwrap(),
                    b.read_block(blk).unwrap(),
                    "radius {radius}"
                );
            }
        }
    }

    #[test]
    fn the_parallel_transform_is_the_sequential_one() {
        let shape = [9usize, 13, 11];
        let n: usize = shape.iter().product();
        let g0: Vec<f64> = (0..n)
            .map(|i| {
                if (i * 29) % 41 == 0 {
                    0.0
                } else {
                    f64::INFINITY
                }
            })
            .collect();
        let (mut a, mut b) = (g0.clone(), g0);
        edt_sq_in_place(&mut a, shape, false);
        edt_sq_in_place(&mut b, shape, true);
        assert_eq!(a, b);
    }

    #[test]
    fn closing_too_small_for_the_slit_adds_nothing_there() {
        let spec = ring_spec(16);
        let solid = slit_ring(&spec);
        let out = MemStore::new(spec.clone(), 0u8);
        // A ball of radius 1 still plugs the slit 2 wide (its inner layers); one 4 wide
        // stays open.
        let wide = MemStore::new(spec.clone(), 0u8);
        for b in spec.block_indices() {
            let st = spec.block_start(b);
            let bs = spec.block_shape(b);
            let mut d = solid.read_block(b).unwrap();
            let mut o = 0;
            for _z in 0..bs[0] {
                for y in 0..bs[1] {
                    for x in 0..bs[2] {
                        let (y, x) = (st[1] + y, st[2] + x);
                        if (18..22).contains(&y) && (12..28).contains(&x) {
                            d[o] = 0;
                        }
                        o += 1;
                    }
                }
            }
            wide.write_block(b, &d).unwrap();
        }
        close(&solid, &out, 1, 2, 0, &Silent).unwrap();
        assert_eq!(handles(&out, 10, 2, u64::MAX, &Silent).unwrap().len(), 1);
        close(&wide, &out, 1, 2, 0, &Silent).unwrap();
        let h = handles(&out, 10, 2, u64::MAX, &Silent).unwrap();
        assert!(h.is_empty(), "{h:?}");
    }
}
