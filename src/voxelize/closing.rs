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
    const INF: f64 = f64::INFINITY;
    let [nz, ny, nx] = shape;
    let mut g: Vec<f64> = feature.iter().map(|&f| if f { 0.0 } else { INF }).collect();
    let n = nx.max(ny).max(nz);
    let (mut f, mut d) = (vec![0.0; n], vec![0.0; n]);
    let (mut v, mut z) = (vec![0usize; n], vec![0.0; n + 1]);
    // One line of `len` values from `start`, `stride` apart: gathered, transformed,
    // scattered back.
    let mut line = |g: &mut [f64], start: usize, stride: usize, len: usize| {
        for (q, fq) in f[..len].iter_mut().enumerate() {
            *fq = g[start + q * stride];
        }
        dt1d(&f[..len], &mut d[..len], &mut v, &mut z);
        for (q, dq) in d[..len].iter().enumerate() {
            g[start + q * stride] = *dq;
        }
    };
    for zz in 0..nz {
        for y in 0..ny {
            line(&mut g, (zz * ny + y) * nx, 1, nx);
        }
    }
    for zz in 0..nz {
        for x in 0..nx {
            line(&mut g, zz * ny * nx + x, nx, ny);
        }
    }
    for y in 0..ny {
        for x in 0..nx {
            line(&mut g, y * nx + x, nx * ny, nz);
        }
    }
    g.iter()
        .map(|&x| if x.is_finite() { x as u32 } else { u32::MAX })
        .collect()
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
pub fn close(
    solid: &dyn BlockStore<u8>,
    out: &dyn BlockStore<u8>,
    radius: u32,
    workers: usize,
    progress: &dyn Progress,
) -> Result<u64, crate::Error> {
    let spec = solid.spec();
    let blocks = spec.block_indices();
    let r2 = radius * radius;
    let h = 2 * radius as usize;
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
        let bs = spec.block_shape(b).map(|c| c as usize);
        let mut data = Vec::with_capacity(bs.iter().product());
        let mut n = 0u64;
        for z in 0..bs[0] {
            for y in 0..bs[1] {
                for x in 0..bs[2] {
                    let i = bx.offset(z + h, y + h, x + h);
                    data.push(if solid_box[i] {
                        1
                    } else if ero[i] > r2 {
                        n += 1;
                        ADDED
                    } else {
                        0
                    });
                }
            }
        }
        out.write_block(b, &data)?;
        progress.advance(1);
        Ok(n)
    })?;
    progress.finish();
    Ok(added.iter().sum())
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

    fn ring_spec(chunk: u64) -> GridSpec {
        GridSpec {
            shape: [24, 40, 40],
            origin: [0.0; 3],
            spacing: 1.0,
            chunk: [chunk; 3],
            unit: None,
        }
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
            let added = close(&solid, &out, 2, 2, &Silent).unwrap();
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
        close(&solid, &out, 1, 2, &Silent).unwrap();
        assert_eq!(handles(&out, 10, 2, u64::MAX, &Silent).unwrap().len(), 1);
        close(&wide, &out, 1, 2, &Silent).unwrap();
        let h = handles(&out, 10, 2, u64::MAX, &Silent).unwrap();
        assert!(h.is_empty(), "{h:?}");
    }
}
