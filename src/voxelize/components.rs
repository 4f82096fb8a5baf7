//! Connected components (6-connectivity) of a predicate over a chunked u8 grid, block by
//! block: each block is labelled alone, the labels meeting across block faces are
//! joined in a union-find over (block, local label), and a second pass rewrites voxels
//! by their global component.
//!
//! Memory: one block of labels per worker, plus the faces of every block run-length
//! encoded (a face is almost always a few runs) and the union-find (one entry per local
//! component). Local labels are numbered in scan order and unions always keep the lower
//! id, so component numbers do not depend on the thread count.

use std::sync::atomic::{AtomicU64, Ordering};

use super::VoxelizeError;
use crate::grid::BlockStore;
use crate::math::{volume, Idx3};
use crate::parallel::map_bounded;
use crate::progress::Progress;

/// Bytes kept per local component until the components are resolved (size, border
/// flag, union-find entry, global id, root map, offset share).
const BYTES_PER_COMPONENT: u64 = 32;

/// Run-length encoded face labels: `(run length, label)`; label 0 = not in the set.
type Rle = Vec<(u32, u32)>;

struct BlockInfo {
    sizes: Vec<u64>,
    border: Vec<bool>,
    /// `faces[axis][0]` = low face, `[1]` = high face.
    faces: [[Rle; 2]; 3],
}

/// The components found.
#[derive(Debug)]
pub struct Components {
    /// Voxel count of each component, in order of first appearance (C order of blocks,
    /// then of voxels inside the block).
    pub sizes: Vec<u64>,
    /// Whether each component touches the faces of the grid.
    pub touches_border: Vec<bool>,
    /// Global component of each (block, local label): `comp[offset[block] + l - 1]`.
    comp: Vec<u32>,
    offset: Vec<usize>,
}

impl Components {
    /// Component id of local label `l` (1-based) of block number `block`.
    #[must_use]
    pub fn of(&self, block: usize, l: u32) -> u32 {
        self.comp[self.offset[block] + l as usize - 1]
    }
}

/// Root of `a` in the parent forest `p`, halving paths on the way.
fn root(p: &mut [u32], mut a: u32) -> u32 {
    while p[a as usize] != a {
        p[a as usize] = p[p[a as usize] as usize];
        a = p[a as usize];
    }
    a
}

/// Label the voxels of a block in scan order (6-connectivity); 0 = not in the set.
/// Returns the labels and the number of components.
pub fn label_block(data: &[u8], shape: [usize; 3], pred: impl Fn(u8) -> bool) -> (Vec<u32>, u32) {
    let [nz, ny, nx] = shape;
    let mut labels = vec![0u32; data.len()];
    let mut parent: Vec<u32> = vec![0];
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let i = (z * ny + y) * nx + x;
                if !pred(data[i]) {
                    continue;
                }
                let mut l = 0u32;
                for (ok, j) in [
                    (x > 0, i.wrapping_sub(1)),
                    (y > 0, i.wrapping_sub(nx)),
                    (z > 0, i.wrapping_sub(nx * ny)),
                ] {
                    if ok && labels[j] != 0 {
                        let r = root(&mut parent, labels[j]);
                        if l == 0 {
                            l = r;
                        } else if r != l {
                            let (lo, hi) = (l.min(r), l.max(r));
                            parent[hi as usize] = lo;
                            l = lo;
                        }
                    }
                }
                if l == 0 {
                    l = parent.len() as u32;
                    parent.push(l);
                }
                labels[i] = l;
            }
        }
    }
    // Renumber roots 1..=n in order of first appearance.
    let mut renum = vec![0u32; parent.len()];
    let mut n = 0;
    for v in &mut labels {
        if *v != 0 {
            let r = root(&mut parent, *v) as usize;
            if renum[r] == 0 {
                n += 1;
                renum[r] = n;
            }
            *v = renum[r];
        }
    }
    (labels, n)
}

fn rle(it: impl Iterator<Item = u32>) -> Rle {
    let mut out: Rle = Vec::new();
    for v in it {
        match out.last_mut() {
            Some((n, l)) if *l == v => *n += 1,
            _ => out.push((1, v)),
        }
    }
    out
}

fn unrle(r: &Rle) -> impl Iterator<Item = u32> + '_ {
    r.iter()
        .flat_map(|&(n, l)| std::iter::repeat_n(l, n as usize))
}

