//! The coarse levels of the hierarchy: their shapes (vertex-centered: coarse node `I`
//! sits on fine node `2I`) and their masks (a coarse node is an unknown when the fine
//! node under it is one and it is not on the level's edge).

use super::blocks::BlockLoop;
use super::cuts::{is_unknown, CUT};
use super::level::Level;
use crate::grid::{BlockStore, GridError, GridSpec, Reach};
use crate::math::Idx3;
use crate::voxelize::cuts::{arm, encode};
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

/// The packed arms of the coarse node over the fine node at offset `i` of the fine
/// level's C-order arrays `mask` and `cuts` (strides `sy`, `sz`), in coarse voxels.
///
/// Along each of the six directions the coarse arm spans two fine ones: it ends where
/// the fine arm from the node itself ends (half its length), at the fine neighbour if
/// that is fixed (a half), or where the neighbour's arm onwards ends (a half plus half
/// of it); otherwise it is not cut and reads the coarse neighbour, as the staircase
/// does.
#[must_use]
pub fn coarse_arms(mask: &[u8], cuts: &[u64], i: usize, sy: usize, sz: usize) -> u64 {
    let step = [1, sy, sz];
    let mut t = [0.0; 6];
    for (k, t) in t.iter_mut().enumerate() {
        let s = step[k / 2];
        let n = if k % 2 == 1 { i + s } else { i - s };
        let own = arm(cuts[i], k);
        *t = if own > 0.0 {
            own / 2.0
        } else if !is_unknown(mask[n]) {
            0.5
        } else {
            let next = arm(cuts[n], k);
            if next > 0.0 {
                0.5 + next / 2.0
            } else {
                0.0
            }
        };
    }
    encode(t)
}

/// Write the mask of the coarse level `spec` into `mask`, from the mask of the level
/// `above` it, and where `above` has arms, the coarse level's arms into `arms`
/// ([`coarse_arms`]; the unknowns with a cut arm are marked [`CUT`]); then exchange
/// both.
pub fn coarsen_mask(
    above: &Level,
    spec: &GridSpec,
    (mask, arms): (&dyn BlockStore<u8>, Option<&dyn BlockStore<u64>>),
    field: &str,
    reach: &Reach,
    blocks: &BlockLoop<'_>,
) -> Result<(), GridError> {
    let fine_arms = above.cuts.as_deref().zip(arms);
    blocks.each(spec, |cb| {
        let cs = spec.block_start(cb).map(|c| 2 * c as i64);
        let csh = spec.block_shape(cb).map(|c| c as usize);
        // Fine nodes 2I - 1 ..= 2I + 1 (the arms look one fine node past 2I).
        let (origin, shape) = (cs.map(|c| c - 1), csh.map(|c| 2 * c + 1));
        let fine = above.mask.read_region(origin, shape, 0)?;
        let cut = match fine_arms {
            Some((f, _)) => Some(f.read_region(origin, shape, 0)?),
            None => None,
        };
        let (sy, sz) = (shape[2], shape[2] * shape[1]);
        let mut out = Vec::with_capacity(csh.iter().product());
        let mut packed = Vec::with_capacity(if cut.is_some() { out.capacity() } else { 0 });
        for z in 0..csh[0] {
            for y in 0..csh[1] {
                for x in 0..csh[2] {
                    let i = fine.offset(2 * z + 1, 2 * y + 1, 2 * x + 1);
                    let v = fine.data[i];
                    // Nodes on the level's edge stay fixed, so every unknown
                    // has its six neighbours inside the grid.
                    let g = [z, y, x].map(|c| c as u64);
                    let edge = (0..3).any(|a| {
                        let c = spec.block_start(cb)[a] + g[a];
                        c == 0 || c + 1 >= spec.shape[a]
                    });
                    let unknown = is_unknown(v) && !edge;
                    let arms = match &cut {
                        Some(c) if unknown => coarse_arms(&fine.data, &c.data, i, sy, sz),
                        _ => 0,
                    };
                    out.push(match (unknown, arms) {
                        (false, _) => 0,
                        (true, 0) => INTERIOR,
                        (true, _) => CUT,
                    });
                    if cut.is_some() {
                        packed.push(arms);
                    }
                }
            }
        }
        if let Some((_, a)) = fine_arms {
            a.write_block(cb, &packed)?;
        }
        mask.write_block(cb, &out)
    })?;
    blocks.exchange(field, mask, reach)?;
    if let Some((_, a)) = fine_arms {
        blocks.exchange(&field.replace("mask", "cuts"), a, reach)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Along x through a row of fine nodes 0..=4 (the coarse node over fine node 2),
    /// each way the coarse arm ends where the fine boundary does.
    #[test]
    fn coarse_arms_end_where_the_fine_boundary_does() {
        let n = 5;
        let row = |mask: [u8; 5], cuts: [[f64; 6]; 5]| {
            // One row along x in a 3 x 3 x 5 box: the row at y = z = 1.
            let (sy, sz) = (n, 3 * n);
            let mut m = vec![INTERIOR; 3 * sz];
            let mut c = vec![0u64; 3 * sz];
            for x in 0..n {
                m[sz + sy + x] = mask[x];
                c[sz + sy + x] = encode(cuts[x]);
            }
            let p = coarse_arms(&m, &c, sz + sy + 2, sy, sz);
            (arm(p, 0), arm(p, 1))
        };
        let none = [0.0; 6];
        // Quantized twice: the fine arms and the coarse ones.
        let q = 1.0 / 1023.0;
        // The node's own x+ arm cut at 0.4: the coarse arm is 0.2; x- not cut.
        let (l, r) = row(
            [INTERIOR; 5],
            [none, none, [0.0, 0.4, 0.0, 0.0, 0.0, 0.0], none, none],
        );
        assert!((r - 0.2).abs() < q && l == 0.0, "{l} {r}");
        // The neighbour's x+ arm cut at 0.6: 0.5 + 0.3; a fixed node at x- : 0.5.
        let (l, r) = row(
            [INTERIOR, 0, INTERIOR, INTERIOR, INTERIOR],
            [none, none, none, [0.0, 0.6, 0.0, 0.0, 0.0, 0.0], none],
        );
        assert!((r - 0.8).abs() < q && (l - 0.5).abs() < q, "{l} {r}");
    }
}
