//! The coarse levels of the hierarchy: their shapes (vertex-centered: coarse node `I`
//! sits on fine node `2I`) and their masks (a coarse node is an unknown when the fine
//! node under it is one and it is not on the level's edge).

use super::blocks::BlockLoop;
use super::cuts::is_unknown;
use super::level::Level;
use crate::grid::{BlockStore, GridError, GridSpec, Reach};
use crate::math::Idx3;
use crate::voxelize::labels::INTERIOR;

/// The shape of the level below `shape`: nodes at even fine indices.
#[must_use]
pub fn coarse_shape(shape: Idx3) -> Idx3 {
    shape.map(|n| (n - 1) / 2 + 1)
}

/// The specs of the coarse levels below `fine` (chunk: half the fine chunk, at least
/// 16), down to one whose longest axis is at most `coarsest` voxels.
#[must_use]
pub fn coarse_specs(fine: &GridSpec, coarsest: u64) -> Vec<GridSpec> {
    let mut out = Vec::new();
    let mut s = fine.clone();
    while s.shape.iter().copied().max().unwrap_or(0) > coarsest.max(3)
        || (out.is_empty() && s.shape.iter().all(|&n| n >= 5))
    {
        let shape = coarse_shape(s.shape);
        let chunk = [0, 1, 2].map(|a| (fine.chunk[a] / 2).max(16).min(shape[a]));
        s = GridSpec {
            shape,
            origin: s.origin,
            spacing: s.spacing * 2.0,
            chunk,
            unit: s.unit.clone(),
        };
        out.push(s.clone());
    }
    out
}

/// Write the mask of the coarse level `spec` into `mask`, from the mask of the level
/// `above` it; then exchange it.
pub fn coarsen_mask(
    above: &Level,
    spec: &GridSpec,
    mask: &dyn BlockStore<u8>,
    field: &str,
    reach: &Reach,
    blocks: &BlockLoop<'_>,
) -> Result<(), GridError> {
    blocks.each(spec, |cb| {
        let cs = spec.block_start(cb).map(|c| 2 * c as i64);
        let csh = spec.block_shape(cb).map(|c| c as usize);
        let fine = above.mask.read_region(cs, csh.map(|c| 2 * c - 1), 0)?;
        let mut m = Vec::with_capacity(csh.iter().product());
        for z in 0..csh[0] {
            for y in 0..csh[1] {
                for x in 0..csh[2] {
                    let v = fine.data[fine.offset(2 * z, 2 * y, 2 * x)];
                    // Nodes on the level's edge stay fixed, so every unknown
                    // has its six neighbours inside the grid.
                    let g = [z, y, x].map(|c| c as u64);
                    let edge = (0..3).any(|a| {
                        let c = spec.block_start(cb)[a] + g[a];
                        c == 0 || c + 1 >= spec.shape[a]
                    });
                    m.push(if is_unknown(v) && !edge { INTERIOR } else { 0 });
                }
            }
        }
        mask.write_block(cb, &m)
    })?;
    blocks.exchange(field, mask, reach)
}
