//! The direction field the upwind map fills: one f32 store per component, and what
//! "has a direction" means for a voxel.

use glam::DVec3;

use super::HALO;
use crate::grid::{BlockStore, GridError, Residence};
use crate::math::{volume, Idx3};

/// Whether a label takes part in the map (boundary, interior, center).
#[must_use]
#[inline]
pub fn is_target(label: u8) -> bool {
    matches!(label, 1..=3)
}

/// The direction field: one f32 store per component, in memory or in scratch files.
/// (0, 0, 0) means "no value yet" (both start zero-filled).
pub struct Directions {
    /// x, y and z components.
    pub c: [Box<dyn BlockStore<f32>>; 3],
}

impl Directions {
    /// Bytes the field takes for `spec`.
    #[must_use]
    pub fn bytes(spec: &crate::grid::GridSpec) -> u64 {
        12 * spec.num_blocks() * volume(spec.chunk)
    }

    /// In memory when `in_memory`, else scratch files `dir/{x,y,z}.f32`.
    pub fn create(
        dir: &std::path::Path,
        spec: &crate::grid::GridSpec,
        in_memory: bool,
    ) -> Result<Self, GridError> {
        let mk = |n: &str| -> Result<Box<dyn BlockStore<f32>>, GridError> {
            let path = dir.join(format!("{n}.f32"));
            let at = if in_memory {
                Residence::Blocks
            } else {
                Residence::File(&path)
            };
            crate::grid::scratch(spec, 0.0f32, at)
        };
        Ok(Self {
            c: [mk("x")?, mk("y")?, mk("z")?],
        })
    }

    /// Block `b` with a halo of [`HALO`], one [x, y, z] per voxel (a visit reads all
    /// three components of a voxel together).
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    pub(super) fn read_halo(&self, b: Idx3) -> Result<Vec<[f32; 3]>, GridError> {
        self.read_halo_of(b, HALO as usize)
    }

    /// Block `b` with a halo of `halo` voxels (all zero outside the grid), one [x, y, z]
    /// per voxel.
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    pub fn read_halo_of(&self, b: Idx3, halo: usize) -> Result<Vec<[f32; 3]>, GridError> {
        let r = |i: usize| -> Result<Vec<f32>, GridError> {
            Ok(self.c[i].read_block_halo(b, halo, 0.0)?.data)
        };
        let [x, y, z] = [r(0)?, r(1)?, r(2)?];
        Ok((0..x.len()).map(|i| [x[i], y[i], z[i]]).collect())
    }

    /// The x, y and z components of block `b` (all three zero where there is no value).
    pub fn read(&self, b: Idx3) -> Result<[Vec<f32>; 3], GridError> {
        Ok([
            self.c[0].read_block(b)?,
            self.c[1].read_block(b)?,
            self.c[2].read_block(b)?,
        ])
    }

    /// Write the directions of block `b` (None: no value).
    pub fn write(&self, b: Idx3, d: &[Option<DVec3>]) -> Result<(), GridError> {
        for (a, store) in self.c.iter().enumerate() {
            let comp: Vec<f32> = d.iter().map(|v| v.map_or(0.0, |v| v[a] as f32)).collect();
            store.write_block(b, &comp)?;
        }
        Ok(())
    }
}

/// Whether voxel `i` of a halo block has a direction.
#[inline]
pub(super) fn known(d: &[[f32; 3]], i: usize) -> bool {
    is_set(d[i])
}

/// Whether a direction (x, y, z) is set: (0, 0, 0) means "no value".
#[must_use]
#[inline]
pub fn is_set(v: [f32; 3]) -> bool {
    v.iter().any(|&c| c != 0.0)
}

/// The direction of voxel `i` of a halo block (zero where it has none).
#[inline]
pub(super) fn get(d: &[[f32; 3]], i: usize) -> DVec3 {
    DVec3::from_array(d[i].map(f64::from))
}
