//! The label pass: solid occupancy -> the labels of DESIGN.md, block by block.
//!
//! - solid with a non-solid 6-neighbour: [`BOUNDARY`];
//! - solid within the center ball: [`CENTER`]; other solid: [`INTERIOR`];
//! - non-solid at 6-connected (L1) distance k <= 4 from the solid: [`LAYER1`] + k - 1;
//! - everything else: [`EXTERIOR`].
//!
//! A block is read with a halo of 4 voxels (the deepest exterior layer).

use super::labels::{BOUNDARY, CENTER, EXTERIOR, INTERIOR, LAYER1};
use crate::grid::{BlockStore, ZarrStore};
use crate::math::Idx3;
use crate::parallel::map_bounded;
use crate::progress::Progress;

/// Halo the label pass reads around each block.
pub const HALO: usize = 4;

/// The center ball: voxels within `radius` voxels of `voxel`.
#[derive(Clone, Copy, Debug)]
pub struct CenterBall {
    /// Center in voxel coordinates `[z, y, x]` (a voxel index, or between voxels).
    pub center: [f64; 3],
    /// Radius in voxels.
    pub radius: f64,
}

impl CenterBall {
    /// The ball around voxel `v`.
    #[must_use]
    pub fn at_voxel(v: Idx3, radius: f64) -> Self {
        Self {
            center: v.map(|c| c as f64),
            radius,
        }
    }

    /// Whether voxel `g` lies in the ball.
    #[must_use]
    pub fn contains(&self, g: [i64; 3]) -> bool {
        let d2: f64 = (0..3).map(|a| (g[a] as f64 - self.center[a]).powi(2)).sum();
        d2 <= self.radius * self.radius + 1e-9
    }
}

/// Whether the center ball may reach the block at `start` of extent `s`.
fn ball_near(ball: &CenterBall, start: [u64; 3], s: [usize; 3]) -> bool {
    (0..3).all(|a| {
        let c = ball.center[a];
        c + ball.radius >= start[a] as f64 && c - ball.radius <= (start[a] as usize + s[a]) as f64
    })
}

/// Write the labels of every block of `solid` into `labels`; returns the count of each
/// label value 0..=7.
pub fn classify(
    solid: &dyn BlockStore<u8>,
    labels: &ZarrStore<u8>,
    ball: CenterBall,
    workers: usize,
    progress: &dyn Progress,
) -> Result<[u64; 8], crate::Error> {
    let spec = solid.spec();
    let blocks = spec.block_indices();
    progress.start("voxelize: labels", blocks.len() as u64);
    let counts = map_bounded(&blocks, workers, |&b| -> Result<[u64; 8], crate::Error> {
        crate::progress::check_interrupt(progress)?;
        let r = solid.read_block_halo(b, HALO, 0)?;
        let [hz, hy, hx] = r.shape;
        let s = spec.block_shape(b).map(|c| c as usize);
        let n = s[0] * s[1] * s[2];
        // Far from the solid every voxel is exterior; deep inside, interior (but for the
        // center ball, which the general path handles).
        let all_solid = r.data.iter().all(|&v| v == 1);
        if r.data.iter().all(|&v| v != 1)
            || (all_solid && !ball_near(&ball, spec.block_start(b), s))
        {
            let label = if all_solid { INTERIOR } else { EXTERIOR };
            labels.write_block(b, &vec![label; n])?;
            let mut counts = [0u64; 8];
            counts[label as usize] = n as u64;
            progress.advance(1);
            return Ok(counts);
        }
        // L1 distance to the solid, up to HALO, over the haloed box.
        let mut dist: Vec<u8> = r
            .data
            .iter()
            .map(|&v| if v == 1 { 0 } else { u8::MAX })
            .collect();
        for k in 1..=HALO as u8 {
            let prev = dist.clone();
            for z in 1..hz - 1 {
                for y in 1..hy - 1 {
                    for x in 1..hx - 1 {
                        let i = (z * hy + y) * hx + x;
                        if prev[i] != u8::MAX {
                            continue;
                        }
                        let n = [i - 1, i + 1, i - hx, i + hx, i - hx * hy, i + hx * hy];
                        if n.iter().any(|&j| prev[j] == k - 1) {
                            dist[i] = k;
                        }
                    }
                }
            }
        }
        let mut out = Vec::with_capacity(s[0] * s[1] * s[2]);
        let mut counts = [0u64; 8];
        let start = spec.block_start(b);
        for z in 0..s[0] {
            for y in 0..s[1] {
                for x in 0..s[2] {
                    let i = ((z + HALO) * hy + y + HALO) * hx + x + HALO;
                    let label = if r.data[i] == 1 {
                        let n = [i - 1, i + 1, i - hx, i + hx, i - hx * hy, i + hx * hy];
                        if n.iter().any(|&j| r.data[j] != 1) {
                            BOUNDARY
                        } else if ball.contains([
                            (start[0] as usize + z) as i64,
                            (start[1] as usize + y) as i64,
                            (start[2] as usize + x) as i64,
                        ]) {
                            CENTER
                        } else {
                            INTERIOR
                        }
                    } else if dist[i] as usize <= HALO {
                        LAYER1 + dist[i] - 1
                    } else {
                        EXTERIOR
                    };
                    counts[label as usize] += 1;
                    out.push(label);
                }
            }
        }
        labels.write_block(b, &out)?;
        progress.advance(1);
        Ok(counts)
    })?;
    progress.finish();
    let mut total = [0u64; 8];
    for c in counts {
        for (t, v) in total.iter_mut().zip(c) {
            *t += v;
        }
    }
    Ok(total)
}

/// Bytes a worker of the label pass holds (haloed block, distances, output, codec).
pub(crate) fn worker_bytes(chunk: u64) -> u64 {
    let h = chunk + 2 * HALO as u64;
    3 * h * h * h + 3 * chunk * chunk * chunk
}
