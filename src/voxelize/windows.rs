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
use crate::grid::{BlockStore, GridSpec};
use crate::input::TriMesh;
use crate::math::{Idx3, Vec3};
use crate::trace::nearest::closest_on_triangle;

/// Depths are compared in units of 1/`SCALE` squared voxels (the squared distance
/// transform's integers times `SCALE`, or a squared distance to the mesh).
const SCALE: f64 = 64.0;

/// How far (voxels) from the mesh a voxel's distance to it is measured.
pub const BAND: f64 = 2.0;

/// The distance (voxels) from the center of each voxel of the box `[origin, origin +
/// shape)` of the grid `spec` to the mesh `mesh` (world coordinates), in C order, where
/// it is at most [`BAND`]; infinity elsewhere. Each triangle near the box visits the
/// voxels within [`BAND`] of its bounding box: the cost is the triangles' and their
/// band's, not the box's.
#[must_use]
pub fn mesh_band(mesh: &TriMesh, spec: &GridSpec, origin: Idx3, shape: [usize; 3]) -> Vec<f32> {
    let mut near = vec![f32::INFINITY; shape.iter().product()];
    // The box in voxel coordinates (x, y, z).
    let o = Vec3::new(origin[2] as f64, origin[1] as f64, origin[0] as f64);
    let n = [shape[2], shape[1], shape[0]];
    for t in &mesh.triangles {
        let Some(c) = t
            .iter()
            .map(|&i| {
                mesh.vertices
                    .get(i as usize)
                    .map(|&v| spec.world_to_voxel(v) - o)
            })
            .collect::<Option<Vec<Vec3>>>()
        else {
            continue;
        };
        let c = [c[0], c[1], c[2]];
        if c.iter().any(|v| !v.is_finite()) {
            continue;
        }
        let (lo, hi) = (c[0].min(c[1]).min(c[2]), c[0].max(c[1]).max(c[2]));
        // Voxel ranges (x, y, z) within BAND of the triangle's box, clipped to the box.
        let mut r = [(0usize, 0usize); 3];
        let mut empty = false;
        for a in 0..3 {
            let l = (lo[a] - BAND).ceil().max(0.0);
            let h = (hi[a] + BAND).floor().min(n[a] as f64 - 1.0);
            if l > h {
                empty = true;
                break;
            }
            r[a] = (l as usize, h as usize);
        }
        if empty {
            continue;
        }
        for z in r[2].0..=r[2].1 {
            for y in r[1].0..=r[1].1 {
                let row = (z * shape[1] + y) * shape[2];
                for x in r[0].0..=r[0].1 {
                    let p = Vec3::new(x as f64, y as f64, z as f64);
                    let d = (closest_on_triangle(p, c) - p).length();
                    if d <= BAND && (d as f32) < near[row + x] {
                        near[row + x] = d as f32;
                    }
                }
            }
        }
    }
    near
}

/// The growths' depths, in units of 1/[`SCALE`] squared voxels: the squared distance
/// transform `edt`, or the squared distance to the mesh `near` where that is less.
#[must_use]
pub fn depths(edt: &[u32], near: &[f32]) -> Vec<u32> {
    edt.iter()
        .enumerate()
        .map(|(i, &e)| depth_of(e, near.get(i).copied().unwrap_or(f32::INFINITY)))
        .collect()
}

/// One voxel's depth: its squared distance transform `e`, or its squared distance to the
/// mesh `near` (infinity: none) where that is less, in units of 1/[`SCALE`].
#[must_use]
pub fn depth_of(e: u32, near: f32) -> u32 {
    let e = (f64::from(e) * SCALE).min(f64::from(u32::MAX));
    let d = f64::from(near) * f64::from(near) * SCALE;
    e.min(d).round() as u32
}

/// Voxels where `new` differs from `solid` whose center is more than a voxel from the
/// mesh (none without one).
#[must_use]
pub fn deep_changes(solid: &[bool], new: &[bool], near: &[f32]) -> u64 {
    (0..near.len())
        .filter(|&i| new[i] != solid[i] && near[i] > 1.0)
        .count() as u64
}

