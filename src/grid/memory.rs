//! In-memory backend: one owned vector per block (or the planes of it that were
//! given). For tests, small grids, and a rank's slab of a level with its halos.

use std::sync::RwLock;

use super::store::{block_in_box, check_block, RowInspector};
use super::{copy_overlap, to_usize, Block, BlockStore, GridError, GridSpec, Scalar};
use crate::math::{volume, Idx3};

/// A grid held in memory, block by block.
///
/// A block is held whole once written whole; a block only ever given some of its planes
/// ([`BlockStore::write_planes`], a halo another process sent) holds those planes alone
/// (the smallest range of planes covering all it was given), and reads as the fill
/// value elsewhere. So a process holding a slab of a grid and the halo planes around it
/// holds no more than that.
pub struct MemStore<T> {
    spec: GridSpec,
    fill: T,
    blocks: Vec<RwLock<Option<Held<T>>>>,
}

/// What a block holds: its planes `z` (all of them once written whole), in C order.
struct Held<T> {
    z: std::ops::Range<usize>,
    data: Vec<T>,
}

impl<T: Scalar> MemStore<T> {
    /// An empty grid; unwritten blocks read as `fill`.
    #[must_use]
    pub fn new(spec: GridSpec, fill: T) -> Self {
        let n = spec.num_blocks() as usize;
        Self {
            spec,
            fill,
            blocks: (0..n).map(|_| RwLock::new(None)).collect(),
        }
    }

    fn slot(&self, b: Idx3) -> &RwLock<Option<Held<T>>> {
        &self.blocks[self.spec.block_linear(b) as usize]
    }

    /// The block `b` of `held` (its planes `z`) as a whole block, the fill value in the
    /// planes it does not hold.
    fn widen(&self, b: Idx3, held: &Held<T>) -> Vec<T> {
        let sh = to_usize(self.spec.block_shape(b));
        let plane = sh[1] * sh[2];
        let mut v = vec![self.fill; sh.iter().product()];
        v[held.z.start * plane..held.z.end * plane].copy_from_slice(&held.data);
        v
    }
}

impl<T: Scalar> BlockStore<T> for MemStore<T> {
    fn spec(&self) -> &GridSpec {
        &self.spec
    }

    fn read_block(&self, b: Idx3) -> Result<Vec<T>, GridError> {
        check_block::<T>(&self.spec, b, None)?;
        let slot = self.slot(b).read().expect("lock");
        let sh = to_usize(self.spec.block_shape(b));
        Ok(match &*slot {
            Some(h) if h.z == (0..sh[0]) => h.data.clone(),
            Some(h) => self.widen(b, h),
            None => vec![self.fill; sh.iter().product()],
        })
    }

    fn write_block(&self, b: Idx3, data: &[T]) -> Result<(), GridError> {
        check_block(&self.spec, b, Some(data))?;
        let mut slot = self.slot(b).write().expect("lock");
        let all = 0..self.spec.block_shape(b)[0] as usize;
        // Overwrite in place: no allocation churn for stores rewritten every pass.
        match &mut *slot {
            Some(h) if h.z == all => h.data.copy_from_slice(data),
            _ => {
                *slot = Some(Held {
                    z: all,
                    data: data.to_vec(),
                });
            }
        }
        Ok(())
    }

    fn write_planes(&self, b: Idx3, z: std::ops::Range<u64>, data: &[T]) -> Result<(), GridError> {
        check_block::<T>(&self.spec, b, None)?;
        let sh = to_usize(self.spec.block_shape(b));
        let plane = sh[1] * sh[2];
        let z = z.start as usize..z.end as usize;
        if z.end > sh[0] || z.start > z.end || data.len() != z.len() * plane {
            return Err(GridError::BlockSize {
                block: b,
                expected: z.end.min(sh[0]).saturating_sub(z.start) * plane,
                got: data.len(),
            });
        }
        let mut slot = self.slot(b).write().expect("lock");
        let mut held = match slot.take() {
            None => Held {
                z: z.clone(),
                data: data.to_vec(),
            },
            Some(h) if h.z.start <= z.start && z.end <= h.z.end => h,
            Some(h) => {
                // Grow to the smallest range of planes covering both.
                let (lo, hi) = (h.z.start.min(z.start), h.z.end.max(z.end));
                let mut v = vec![self.fill; (hi - lo) * plane];
                v[(h.z.start - lo) * plane..(h.z.end - lo) * plane].copy_from_slice(&h.data);
                Held { z: lo..hi, data: v }
            }
        };
        let at = (z.start - held.z.start) * plane;
        held.data[at..at + data.len()].copy_from_slice(data);
        *slot = Some(held);
        Ok(())
    }

