//! The check that the center ball lies inside the solid, off its boundary.

use super::{CenterBall, VoxelizeError};
use crate::grid::BlockStore;
use crate::math::Idx3;

/// Check that every voxel of the center ball is solid and not on the boundary, given
/// `depth`, the distance from the center voxel to the nearest non-solid voxel.
///
/// Every voxel closer than `depth` is solid, so a ball with `radius + 1 < depth` is
/// fine and one with `radius >= depth` holds a non-solid voxel. Only in between are
/// the voxels looked at, three slices of the ball's box at a time.
pub(super) fn check_center_ball(
    solid: &dyn BlockStore<u8>,
    c: Idx3,
    radius: f64,
    depth: f64,
) -> Result<(), crate::Error> {
    let fail = |at: String| -> crate::Error {
        let advice = if radius >= 1.0 {
            "use a smaller --center-radius, another --center, or a finer --resolution"
        } else {
            "use another --center or a finer --resolution"
        };
        VoxelizeError::Center(format!(
            "the center ball (radius {radius} voxels around voxel [{}, {}, {}]) reaches the boundary{at}: the solid is {depth:.1} voxels deep there; {advice}",
            c[0], c[1], c[2]
        ))
        .into()
    };
    if radius + 1.0 < depth {
        return Ok(());
    }
    if radius >= depth {
        return Err(fail(String::new()));
    }
    let r = radius.ceil() as i64 + 1;
    let n = (2 * r + 1) as usize;
    let ball = CenterBall::at_voxel(c, radius);
    let ci = c.map(|v| v as i64);
    for dz in -r + 1..r {
        let slab = solid.read_region([ci[0] + dz - 1, ci[1] - r, ci[2] - r], [3, n, n], 0)?;
        for dy in -r + 1..r {
            for dx in -r + 1..r {
                let g = [ci[0] + dz, ci[1] + dy, ci[2] + dx];
                if !ball.contains(g) {
                    continue;
                }
                let nbrs = [
                    [0, 0, 0],
                    [1, 0, 0],
                    [-1, 0, 0],
                    [0, 1, 0],
                    [0, -1, 0],
                    [0, 0, 1],
                    [0, 0, -1],
                ];
                if nbrs
                    .iter()
                    .any(|d| slab.at_global([g[0] + d[0], g[1] + d[1], g[2] + d[2]]) != 1)
                {
                    return Err(fail(format!(" at voxel [{}, {}, {}]", g[0], g[1], g[2])));
                }
            }
        }
    }
    Ok(())
}