fn face(labels: &[u32], s: [usize; 3], axis: usize, at: usize) -> Rle {
    let [nz, ny, nx] = s;
    let idx = move |z: usize, y: usize, x: usize| labels[(z * ny + y) * nx + x];
    match axis {
        0 => rle((0..ny).flat_map(move |y| (0..nx).map(move |x| idx(at, y, x)))),
        1 => rle((0..nz).flat_map(move |z| (0..nx).map(move |x| idx(z, at, x)))),
        _ => rle((0..nz).flat_map(move |z| (0..ny).map(move |y| idx(z, y, at)))),
    }
}

struct Uf(Vec<u32>);

impl Uf {
    fn find(&mut self, a: u32) -> u32 {
        root(&mut self.0, a)
    }
    fn union(&mut self, a: u32, b: u32) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb {
            let (lo, hi) = (ra.min(rb), ra.max(rb));
            self.0[hi as usize] = lo;
        }
    }
}

/// Find the 6-connected components of `{v : pred(v)}` over the whole grid.
#[allow(clippy::too_many_lines)] // the union-find's block pass and its merge across faces share the labels
pub fn find(
    store: &dyn BlockStore<u8>,
    pred: fn(u8) -> bool,
    workers: usize,
    limit: u64,
    name: &str,
    progress: &dyn Progress,
) -> Result<Components, crate::Error> {
    let spec = store.spec();
    let blocks = spec.block_indices();
    progress.start(name, blocks.len() as u64);
    // What the per-block results hold, against `limit`: a grid cut into millions of
    // pieces (a noisy segmentation) would otherwise outgrow the memory budget.
    let held = AtomicU64::new(0);
    let infos = map_bounded(&blocks, workers, |&b| -> Result<BlockInfo, crate::Error> {
        // A stop request (Ctrl-C) ends the pass at the next block.
        crate::progress::check_interrupt(progress)?;
        let data = store.read_block(b)?;
        let s = spec.block_shape(b).map(|c| c as usize);
        let (labels, n) = label_block(&data, s, pred);
        let mut sizes = vec![0u64; n as usize];
        for &l in &labels {
            if l != 0 {
                sizes[l as usize - 1] += 1;
            }
        }
        let mut border = vec![false; n as usize];
        let faces: [[Rle; 2]; 3] =
            [0, 1, 2].map(|a| [face(&labels, s, a, 0), face(&labels, s, a, s[a] - 1)]);
        let start = spec.block_start(b);
        for a in 0..3 {
            let on_low = start[a] == 0;
            let on_high = start[a] + s[a] as u64 == spec.shape[a];
            for (side, on) in [(0, on_low), (1, on_high)] {
                if on {
                    for l in unrle(&faces[a][side]) {
                        if l != 0 {
                            border[l as usize - 1] = true;
                        }
                    }
                }
            }
        }
        let bytes = BYTES_PER_COMPONENT * sizes.len() as u64
            + 8 * faces.iter().flatten().map(|f| f.len() as u64).sum::<u64>();
        if held.fetch_add(bytes, Ordering::Relaxed) + bytes > limit {
            return Err(VoxelizeError::Topology(format!(
                "the grid falls apart into too many separate pieces to label within the memory budget ({} pieces in the first blocks alone); denoise the input, use a coarser grid, or give more --mem",
                held.load(Ordering::Relaxed) / BYTES_PER_COMPONENT
            ))
            .into());
        }
        progress.advance(1);
        Ok(BlockInfo {
            sizes,
            border,
            faces,
        })
    })?;
    progress.finish();
    let mut offset = Vec::with_capacity(infos.len() + 1);
    let mut total = 0usize;
    for i in &infos {
        offset.push(total);
        total += i.sizes.len();
    }
    offset.push(total);
    if total > u32::MAX as usize {
        return Err(VoxelizeError::Topology(format!(
            "{total} separate pieces in the blocks of the grid: too fragmented to label; use a coarser grid"
        ))
        .into());
    }
    let mut uf = Uf((0..total as u32).collect());
    let nb = spec.blocks();
    for (bi, &b) in blocks.iter().enumerate() {
        for a in 0..3 {
            if b[a] + 1 >= nb[a] {
                continue;
            }
            let mut n: Idx3 = b;
            n[a] += 1;
            let ni = spec.block_linear(n) as usize;
            for (l1, l2) in unrle(&infos[bi].faces[a][1]).zip(unrle(&infos[ni].faces[a][0])) {
                if l1 != 0 && l2 != 0 {
                    uf.union(
                        (offset[bi] + l1 as usize - 1) as u32,
                        (offset[ni] + l2 as usize - 1) as u32,
                    );
                }
            }
        }
    }
    let mut comp = vec![u32::MAX; total];
    let mut root_comp = vec![u32::MAX; total];
    let mut sizes = Vec::new();
    let mut touches = Vec::new();
    for (bi, info) in infos.iter().enumerate() {
        for (l, (&sz, &bd)) in info.sizes.iter().zip(&info.border).enumerate() {
            let g = offset[bi] + l;
            let r = uf.find(g as u32) as usize;
            if root_comp[r] == u32::MAX {
                root_comp[r] = sizes.len() as u32;
                sizes.push(0);
                touches.push(false);
            }
            let c = root_comp[r];
            comp[g] = c;
            sizes[c as usize] += sz;
            touches[c as usize] |= bd;
        }
    }
    Ok(Components {
        sizes,
        touches_border: touches,
        comp,
        offset,
    })
}