    fn write_block_from(
        &self,
        b: Idx3,
        src: &Block<T>,
        mut inspect: Option<RowInspector<'_, T>>,
    ) -> Result<(), GridError> {
        check_block::<T>(&self.spec, b, None)?;
        let (lo, shape) = block_in_box(&self.spec, b, src);
        let mut slot = self.slot(b).write().expect("lock");
        let dst = match slot.take() {
            Some(h) if h.z == (0..shape[0]) => h.data,
            Some(h) => self.widen(b, &h),
            None => vec![self.fill; shape.iter().product()],
        };
        let dst = &mut slot
            .insert(Held {
                z: 0..shape[0],
                data: dst,
            })
            .data;
        // Row by row from the box into the block, under its write lock.
        for z in 0..shape[0] {
            for y in 0..shape[1] {
                let r = z * shape[1] + y;
                let o = src.offset(lo[0] + z, lo[1] + y, lo[2]);
                let new = &src.data[o..o + shape[2]];
                let old = &mut dst[r * shape[2]..(r + 1) * shape[2]];
                if let Some(f) = inspect.as_mut() {
                    f(r, old, new);
                }
                old.copy_from_slice(new);
            }
        }
        Ok(())
    }

    fn read_region(
        &self,
        origin: [i64; 3],
        shape: [usize; 3],
        outside: T,
    ) -> Result<Block<T>, GridError> {
        // Copy only the overlapping rows of each block, under its read lock.
        let spec = &self.spec;
        let mut out = Block::filled(origin, shape, outside);
        for b in spec.blocks_overlapping(origin, shape) {
            let slot = self.slot(b).read().expect("lock");
            let s = spec.block_start(b).map(|v| v as i64);
            let sh = to_usize(spec.block_shape(b));
            match &*slot {
                Some(h) if h.z == (0..sh[0]) || self.fill == outside => {
                    // Where a block holds some planes only, the rest reads as the fill,
                    // which is what the box was filled with.
                    let at = [s[0] + h.z.start as i64, s[1], s[2]];
                    copy_overlap(&h.data, at, [h.z.len(), sh[1], sh[2]], &mut out);
                }
                Some(h) => copy_overlap(&self.widen(b, h), s, sh, &mut out),
                None if self.fill != outside => {
                    let f = vec![self.fill; volume(spec.block_shape(b)) as usize];
                    copy_overlap(&f, s, to_usize(spec.block_shape(b)), &mut out);
                }
                None => {}
            }
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Planes given to blocks, in any order and overlap, then whole writes and box
    /// writes over them: every read (block, region, with either outside value) sees
    /// what a whole-grid array given the same writes holds, the fill elsewhere.
    #[test]
    fn planes_read_back_as_a_whole_array_would() {
        let spec = GridSpec {
            shape: [10, 3, 4],
            origin: [0.0; 3],
            spacing: 1.0,
            chunk: [4, 3, 4],
            unit: None,
        };
        let fill = 7.0f64;
        let store = MemStore::new(spec.clone(), fill);
        let mut model = vec![fill; 10 * 12];
        let plane = 12;
        let mut next = 0.0;
        let mut put =
            |store: &MemStore<f64>, model: &mut Vec<f64>, b: u64, z: std::ops::Range<u64>| {
                let n = (z.end - z.start) as usize * plane;
                let data: Vec<f64> = (0..n).map(|i| next + i as f64).collect();
                next += 1000.0;
                store.write_planes([b, 0, 0], z.clone(), &data).unwrap();
                let z0 = spec.block_start([b, 0, 0])[0] as usize + z.start as usize;
                model[z0 * plane..z0 * plane + n].copy_from_slice(&data);
            };
        let check = |store: &MemStore<f64>, model: &[f64]| {
            for b in 0..3u64 {
                let (z0, h) = (4 * b as usize, spec.block_shape([b, 0, 0])[0] as usize);
                let got = store.read_block([b, 0, 0]).unwrap();
                assert_eq!(got, model[z0 * plane..(z0 + h) * plane]);
            }
            for outside in [fill, -1.0] {
                let r = store.read_region([-1, 0, 0], [12, 3, 4], outside).unwrap();
                for z in 0..12usize {
                    let want = if z == 0 || z == 11 {
                        vec![outside; plane]
                    } else {
                        model[(z - 1) * plane..z * plane].to_vec()
                    };
                    assert_eq!(r.data[z * plane..(z + 1) * plane], want, "plane {z}");
                }
            }
        };
        check(&store, &model);
        put(&store, &mut model, 0, 3..4);
        check(&store, &model);
        put(&store, &mut model, 0, 1..2);
        check(&store, &model);
        put(&store, &mut model, 0, 2..4);
        put(&store, &mut model, 2, 0..2);
        check(&store, &model);
        // A whole write, then planes into it; a box write over a block with planes.
        let whole: Vec<f64> = (0..4 * plane).map(|i| -(i as f64)).collect();
        store.write_block([1, 0, 0], &whole).unwrap();
        model[4 * plane..8 * plane].copy_from_slice(&whole);
        put(&store, &mut model, 1, 1..3);
        check(&store, &model);
        let mut bx = Block::filled([0, 0, 0], [4, 3, 4], 0.5);
        bx.data[5] = 9.0;
        store.write_block_from([0, 0, 0], &bx, None).unwrap();
        model[..4 * plane].copy_from_slice(&bx.data);
        check(&store, &model);
        assert!(store.write_planes([2, 0, 0], 1..3, &[0.0; 12]).is_err());
    }
}