/// Peak bytes a voxel of a window takes (the box, the masks, the growth state, the
/// distances to the mesh, the depths and the distance transform's work).
pub const BYTES_PER_WINDOW_VOXEL: u64 = 32;

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
/// and returns None when neither growth removes a handle. `surface`, the input mesh
/// and the grid, when the input is a mesh: a voxel's depth is then its distance to the
/// mesh where that is less than [`BAND`] voxels and less than its distance transform
/// ([`mesh_band`], [`depths`]), so that the growths meet where the mesh is thin (two
/// parts that touch in the grid but not in the mesh meet there) and changes stay near
/// the surface.
#[allow(clippy::too_many_lines)] // the two growths, their checks and the choice share the window's masks
pub fn repair_window(
    store: &dyn BlockStore<u8>,
    origin: Idx3,
    shape: [usize; 3],
    surface: Option<(&TriMesh, &GridSpec)>,
) -> Result<Option<WindowOutcome>, crate::Error> {
    let bx = store.read_region(origin.map(|c| c as i64), shape, 0)?;
    let solid: Vec<bool> = bx.data.iter().map(|&v| v == 1).collect();
    let flat = Flat::new(shape);
    let total = solid.len();
    let interior = |i: usize| !flat.on_face(i);
    let as_u8 = |s: &[bool]| s.iter().map(|&b| u8::from(b)).collect::<Vec<u8>>();
    let chi0 = box_euler(&as_u8(&solid), shape);
    let near: Vec<f32> = surface.map_or_else(Vec::new, |(mesh, spec)| {
        mesh_band(mesh, spec, origin, shape)
    });
    let depths = |edt: Vec<u32>| depths(&edt, &near);
    let deep = |new: &[bool]| deep_changes(&solid, new, &near);

    // Cuts: the shell's solid grows inward through the window's solid, deepest first. A
    // window with no solid on its shell holds whole pieces: the deepest voxel seeds it,
    // as in the whole-grid cut. Two of them: the kept solid grown as a 6-connected
    // object (its pieces and tunnels stay those of the shell's solid), and grown as a
    // 26-connected set whose complement keeps its 6-connected topology (the removed
    // voxels then always reach the background through faces, where the first cut can
    // leave a pocket that touches it only along edges or corners).
    let depth = depths(edt_sq(
        &solid.iter().map(|&s| !s).collect::<Vec<_>>(),
        shape,
    ));
    let cut_by = |object: bool| -> Vec<bool> {
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
        grow(
            &flat,
            &mut state,
            |i| solid[i] && interior(i),
            &depth,
            object,
        );
        (0..total)
            .map(|i| {
                if interior(i) {
                    state[i] & IN != 0
                } else {
                    solid[i]
                }
            })
            .collect()
    };
    let cut6 = cut_by(true);
    let cut26 = cut_by(false);
    drop(depth);

    // Fill: the shell's background grows inward through the window's background,
    // farthest from the solid first.
    let far = depths(edt_sq(&solid, shape));
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

    // Pieces of a window's solid (6-connected) or background (6-connected, so a count
    // that may include pockets 26-connected to the rest: a stricter test) that reach its
    // shell and that do not.
    let pieces = |s: &[bool], of_solid: bool| {
        let (labels, n) =
            super::components::label_block(&as_u8(s), shape, |v| (v == 1) == of_solid);
        let mut on = vec![false; n as usize + 1];
        for i in 0..total {
            if !interior(i) {
                on[labels[i] as usize] = true;
            }
        }
        let reach = on[1..].iter().filter(|&&b| b).count();
        (reach, n as usize - reach)
    };
    let (_, pockets0) = pieces(&solid, false);
    let (shell0, islands0) = pieces(&solid, true);
    let changes = |new: &[bool]| (0..total).filter(|&i| new[i] != solid[i]).count() as u64;
    // Each growth: whether it fills, its solid, the handles it removes, and whether it
    // is kept: it removes a handle, and leaves no pocket of background and no piece of
    // solid away from the shell that was not there.
    let candidates: Vec<(bool, Vec<bool>, i64, bool)> =
        [(false, cut6), (false, cut26), (true, fill)]
            .into_iter()
            .map(|(is_fill, new)| {
                let d = box_euler(&as_u8(&new), shape) - chi0;
                let ok =
                    d > 0 && pieces(&new, false).1 <= pockets0 && pieces(&new, true).1 <= islands0;
                (is_fill, new, d, ok)
            })
            .collect();
    // The one that removes more handles (a cut across two fused parts can remove two
    // where the fill plugs one), then the one that changes fewer voxels more than a
    // voxel from the mesh, then the one that changes fewer voxels; the first of equals.
    let key = |c: &(bool, Vec<bool>, i64, bool)| (Reverse(c.2), deep(&c.1), changes(&c.1));
    let Some(best) = (0..candidates.len())
        .filter(|&k| candidates[k].3)
        .min_by_key(|&k| key(&candidates[k]))
    else {
        return Ok(None);
    };
    let use_fill = candidates[best].0;
    let alternative = candidates
        .iter()
        .filter(|c| c.3 && c.0 != use_fill)
        .map(|c| changes(&c.1))
        .min()
        .unwrap_or(u64::MAX);
    let (_, new, closes, _) = candidates.into_iter().nth(best).expect("a candidate");
    let split = !use_fill && pieces(&new, true).0 > shell0;

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
