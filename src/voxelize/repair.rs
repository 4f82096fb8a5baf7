//! Topology repair: the voxel solid made one genus-0 piece with few changed voxels, by
//! growth through simple points (see [`super::simple`]), ordered by depth, after Bazin
//! and Pham's topology-preserving fast marching (2007).
//!
//! Two growths, each of which cannot change the topology of what it grows:
//! - cut: from the deepest voxel of the solid outward, within the solid, deepest first.
//!   It starts as one voxel (a ball) and adds only simple points, so it ends as a
//!   genus-0 piece inside the solid. The fronts meet last where the solid is thinnest, so
//!   a handle loses a one-voxel-thick sheet where it is narrowest; pieces the growth
//!   never reaches (specks) are dropped.
//! - fill: from the grid's faces inward, within the background of the main piece,
//!   farthest from the solid first. It grows the background, whose complement starts as
//!   a box (a ball) and stays one, so everything it leaves is a genus-0 solid holding
//!   the main piece; a tunnel keeps a one-voxel-thick plug where it is narrowest.
//!
//! The one that changes fewer voxels wins, for the whole solid (not handle by handle).
//! Ties of depth are broken by the linear voxel index, and the growth is one sequential
//! pass, so the result does not depend on threads or on where the grid is stored.
//!
//! Memory: the whole grid in memory, [`BYTES_PER_VOXEL`] bytes a voxel at the peak
//! (solid, growth state, depths and the distance transform's work), plus the queue.
// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use super::closing::edt_sq;
use super::simple::is_simple;
use super::windows::{deep_changes, depths, mesh_band};
use crate::grid::{BlockStore, GridSpec};
use crate::input::TriMesh;
use crate::math::Idx3;

/// Peak bytes a voxel of the grid takes during the repair.
pub const BYTES_PER_VOXEL: u64 = 24;

/// In the growing set.
pub(super) const IN: u8 = 1;
/// In the queue.
const QUEUED: u8 = 2;
/// Popped while not simple: looked at again when its neighbourhood changes.
const WAITING: u8 = 4;

/// One connected region of changed voxels.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Region {
    /// Whether its voxels were added (else removed).
    pub added: bool,
    /// Voxels in it.
    pub voxels: u64,
    /// Its first voxel in C order, `[z, y, x]`.
    pub voxel: Idx3,
}

/// What the repair did.
#[derive(Clone, Debug, Default)]
pub struct Outcome {
    /// "cut" or "fill".
    pub method: &'static str,
    /// Voxels taken out of the solid (specks included).
    pub removed: u64,
    /// Voxels added to the solid.
    pub added: u64,
    /// Pieces other than the main one, dropped.
    pub specks: u64,
    /// Their voxels.
    pub speck_voxels: u64,
    /// Voxels the other method would have changed.
    pub alternative: u64,
    /// The largest connected regions of changed voxels (26-connected), largest first.
    pub regions: Vec<Region>,
}

/// The grid's geometry for neighbourhood work on a flat C-order array.
pub(super) struct Flat {
    n: [usize; 3],
    /// Linear offsets of the 27 neighbourhood positions (bit order of [`super::simple`]).
    off: [isize; 27],
}

impl Flat {
    pub(super) fn new(n: [usize; 3]) -> Self {
        let mut off = [0isize; 27];
        for (b, o) in off.iter_mut().enumerate() {
            let (dz, dy, dx) = (
                b as isize / 9 - 1,
                (b as isize / 3) % 3 - 1,
                b as isize % 3 - 1,
            );
            *o = (dz * n[1] as isize + dy) * n[2] as isize + dx;
        }
        Self { n, off }
    }

    pub(super) fn zyx(&self, i: usize) -> [usize; 3] {
        [
            i / (self.n[1] * self.n[2]),
            (i / self.n[2]) % self.n[1],
            i % self.n[2],
        ]
    }

    /// Whether voxel `i` is on a face of the grid.
    pub(super) fn on_face(&self, i: usize) -> bool {
        let [z, y, x] = self.zyx(i);
        z == 0 || y == 0 || x == 0 || z + 1 == self.n[0] || y + 1 == self.n[1] || x + 1 == self.n[2]
    }

