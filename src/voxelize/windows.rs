//! The topology repair out of core: the growths of [`super::repair`] run in windows
//! around each handle, with the rest of the solid fixed.
//!
//! A window is a box around a handle's plug (the piece a closing adds there, found block
//! by block by [`super::closing::handles`]) with a margin. Its one-voxel outer shell is
//! fixed; inside, the two growths of the whole-grid repair run as they would there:
//! - cut: the solid of the shell is the growing object; it grows into the window's solid
//!   through simple points, deepest first. What it does not reach is removed: where
//!   the handle passes through the window, the fronts from its two sides meet last where
//!   it is thinnest and a one-voxel-thick sheet stays out.
//! - fill: the background of the shell grows into the window's background, farthest
//!   from the solid first; what it does not reach is added: a one-voxel-thick plug where
//!   the tunnel is narrowest.
//!
//! Each growth adds only simple points to a set that includes everything outside the
//! window, so the solid outside and on the shell keeps its topology; what changes is
//! measured exactly by the Euler characteristic of the window (every cell a changed
//! voxel touches lies in it). A growth is kept only when it raises the Euler
//! characteristic (removes at least one handle) and encloses no background pocket; of
//! the two, the one that removes more handles, then the one that changes fewer voxels
//! (per handle, not for the whole solid). A window whose growths both fail is
//! left as it is. The caller checks the whole solid afterwards (pieces, cavities, Euler
//! characteristic) and goes on with larger windows while handles are left.
//!
//! Windows depend only on the solid and on fixed sizes, never on `--mem` or the thread
//! count, and each is one sequential pass; so the result is the same bytes for any
//! memory budget and any number of threads.
// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

use std::cmp::Reverse;

use super::closing::{box_euler, edt_sq};
use super::repair::{changed_regions, grow, Flat, Region, IN};
use crate::grid::BlockStore;
use crate::math::Idx3;

/// Peak bytes a voxel of a window takes (the box, the masks, the growth state, the
/// depths and the distance transform's work).
pub const BYTES_PER_WINDOW_VOXEL: u64 = 24;

/// The largest window, in voxels: a window larger than this is not repaired (the
/// caller falls back). Fixed, so that what is repaired never depends on `--mem`.
pub const MAX_WINDOW_VOXELS: u64 = 1 << 22;

/// What one window's repair did.
#[derive(Clone, Debug, Default)]
pub struct WindowOutcome {
    /// Whether the fill was chosen (else the cut).
    pub fill: bool,
    /// Rise of the Euler characteristic (handles removed).
    pub closes: i64,
    /// Voxels removed.
    pub removed: u64,
    /// Voxels added.
    pub added: u64,
    /// Voxels the other growth would have changed (`u64::MAX` when it removes no handle).
    pub alternative: u64,
    /// Connected regions of changed voxels (26-connected, within the window).
    pub regions: Vec<Region>,
    /// Whether a cut splits a piece of the window's solid that reaches its shell: the
    /// solid may then have fallen apart, which only a pass over the whole grid can tell.
    pub split: bool,
    /// The window's solid before.
    pub before: Vec<bool>,
}

/// The window around the box `[lo, hi]` with `margin` voxels on each side, clipped to
/// the grid: origin and shape.
#[must_use]
pub fn window(shape: Idx3, lo: Idx3, hi: Idx3, margin: u64) -> (Idx3, [usize; 3]) {
    let o = [0, 1, 2].map(|a| lo[a].saturating_sub(margin));
    let e = [0, 1, 2].map(|a| (hi[a] + margin + 1).min(shape[a]));
    (o, [0, 1, 2].map(|a| (e[a] - o[a]) as usize))
}

