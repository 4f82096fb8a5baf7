//! OpenDX scalar field (text), as APBS writes them (counts nx ny nz, z fastest): for
//! VMD, PyMOL and APBS tools. The first line, a comment ending in `(harmap)`, marks the
//! file as harmap's own export.
// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

use std::io::Write;

use super::source::Source;
use super::Field;
use crate::export::Staged;
use crate::grid::{GridSpec, MemBudget};
use crate::progress::Progress;
use crate::run::RunDir;

/// Write `field` of `run` (opened as `src`) to `out`, in columns of constant x as wide as
/// half of `mem` holds.
pub(super) fn write(
    out: &mut Staged,
    run: &RunDir,
    spec: &GridSpec,
    field: Field,
    src: &Source,
    mem: MemBudget,
    progress: &dyn Progress,
) -> Result<(), crate::Error> {
    let n = spec.num_voxels();
    let s = spec.shape;
    let o = spec.origin;
    let h = spec.spacing;
    let head = format!(
        "# {} of {} (harmap)\n\
         object 1 class gridpositions counts {nx} {ny} {nz}\n\
         origin {} {} {}\n\
         delta {h} 0 0\ndelta 0 {h} 0\ndelta 0 0 {h}\n\
         object 2 class gridconnections counts {nx} {ny} {nz}\n\
         object 3 class array type double rank 0 items {n} data follows\n",
        field.name(),
        run.root().display(),
        o[0],
        o[1],
        o[2],
        nx = s[2],
        ny = s[1],
        nz = s[0],
    );
    out.out.write_all(head.as_bytes()).map_err(|e| out.io(e))?;
    // x slowest: planes of constant x, as many as half the budget holds.
    let per_x = s[0] * s[1] * 40;
    let w = (mem.work_bytes() / 2 / per_x.max(1)).clamp(1, spec.chunk[2]);
    progress.start(&format!("export {}", field.name()), s[2]);
    let mut col = 0;
    let mut x0 = 0;
    while x0 < s[2] {
        let wx = w.min(s[2] - x0);
        let vals = src.x_slab_text(spec, x0, wx)?;
        let mut buf = String::with_capacity(vals.len() * 14);
        for v in vals {
            buf.push_str(&v);
            col += 1;
            buf.push(if col % 3 == 0 { '\n' } else { ' ' });
        }
        out.out.write_all(buf.as_bytes()).map_err(|e| out.io(e))?;
        x0 += wx;
        progress.advance(wx);
    }
    progress.finish();
    let tail = format!(
        "{}attribute \"dep\" string \"positions\"\n\
         object \"{}\" class field\n\
         component \"positions\" value 1\n\
         component \"connections\" value 2\n\
         component \"data\" value 3\n",
        if col % 3 == 0 { "" } else { "\n" },
        field.name()
    );
    out.out.write_all(tail.as_bytes()).map_err(|e| out.io(e))?;
    Ok(())
}
