//! Euler characteristic of the voxel solid under 6-connectivity, block by block.
//!
//! The solid is the cubical complex whose vertices are solid voxels, edges join
//! 6-neighbours, squares are 2x2 solid squares and cubes 2x2x2 solid cubes; its
//! components are the 6-components of the solid and its cavities the 26-components of
//! the background. chi = V - E + F - C, each cell counted at its lowest corner, so a
//! block needs one voxel of halo on its high sides. For one component without cavities,
//! genus = 1 - chi.

use crate::grid::BlockStore;
use crate::parallel::map_bounded;

/// Euler characteristic of `{v == 1}` over the grid.
pub fn euler_characteristic(
    store: &dyn BlockStore<u8>,
    workers: usize,
) -> Result<i64, crate::Error> {
    let spec = store.spec();
    let blocks = spec.block_indices();
    let parts = map_bounded(&blocks, workers, |&b| -> Result<i64, crate::Error> {
        let start = spec.block_start(b);
        let s = spec.block_shape(b).map(|c| c as usize);
        let region = store.read_region(start.map(|c| c as i64), s.map(|c| c + 1), 0)?;
        let [_, ry, rx] = region.shape;
        let d = &region.data;
        let at = |z: usize, y: usize, x: usize| i64::from(d[(z * ry + y) * rx + x] == 1);
        Ok(cells_chi(s, at))
    })?;
    Ok(parts.iter().sum())
}

/// V - E + F - C of the cells whose lowest corner lies in `[0, s)`, where `at(z, y, x)`
/// is 1 for a solid voxel and 0 otherwise (it is asked one voxel past `s` on the high
/// sides).
pub(super) fn cells_chi(s: [usize; 3], at: impl Fn(usize, usize, usize) -> i64) -> i64 {
    let mut chi = 0i64;
    for z in 0..s[0] {
        for y in 0..s[1] {
            for x in 0..s[2] {
                if at(z, y, x) == 0 {
                    continue;
                }
                let (ax, ay, az) = (at(z, y, x + 1), at(z, y + 1, x), at(z + 1, y, x));
                let sxy = ax * ay * at(z, y + 1, x + 1);
                let sxz = ax * az * at(z + 1, y, x + 1);
                let syz = ay * az * at(z + 1, y + 1, x);
                let cube = sxy * sxz * syz * at(z + 1, y + 1, x + 1);
                chi += 1 - (ax + ay + az) + (sxy + sxz + syz) - cube;
            }
        }
    }
    chi
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::{FileStore, GridSpec};

    fn store_with(
        shape: [u64; 3],
        solid: impl Fn(u64, u64, u64) -> bool + Sync + Send,
    ) -> (tempfile::TempDir, FileStore<u8>) {
        let dir = tempfile::tempdir().unwrap();
        let spec = GridSpec {
            shape,
            origin: [0.0; 3],
            spacing: 1.0,
            chunk: [4, 4, 4],
            unit: None,
        };
        let s = FileStore::<u8>::create(&dir.path().join("s"), spec.clone()).unwrap();
        crate::grid::fill_with(&s, 1, |[z, y, x]| u8::from(solid(z, y, x))).unwrap();
        (dir, s)
    }

    #[test]
    fn ball_and_torus() {
        let (_d, ball) = store_with([12, 12, 12], |z, y, x| {
            let r2 = [z, y, x]
                .iter()
                .map(|&c| (c as f64 - 5.5).powi(2))
                .sum::<f64>();
            r2 < 16.0
        });
        assert_eq!(euler_characteristic(&ball, 2).unwrap(), 1);
        // A square ring, 2 voxels thick, crossing block edges: genus 1.
        let (_d, ring) = store_with([10, 10, 10], |z, y, x| {
            (3..5).contains(&z)
                && (1..9).contains(&y)
                && (1..9).contains(&x)
                && !((3..7).contains(&y) && (3..7).contains(&x))
        });
        assert_eq!(euler_characteristic(&ring, 1).unwrap(), 0);
        // A hollow box: one component with one cavity, chi = 2.
        let (_d, shell) = store_with([9, 9, 9], |z, y, x| {
            let inb = |c: u64| (1..8).contains(&c);
            let core = |c: u64| (3..6).contains(&c);
            inb(z) && inb(y) && inb(x) && !(core(z) && core(y) && core(x))
        });
        assert_eq!(euler_characteristic(&shell, 2).unwrap(), 2);
    }
}
