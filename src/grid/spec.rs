//! `GridSpec`: the regular grid of a run and its world <-> voxel transforms.

use serde::{Deserialize, Serialize};

use crate::math::{volume, Idx3, Vec3};

/// A regular, isotropic grid cut into blocks (chunks).
///
/// Voxel `(k, j, i)` (axis order z, y, x) has its center at
/// `origin + spacing * (i, j, k)` in world units.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GridSpec {
    /// Voxels per axis, `[z, y, x]`.
    pub shape: Idx3,
    /// World position `(x, y, z)` of the center of voxel `(0, 0, 0)`.
    pub origin: [f64; 3],
    /// Distance between neighbouring voxel centers, world units.
    pub spacing: f64,
    /// Block (chunk) shape, `[z, y, x]`.
    pub chunk: Idx3,
    /// Unit of world coordinates, if known (an OME-Zarr unit name such as "angstrom").
    pub unit: Option<String>,
}

impl GridSpec {
    /// Number of voxels.
    #[must_use]
    pub fn num_voxels(&self) -> u64 {
        volume(self.shape)
    }

    /// Blocks per axis, `[z, y, x]`.
    #[must_use]
    pub fn blocks(&self) -> Idx3 {
        [0, 1, 2].map(|a| self.shape[a].div_ceil(self.chunk[a]))
    }

    /// Number of blocks.
    #[must_use]
    pub fn num_blocks(&self) -> u64 {
        volume(self.blocks())
    }

    /// Every block index in C order (z slowest). This order is the reduction order of
    /// all per-block partial results, which keeps results independent of threads.
    #[must_use]
    pub fn block_indices(&self) -> Vec<Idx3> {
        let b = self.blocks();
        let mut v = Vec::with_capacity(volume(b) as usize);
        for z in 0..b[0] {
            for y in 0..b[1] {
                for x in 0..b[2] {
                    v.push([z, y, x]);
                }
            }
        }
        v
    }

    /// Linear number of a block in C order.
    #[must_use]
    pub fn block_linear(&self, b: Idx3) -> u64 {
        let n = self.blocks();
        (b[0] * n[1] + b[1]) * n[2] + b[2]
    }

    /// First voxel of block `b`.
    #[must_use]
    pub fn block_start(&self, b: Idx3) -> Idx3 {
        [0, 1, 2].map(|a| b[a] * self.chunk[a])
    }

    /// Extent of block `b` (edge blocks are cut at the grid edge).
    #[must_use]
    pub fn block_shape(&self, b: Idx3) -> Idx3 {
        [0, 1, 2].map(|a| (self.shape[a] - b[a] * self.chunk[a]).min(self.chunk[a]))
    }

    /// World position `(x, y, z)` of the center of voxel `[z, y, x]`.
    #[must_use]
    pub fn voxel_center(&self, v: Idx3) -> Vec3 {
        Vec3::new(
            self.origin[0] + self.spacing * v[2] as f64,
            self.origin[1] + self.spacing * v[1] as f64,
            self.origin[2] + self.spacing * v[0] as f64,
        )
    }

    /// Continuous voxel coordinates `(i, j, k)` = (x, y, z) of a world point.
    #[must_use]
    pub fn world_to_voxel(&self, p: Vec3) -> Vec3 {
        (p - Vec3::from_array(self.origin)) / self.spacing
    }

    /// The voxel `[z, y, x]` whose center is nearest to world point `p`, if inside.
    #[must_use]
    pub fn nearest_voxel(&self, p: Vec3) -> Option<Idx3> {
        let c = self.world_to_voxel(p).round();
        let v = [c.z, c.y, c.x];
        if v.iter()
            .zip(self.shape)
            .all(|(&c, n)| c >= 0.0 && c < n as f64)
        {
            Some(v.map(|c| c as u64))
        } else {
            None
        }
    }

    /// The blocks that hold some voxel of the box `[origin, origin + shape)` (grid
    /// coordinates, possibly reaching off the grid), in C order.
    #[must_use]
    pub fn blocks_overlapping(&self, origin: [i64; 3], shape: [usize; 3]) -> Vec<Idx3> {
        let lo = [0, 1, 2].map(|a| origin[a].max(0));
        let hi = [0, 1, 2].map(|a| (origin[a] + shape[a] as i64).min(self.shape[a] as i64));
        if (0..3).any(|a| lo[a] >= hi[a]) {
            return Vec::new();
        }
        let c = self.chunk.map(|c| c as i64);
        let r = |a: usize| (lo[a] / c[a]) as u64..=((hi[a] - 1) / c[a]) as u64;
        r(0).flat_map(|z| r(1).flat_map(move |y| r(2).map(move |x| [z, y, x])))
            .collect()
    }

    /// Whether `v` is a valid voxel index.
    #[must_use]
    pub fn contains(&self, v: [i64; 3]) -> bool {
        (0..3).all(|a| v[a] >= 0 && (v[a] as u64) < self.shape[a])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec() -> GridSpec {
        GridSpec {
            shape: [10, 20, 130],
            origin: [1.0, 2.0, 3.0],
            spacing: 0.5,
            chunk: [8, 8, 64],
            unit: None,
        }
    }

    #[test]
    fn blocks_cover_the_grid_exactly() {
        let s = spec();
        assert_eq!(s.blocks(), [2, 3, 3]);
        let total: u64 = s
            .block_indices()
            .iter()
            .map(|&b| volume(s.block_shape(b)))
            .sum();
        assert_eq!(total, s.num_voxels());
        assert_eq!(s.block_shape([1, 2, 2]), [2, 4, 2]);
    }

    #[test]
    fn world_voxel_round_trip() {
        let s = spec();
        let v = [3, 7, 101];
        let p = s.voxel_center(v);
        assert_eq!(p, Vec3::new(1.0 + 50.5, 2.0 + 3.5, 3.0 + 1.5));
        assert_eq!(s.nearest_voxel(p), Some(v));
        assert_eq!(s.nearest_voxel(Vec3::new(-10.0, 0.0, 0.0)), None);
    }
}