    /// Linear indices of the neighbours of `i` at the given bits that lie in the grid.
    pub(super) fn neighbours<'a>(
        &'a self,
        i: usize,
        bits: &'a [usize],
    ) -> impl Iterator<Item = usize> + 'a {
        let interior = !self.on_face(i);
        let [z, y, x] = self.zyx(i).map(|c| c as isize);
        bits.iter().filter_map(move |&b| {
            if !interior {
                let (dz, dy, dx) = (
                    b as isize / 9 - 1,
                    (b as isize / 3) % 3 - 1,
                    b as isize % 3 - 1,
                );
                let (nz, ny, nx) = (z + dz, y + dy, x + dx);
                if nz < 0
                    || ny < 0
                    || nx < 0
                    || nz >= self.n[0] as isize
                    || ny >= self.n[1] as isize
                    || nx >= self.n[2] as isize
                {
                    return None;
                }
            }
            Some((i as isize + self.off[b]) as usize)
        })
    }

    /// The 27-bit mask of the neighbours of `i` where `f` holds; outside the grid counts
    /// as `outside`.
    pub(super) fn mask(&self, i: usize, outside: bool, f: impl Fn(usize) -> bool) -> u32 {
        let mut m = 0u32;
        if self.on_face(i) {
            let [z, y, x] = self.zyx(i).map(|c| c as isize);
            for b in 0..27 {
                let (dz, dy, dx) = (b / 9 - 1, (b / 3) % 3 - 1, b % 3 - 1);
                let (nz, ny, nx) = (z + dz, y + dy, x + dx);
                let inside = nz >= 0
                    && ny >= 0
                    && nx >= 0
                    && nz < self.n[0] as isize
                    && ny < self.n[1] as isize
                    && nx < self.n[2] as isize;
                let v = if inside {
                    f((i as isize + self.off[b as usize]) as usize)
                } else {
                    outside
                };
                m |= u32::from(v) << b;
            }
        } else {
            for (b, &o) in self.off.iter().enumerate() {
                m |= u32::from(f((i as isize + o) as usize)) << b;
            }
        }
        m
    }
}

/// Bits of the 6 face neighbours and of all 26 neighbours.
pub(super) const FACES: [usize; 6] = [4, 10, 12, 14, 16, 22];
pub(super) const ALL: [usize; 26] = [
    0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 26,
];

/// Grow `state`'s IN set through voxels where `allowed` holds, adding a voxel only when
/// it is simple for the growing set, taken as the 6-connected object (`grow_object`) or
/// as the 26-connected background whose complement is the object (`!grow_object`).
/// Highest `prio` first, then lowest index.
pub(super) fn grow(
    flat: &Flat,
    state: &mut [u8],
    allowed: impl Fn(usize) -> bool,
    prio: &[u32],
    grow_object: bool,
) {
    let mut heap: BinaryHeap<(u32, Reverse<usize>)> = BinaryHeap::new();
    // Seeds: what touches the set already (face neighbours for an object, which
    // needs a face neighbour to be simple; any neighbour for a 26-connected background).
    let near: &[usize] = if grow_object { &FACES } else { &ALL };
    for i in 0..state.len() {
        if state[i] & IN != 0 {
            continue;
        }
        if allowed(i) && flat.neighbours(i, near).any(|j| state[j] & IN != 0) {
            state[i] |= QUEUED;
            heap.push((prio[i], Reverse(i)));
        }
    }
    while let Some((_, Reverse(i))) = heap.pop() {
        state[i] &= !QUEUED;
        let simple = if grow_object {
            is_simple(flat.mask(i, false, |j| state[j] & IN != 0))
        } else {
            is_simple(flat.mask(i, false, |j| state[j] & IN == 0))
        };
        if !simple {
            state[i] |= WAITING;
            continue;
        }
        state[i] = IN;
        for j in flat.neighbours(i, &ALL) {
            let s = state[j];
            if s & (IN | QUEUED) != 0 || !allowed(j) {
                continue;
            }
            // A new candidate must touch the set as `near` says; a waiting one may have
            // become simple whichever neighbour joined.
            let touches = !grow_object
                || s & WAITING != 0
                || FACES
                    .iter()
                    .any(|&b| (i as isize - flat.off[b]) as usize == j);
            if touches {
                state[j] = (s & !WAITING) | QUEUED;
                heap.push((prio[j], Reverse(j)));
            }
        }
    }
}

