//! Solid occupancy of a label volume input ("anything > 0 is inside"), block by block,
//! shifted by the padding.

use crate::grid::{BlockStore, Decomposition};
use crate::input::LabelVolume;
use crate::parallel::map_bounded;
use crate::progress::Progress;

/// Write 1 where the volume is > 0 and 0 elsewhere (including the padding), on the
/// blocks `decomp` gives this process.
pub fn volume_solid(
    volume: &LabelVolume,
    padding: u64,
    out: &dyn BlockStore<u8>,
    workers: usize,
    progress: &dyn Progress,
    decomp: &dyn Decomposition,
) -> Result<(), crate::Error> {
    let spec = out.spec();
    let vs = volume.shape();
    let blocks = decomp.owned(spec);
    progress.start("voxelize: reading the label volume", blocks.len() as u64);
    map_bounded(&blocks, workers, |&b| -> Result<(), crate::Error> {
        // A stop request (Ctrl-C) ends the pass at the next block.
        crate::progress::check_interrupt(progress)?;
        let start = spec.block_start(b);
        let shape = spec.block_shape(b);
        // The block's box in volume coordinates, clipped to the volume.
        let lo = [0, 1, 2].map(|a| start[a].max(padding) - padding);
        let hi = [0, 1, 2].map(|a| (start[a] + shape[a]).saturating_sub(padding).min(vs[a]));
        let mut data = vec![0u8; (shape[0] * shape[1] * shape[2]) as usize];
        if (0..3).all(|a| lo[a] < hi[a]) {
            let size = [0, 1, 2].map(|a| hi[a] - lo[a]);
            let inside = volume.read_inside(lo, size)?;
            let s = shape.map(|c| c as usize);
            let mut it = inside.into_iter();
            for z in 0..size[0] {
                for y in 0..size[1] {
                    for x in 0..size[2] {
                        let l = [
                            lo[0] + z + padding - start[0],
                            lo[1] + y + padding - start[1],
                            lo[2] + x + padding - start[2],
                        ]
                        .map(|c| c as usize);
                        data[(l[0] * s[1] + l[1]) * s[2] + l[2]] =
                            u8::from(it.next().unwrap_or(false));
                    }
                }
            }
        }
        out.write_block(b, &data)?;
        progress.advance(1);
        Ok(())
    })?;
    progress.finish();
    Ok(())
}