/// Repair the window `[origin, origin + shape)` of the solid `{v == 1}` in `store`:
/// writes the better growth back and says what it did, or leaves the window as it is
/// and returns None when neither growth removes a handle.
#[allow(clippy::too_many_lines)] // the two growths, their checks and the choice share the window's masks
pub fn repair_window(
    store: &dyn BlockStore<u8>,
    origin: Idx3,
    shape: [usize; 3],
) -> Result<Option<WindowOutcome>, crate::Error> {
    let bx = store.read_region(origin.map(|c| c as i64), shape, 0)?;
    let solid: Vec<bool> = bx.data.iter().map(|&v| v == 1).collect();
    let flat = Flat::new(shape);
    let total = solid.len();
    let interior = |i: usize| !flat.on_face(i);
    let as_u8 = |s: &[bool]| s.iter().map(|&b| u8::from(b)).collect::<Vec<u8>>();
    let chi0 = box_euler(&as_u8(&solid), shape);

    // Cut: the shell's solid grows inward through the window's solid, deepest first. A
    // window with no solid on its shell holds whole pieces: the deepest voxel seeds it,
    // as in the whole-grid cut.
    let depth = edt_sq(&solid.iter().map(|&s| !s).collect::<Vec<_>>(), shape);
    let mut state = vec![0u8; total];
    let mut seeded = false;
    for i in 0..total {
        if solid[i] && !interior(i) {
            state[i] = IN;
            seeded = true;
        }
    }
    if !seeded {
        if let Some(s) = (0..total)
            .filter(|&i| solid[i])
            .max_by_key(|&i| (depth[i], Reverse(i)))
        {
            state[s] = IN;
        }
    }
    grow(&flat, &mut state, |i| solid[i] && interior(i), &depth, true);
    drop(depth);
    let cut: Vec<bool> = (0..total)
        .map(|i| {
            if interior(i) {
                state[i] & IN != 0
            } else {
                solid[i]
            }
        })
        .collect();

    // Fill: the shell's background grows inward through the window's background,
    // farthest from the solid first.
    let far = edt_sq(&solid, shape);
    let mut state = vec![0u8; total];
    for i in 0..total {
        if !solid[i] && !interior(i) {
            state[i] = IN;
        }
    }
    grow(&flat, &mut state, |i| !solid[i] && interior(i), &far, false);
    drop(far);
    let fill: Vec<bool> = (0..total)
        .map(|i| {
            if interior(i) {
                state[i] & IN == 0
            } else {
                solid[i]
            }
        })
        .collect();
    drop(state);

    // Pieces of a window's solid that reach its shell.
    let shell_pieces = |s: &[bool]| {
        let (labels, n) = super::components::label_block(&as_u8(s), shape, |v| v == 1);
        let mut on = vec![false; n as usize + 1];
        for i in 0..total {
            if !interior(i) {
                on[labels[i] as usize] = true;
            }
        }
        on[1..].iter().filter(|&&b| b).count()
    };
    // Background pockets of the window that do not reach its shell (6-connected, so a
    // count that may include pockets 26-connected to the rest: a stricter test).
    let pockets = |s: &[bool]| {
        let (labels, n) = super::components::label_block(&as_u8(s), shape, |v| v != 1);
        let mut on = vec![false; n as usize + 1];
        for i in 0..total {
            if !interior(i) {
                on[labels[i] as usize] = true;
            }
        }
        on[1..].iter().filter(|&&b| !b).count()
    };
    let pockets0 = pockets(&solid);
    let changes = |new: &[bool]| (0..total).filter(|&i| new[i] != solid[i]).count() as u64;
    let d_cut = box_euler(&as_u8(&cut), shape) - chi0;
    let d_fill = box_euler(&as_u8(&fill), shape) - chi0;
    let (n_cut, n_fill) = (changes(&cut), changes(&fill));
    let ok_cut = d_cut > 0 && pockets(&cut) <= pockets0;
    let ok_fill = d_fill > 0 && pockets(&fill) <= pockets0;
    let use_fill = match (ok_cut, ok_fill) {
        (false, false) => return Ok(None),
        (true, false) => false,
        (false, true) => true,
        // The one that removes more handles (a cut across two fused parts can remove
        // two where the fill plugs one), then the one that changes fewer voxels.
        (true, true) => (Reverse(d_fill), n_fill) < (Reverse(d_cut), n_cut),
    };
    let split = !use_fill && shell_pieces(&cut) > shell_pieces(&solid);
    let (new, closes, alternative) = if use_fill {
        (fill, d_fill, if ok_cut { n_cut } else { u64::MAX })
    } else {
        (cut, d_cut, if ok_fill { n_fill } else { u64::MAX })
    };

    // Changed regions, in C order of their first voxel.
    let regions = changed_regions(&flat, &solid, &new, origin);
    let removed = (0..total).filter(|&i| solid[i] && !new[i]).count() as u64;
    let added = (0..total).filter(|&i| !solid[i] && new[i]).count() as u64;

    write_window(store, origin, shape, &new)?;
    Ok(Some(WindowOutcome {
        fill: use_fill,
        closes,
        removed,
        added,
        alternative,
        regions,
        split,
        before: solid,
    }))
}

/// Write the solid `new` of the window `[origin, origin + shape)` into `store` (the
/// blocks where it differs).
pub fn write_window(
    store: &dyn BlockStore<u8>,
    origin: Idx3,
    shape: [usize; 3],
    new: &[bool],
) -> Result<(), crate::Error> {
    let spec = store.spec().clone();
    let o = origin.map(|c| c as i64);
    for b in spec.blocks_overlapping(o, shape) {
        let st = spec.block_start(b);
        let sh = spec.block_shape(b).map(|c| c as usize);
        let mut data = store.read_block(b)?;
        let mut changed = false;
        let mut k = 0;
        for z in 0..sh[0] {
            for y in 0..sh[1] {
                for x in 0..sh[2] {
                    let g = [st[0] + z as u64, st[1] + y as u64, st[2] + x as u64];
                    let inside =
                        (0..3).all(|a| g[a] >= origin[a] && g[a] < origin[a] + shape[a] as u64);
                    if inside {
                        let i = ((g[0] - origin[0]) as usize * shape[1]
                            + (g[1] - origin[1]) as usize)
                            * shape[2]
                            + (g[2] - origin[2]) as usize;
                        if new[i] != (data[k] == 1) {
                            data[k] = u8::from(new[i]);
                            changed = true;
                        }
                    }
                    k += 1;
                }
            }
        }
        if changed {
            store.write_block(b, &data)?;
        }
    }
    Ok(())
}