/// Repair the solid `{v == 1}` of `store` in place (1 solid, 0 background): returns
/// what changed. The caller checks the topology afterwards.
#[allow(clippy::too_many_lines)] // the two growths and the choice between them share the depth buckets
pub fn repair(
    store: &dyn BlockStore<u8>,
    surface: Option<(&TriMesh, &GridSpec)>,
) -> Result<Outcome, crate::Error> {
    let spec = store.spec().clone();
    let n = spec.shape.map(|c| c as usize);
    let solid: Vec<bool> = store
        .read_region([0, 0, 0], n, 0)?
        .data
        .into_iter()
        .map(|v| v == 1)
        .collect();
    let flat = Flat::new(n);
    let total = solid.len();
    // For a mesh: each voxel's distance to it, where within a few voxels (the depths
    // follow it there, as in the windows).
    let near: Vec<f32> =
        surface.map_or_else(Vec::new, |(mesh, grid)| mesh_band(mesh, grid, [0; 3], n));

    // Cut: from the deepest voxel (first in C order among equals), within the solid.
    let depth = depths(
        &edt_sq(&solid.iter().map(|&s| !s).collect::<Vec<_>>(), n),
        &near,
    );
    let seed = (0..total)
        .filter(|&i| solid[i])
        .max_by_key(|&i| (depth[i], Reverse(i)))
        .ok_or_else(|| {
            crate::Error::from(super::VoxelizeError::Options(
                "no solid voxel to repair".into(),
            ))
        })?;
    let mut cut = vec![0u8; total];
    cut[seed] = IN;
    grow(&flat, &mut cut, |i| solid[i], &depth, true);
    drop(depth);

    // The seed's piece: what fill works on (other pieces are dropped either way).
    let mut main = vec![false; total];
    main[seed] = true;
    let mut stack = vec![seed];
    while let Some(i) = stack.pop() {
        for j in flat.neighbours(i, &FACES) {
            if solid[j] && !main[j] {
                main[j] = true;
                stack.push(j);
            }
        }
    }
    let (mut specks, mut speck_voxels) = (0u64, 0u64);
    {
        let mut seen = main.clone();
        for s in 0..total {
            if solid[s] && !seen[s] {
                specks += 1;
                seen[s] = true;
                stack.push(s);
                while let Some(i) = stack.pop() {
                    speck_voxels += 1;
                    for j in flat.neighbours(i, &FACES) {
                        if solid[j] && !seen[j] {
                            seen[j] = true;
                            stack.push(j);
                        }
                    }
                }
            }
        }
    }

    // Fill: from the grid's faces inward, within the main piece's background.
    let far = depths(&edt_sq(&main, n), &near);
    let mut fill = vec![0u8; total];
    let mut faces_clear = true;
    for i in 0..total {
        if flat.on_face(i) {
            faces_clear &= !main[i];
            fill[i] = IN;
        }
    }
    if faces_clear {
        grow(&flat, &mut fill, |i| !main[i], &far, false);
    }
    drop(far);

    let removed_cut = (0..total).filter(|&i| solid[i] && cut[i] & IN == 0).count() as u64;
    let added_fill = (0..total)
        .filter(|&i| !main[i] && fill[i] & IN == 0)
        .count() as u64;
    let cut: Vec<bool> = (0..total).map(|i| cut[i] & IN != 0).collect();
    let fill: Vec<bool> = (0..total).map(|i| fill[i] & IN == 0).collect();
    // Fewer changes more than a voxel from the mesh (for a mesh), then fewer changes.
    let use_fill = faces_clear
        && (
            deep_changes(&solid, &fill, &near),
            added_fill + speck_voxels,
        ) < (deep_changes(&solid, &cut, &near), removed_cut);
    let new = if use_fill { fill } else { cut };
    drop((main, near));

    // Changed regions, largest first (then first in C order).
    let mut regions = changed_regions(&flat, &solid, &new, [0; 3]);
    regions.sort_by_key(|r| Reverse(r.voxels));
    let removed = (0..total).filter(|&i| solid[i] && !new[i]).count() as u64;
    let added = (0..total).filter(|&i| !solid[i] && new[i]).count() as u64;

    // Write back the blocks that changed.
    for b in spec.block_indices() {
        let st = spec.block_start(b).map(|c| c as usize);
        let sh = spec.block_shape(b).map(|c| c as usize);
        let mut data = store.read_block(b)?;
        let mut changed = false;
        let mut k = 0;
        for z in st[0]..st[0] + sh[0] {
            for y in st[1]..st[1] + sh[1] {
                let row = (z * n[1] + y) * n[2];
                for x in st[2]..st[2] + sh[2] {
                    let i = row + x;
                    if new[i] != solid[i] {
                        data[k] = u8::from(new[i]);
                        changed = true;
                    }
                    k += 1;
                }
            }
        }
        if changed {
            store.write_block(b, &data)?;
        }
    }
    Ok(Outcome {
        method: if use_fill { "fill" } else { "cut" },
        removed,
        added,
        specks,
        speck_voxels,
        alternative: if use_fill {
            removed_cut
        } else if faces_clear {
            added_fill + speck_voxels
        } else {
            u64::MAX
        },
        regions,
    })
}

/// The voxels where `new` differs from `solid`, as 26-connected regions of one kind (all
/// added or all removed), in C order of their first voxel; `origin` is added to that
/// voxel's `[z, y, x]` (a window's place in the grid).
pub(super) fn changed_regions(
    flat: &Flat,
    solid: &[bool],
    new: &[bool],
    origin: Idx3,
) -> Vec<Region> {
    let mut regions = Vec::new();
    let mut seen = vec![false; solid.len()];
    let mut stack = Vec::new();
    for s in 0..solid.len() {
        if new[s] == solid[s] || seen[s] {
            continue;
        }
        let added = new[s];
        let mut voxels = 0u64;
        seen[s] = true;
        stack.push(s);
        while let Some(i) = stack.pop() {
            voxels += 1;
            for j in flat.neighbours(i, &ALL) {
                if !seen[j] && new[j] != solid[j] && new[j] == added {
                    seen[j] = true;
                    stack.push(j);
                }
            }
        }
        let z = flat.zyx(s);
        regions.push(Region {
            added,
            voxels,
            voxel: [0, 1, 2].map(|a| origin[a] + z[a] as u64),
        });
    }
    regions
}