/// Rewrite every voxel of the set: `f(component, old value)` gives its new value.
pub fn rewrite(
    store: &dyn BlockStore<u8>,
    comps: &Components,
    pred: fn(u8) -> bool,
    f: impl Fn(u32, u8) -> u8 + Sync + Send,
    workers: usize,
) -> Result<(), crate::Error> {
    let spec = store.spec();
    let blocks = spec.block_indices();
    map_bounded(&blocks, workers, |&b| -> Result<(), crate::Error> {
        let mut data = store.read_block(b)?;
        let s = spec.block_shape(b).map(|c| c as usize);
        let (labels, n) = label_block(&data, s, pred);
        if n == 0 {
            return Ok(());
        }
        let bl = spec.block_linear(b) as usize;
        let mut changed = false;
        for (v, &l) in data.iter_mut().zip(&labels) {
            if l != 0 {
                let nv = f(comps.of(bl, l), *v);
                changed |= nv != *v;
                *v = nv;
            }
        }
        if changed {
            debug_assert_eq!(data.len() as u64, volume(spec.block_shape(b)));
            store.write_block(b, &data)?;
        }
        Ok(())
    })?;
    Ok(())
}

#[allow(clippy::many_single_char_names)] // z, y, x and the block's shape read as in the other passes
/// The largest eight components other than `keep`, as regions of removed voxels with
/// their first voxel in C order.
pub fn first_voxels(
    store: &dyn BlockStore<u8>,
    comps: &Components,
    pred: fn(u8) -> bool,
    keep: u32,
    workers: usize,
) -> Result<Vec<super::repair::Region>, crate::Error> {
    let mut order: Vec<u32> = (0..comps.sizes.len() as u32)
        .filter(|&c| c != keep)
        .collect();
    order.sort_by_key(|&c| (std::cmp::Reverse(comps.sizes[c as usize]), c));
    order.truncate(8);
    let spec = store.spec();
    let per_block = map_bounded(&spec.block_indices(), workers, |&b| {
        let data = store.read_block(b)?;
        let s = spec.block_shape(b).map(|c| c as usize);
        let (labels, n) = label_block(&data, s, pred);
        let bl = spec.block_linear(b) as usize;
        let st = spec.block_start(b);
        let mut found: Vec<(u32, Idx3)> = Vec::new();
        if n > 0 {
            let mut o = 0;
            for z in 0..s[0] {
                for y in 0..s[1] {
                    for x in 0..s[2] {
                        let l = labels[o];
                        o += 1;
                        if l != 0 {
                            let c = comps.of(bl, l);
                            if order.contains(&c) && !found.iter().any(|f| f.0 == c) {
                                found.push((
                                    c,
                                    [st[0] + z as u64, st[1] + y as u64, st[2] + x as u64],
                                ));
                            }
                        }
                    }
                }
            }
        }
        Ok::<_, crate::Error>(found)
    })?;
    let mut first: Vec<Option<Idx3>> = vec![None; order.len()];
    for (c, v) in per_block.into_iter().flatten() {
        let k = order.iter().position(|&o| o == c).expect("wanted");
        if first[k].is_none_or(|f| v < f) {
            first[k] = Some(v);
        }
    }
    Ok(order
        .iter()
        .zip(first)
        .filter_map(|(&c, f)| {
            f.map(|voxel| super::repair::Region {
                added: false,
                voxels: comps.sizes[c as usize],
                voxel,
            })
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_in_scan_order_with_merges() {
        // A U shape in one slice: two arms that join at the bottom row.
        #[rustfmt::skip]
        let d: Vec<u8> = vec![
            1, 0, 1,
            1, 0, 1,
            1, 1, 1,
            0, 0, 0,
            1, 0, 0,
        ];
        let (l, n) = label_block(&d, [1, 5, 3], |v| v == 1);
        assert_eq!(n, 2);
        assert_eq!(l[0], 1);
        assert_eq!(l[2], 1, "the arms join below");
        assert_eq!(l[12], 2);
    }
}
