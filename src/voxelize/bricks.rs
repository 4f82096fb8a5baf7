//! The compact cut's records ([`super::compact`]): one 32-bit record a voxel of the
//! grid, in bricks of 16^3 voxels; a brick without a solid voxel is not stored. The
//! bricks live in memory, or in a scratch file behind a cache of bricks with clock
//! replacement (a brick used since the hand last passed stays; a changed one is written
//! back when it leaves). The records' meaning is the cut's; a voxel outside the grid,
//! and the padding of a brick at the grid's edge, reads 0.

// Index arithmetic over the grid's axes: z, y, x and i, l read as in the formulas.
#![allow(clippy::many_single_char_names)]

use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

use crate::grid::GridError;

/// log2 of a brick's edge in voxels.
pub(super) const SHIFT: usize = 4;
/// A brick's edge in voxels.
pub(super) const EDGE: usize = 1 << SHIFT;
/// A voxel's place along an axis within its brick: its coordinate `& MASK`.
pub(super) const MASK: usize = EDGE - 1;
/// Voxels of a brick.
pub(super) const BRICK: usize = EDGE * EDGE * EDGE;
/// Bytes of a brick.
pub(super) const BRICK_BYTES: u64 = BRICK as u64 * 4;
/// The fewest bricks the cache holds (a neighbourhood spans at most 8).
pub(super) const MIN_CACHE: usize = 8;

/// No brick (not stored; not cached).
pub(super) const NONE: u32 = u32::MAX;

/// The grid's records, brick by brick.
pub(super) struct Bricks {
    /// The grid's shape, and its shape in bricks.
    pub(super) n: [usize; 3],
    pub(super) nb: [usize; 3],
    /// Where each brick is stored, by its position among the stored ones; NONE: none
    /// of its voxels is solid.
    at: Vec<u32>,
    stored: usize,
    /// The scratch file, when the bricks do not all fit in memory.
    file: Option<(File, PathBuf)>,
    /// Memory: every stored brick at its position. File: the cached bricks, one a slot.
    data: Vec<u32>,
    /// File: the slot of each stored brick (NONE: not cached), the brick in each slot,
    /// whether it was written since it was read, whether it was used since the clock
    /// hand last passed it, and the hand.
    slot_of: Vec<u32>,
    owner: Vec<u32>,
    dirty: Vec<bool>,
    used: Vec<bool>,
    hand: usize,
    /// Bricks read from the file into the cache.
    pub(super) reads: u64,
}

impl Bricks {
    /// Records of a grid of shape `n`, all background until bricks are appended; in a
    /// scratch file `cut.bricks` in `scratch` (created or truncated; removed when
    /// dropped) if given, else in memory.
    pub(super) fn new(n: [usize; 3], scratch: Option<&Path>) -> Result<Self, GridError> {
        let nb = n.map(|c| c.div_ceil(EDGE));
        Ok(Self {
            n,
            nb,
            at: vec![NONE; nb.iter().product()],
            stored: 0,
            file: scratch.map(scratch_file).transpose()?,
            data: Vec::new(),
            slot_of: Vec::new(),
            owner: Vec::new(),
            dirty: Vec::new(),
            used: Vec::new(),
            hand: 0,
            reads: 0,
        })
    }

    /// Whether the bricks live in a scratch file.
    pub(super) fn spilled(&self) -> bool {
        self.file.is_some()
    }

    /// Where brick `b` (`[z, y, x]` in bricks) is stored; None: none of its voxels is
    /// solid.
    pub(super) fn stored(&self, b: [usize; 3]) -> Option<u32> {
        let p = self.at[self.index(b)];
        (p != NONE).then_some(p)
    }

    /// The stored bricks of layer `bz`, in C order, with where each is stored.
    pub(super) fn layer(&self, bz: usize) -> impl Iterator<Item = ([usize; 3], u32)> + '_ {
        (0..self.nb[1])
            .flat_map(move |by| (0..self.nb[2]).map(move |bx| [bz, by, bx]))
            .filter_map(|b| self.stored(b).map(|p| (b, p)))
    }

    /// Voxel `[z, y, x]` of the grid at place `l` of brick `b`.
    pub(super) fn voxel(b: [usize; 3], l: usize) -> [usize; 3] {
        [
            b[0] * EDGE + (l >> (2 * SHIFT)),
            b[1] * EDGE + ((l >> SHIFT) & MASK),
            b[2] * EDGE + (l & MASK),
        ]
    }

    fn io(&self, e: std::io::Error) -> GridError {
        GridError::Io {
            path: self.file.as_ref().map(|f| f.1.clone()).unwrap_or_default(),
            source: e,
        }
    }

    /// Brick `b`'s (`[z, y, x]` in bricks) index among all the grid's bricks.
    fn index(&self, b: [usize; 3]) -> usize {
        (b[0] * self.nb[1] + b[1]) * self.nb[2] + b[2]
    }

    /// The brick holding voxel `[z, y, x]`, and the voxel's place in it.
    fn locate(&self, z: usize, y: usize, x: usize) -> (usize, usize) {
        (
            self.index([z >> SHIFT, y >> SHIFT, x >> SHIFT]),
            ((z & MASK) << (2 * SHIFT)) | ((y & MASK) << SHIFT) | (x & MASK),
        )
    }

    /// Store brick `b` (not stored before) with the records `rec`.
    pub(super) fn append(&mut self, b: [usize; 3], rec: &[u32]) -> Result<(), GridError> {
        let p = self.stored;
        let id = self.index(b);
        self.at[id] = p as u32;
        self.stored += 1;
        match &self.file {
            None => self.data.extend_from_slice(rec),
            Some((f, _)) => f
                .write_all_at(bytemuck::cast_slice(rec), p as u64 * BRICK_BYTES)
                .map_err(|e| self.io(e))?,
        }
        Ok(())
    }

    /// Read the stored brick at position `p` (not through the cache).
    pub(super) fn read_raw(&self, p: u32, out: &mut [u32]) -> Result<(), GridError> {
        match &self.file {
            None => out.copy_from_slice(&self.data[p as usize * BRICK..][..BRICK]),
            Some((f, _)) => f
                .read_exact_at(bytemuck::cast_slice_mut(out), u64::from(p) * BRICK_BYTES)
                .map_err(|e| self.io(e))?,
        }
        Ok(())
    }

    /// Write the stored brick at position `p` (not through the cache).
    pub(super) fn write_raw(&mut self, p: u32, rec: &[u32]) -> Result<(), GridError> {
        match &self.file {
            None => self.data[p as usize * BRICK..][..BRICK].copy_from_slice(rec),
            Some((f, _)) => f
                .write_all_at(bytemuck::cast_slice(rec), u64::from(p) * BRICK_BYTES)
                .map_err(|e| self.io(e))?,
        }
        Ok(())
    }

    /// Make room for `slots` cached bricks (file only; from here on, go through the
    /// cache).
    pub(super) fn open_cache(&mut self, slots: usize) {
        if self.file.is_some() {
            let slots = slots.clamp(MIN_CACHE, self.stored.max(MIN_CACHE));
            self.data = vec![0; slots * BRICK];
            self.slot_of = vec![NONE; self.stored];
            self.owner = vec![NONE; slots];
            self.dirty = vec![false; slots];
            self.used = vec![false; slots];
        }
    }

    /// The first record of stored brick `p` in `data`, read into the cache if need be.
    fn slot(&mut self, p: u32) -> Result<usize, GridError> {
        if self.file.is_none() {
            return Ok(p as usize * BRICK);
        }
        let s = self.slot_of[p as usize];
        if s != NONE {
            self.used[s as usize] = true;
            return Ok(s as usize * BRICK);
        }
        // The clock: the first slot not used since the hand last passed.
        let slots = self.owner.len();
        while self.used[self.hand] {
            self.used[self.hand] = false;
            self.hand = (self.hand + 1) % slots;
        }
        let s = self.hand;
        self.hand = (self.hand + 1) % slots;
        let old = self.owner[s];
        let (f, path) = self.file.as_ref().expect("file mode");
        let io = |e| GridError::Io {
            path: path.clone(),
            source: e,
        };
        let buf = &mut self.data[s * BRICK..][..BRICK];
        if old != NONE {
            if self.dirty[s] {
                f.write_all_at(bytemuck::cast_slice(buf), u64::from(old) * BRICK_BYTES)
                    .map_err(io)?;
            }
            self.slot_of[old as usize] = NONE;
        }
        f.read_exact_at(bytemuck::cast_slice_mut(buf), u64::from(p) * BRICK_BYTES)
            .map_err(io)?;
        self.reads += 1;
        self.owner[s] = p;
        self.slot_of[p as usize] = s as u32;
        self.dirty[s] = false;
        self.used[s] = true;
        Ok(s * BRICK)
    }

    /// Write every cached brick that changed back to the file.
    pub(super) fn flush(&mut self) -> Result<(), GridError> {
        if let Some((f, _)) = &self.file {
            for s in 0..self.owner.len() {
                if self.dirty[s] {
                    f.write_all_at(
                        bytemuck::cast_slice(&self.data[s * BRICK..][..BRICK]),
                        u64::from(self.owner[s]) * BRICK_BYTES,
                    )
                    .map_err(|e| self.io(e))?;
                    self.dirty[s] = false;
                }
            }
        }
        Ok(())
    }

    fn zyx(&self, i: usize) -> [usize; 3] {
        [
            i / (self.n[1] * self.n[2]),
            (i / self.n[2]) % self.n[1],
            i % self.n[2],
        ]
    }

    /// Set the record of solid voxel `i`.
    pub(super) fn set(&mut self, i: usize, rec: u32) -> Result<(), GridError> {
        let [z, y, x] = self.zyx(i);
        let (id, l) = self.locate(z, y, x);
        let p = self.at[id];
        debug_assert!(p != NONE, "only solid voxels change");
        let s = self.slot(p)?;
        self.data[s + l] = rec;
        if self.file.is_some() {
            self.dirty[s / BRICK] = true;
        }
        Ok(())
    }

    /// The records of the 27 voxels around voxel `i` (bit order of
    /// [`super::simple`]); a voxel outside the grid reads 0, as the padding of a brick
    /// at the grid's edge does (not solid).
    pub(super) fn hood(&mut self, i: usize) -> Result<[u32; 27], GridError> {
        let [z, y, x] = self.zyx(i);
        let mut out = [0u32; 27];
        let inner = |c: usize| (1..MASK).contains(&(c & MASK));
        if inner(z) && inner(y) && inner(x) {
            // The whole neighbourhood is in this brick.
            let (id, l) = self.locate(z, y, x);
            let p = self.at[id];
            if p == NONE {
                return Ok(out);
            }
            let s = self.slot(p)? + l;
            for (b, o) in out.iter_mut().enumerate() {
                let (dz, dy, dx) = (b / 9, (b / 3) % 3, b % 3);
                let off = (dz << (2 * SHIFT)) + (dy << SHIFT) + dx;
                *o = self.data[s + off - (1 << (2 * SHIFT)) - (1 << SHIFT) - 1];
            }
            return Ok(out);
        }
        for (b, o) in out.iter_mut().enumerate() {
            let (Some(zz), Some(yy), Some(xx)) = (
                (z + b / 9).checked_sub(1),
                (y + (b / 3) % 3).checked_sub(1),
                (x + b % 3).checked_sub(1),
            ) else {
                continue;
            };
            if zz >= self.n[0] || yy >= self.n[1] || xx >= self.n[2] {
                continue;
            }
            let (id, l) = self.locate(zz, yy, xx);
            let p = self.at[id];
            if p != NONE {
                let s = self.slot(p)?;
                *o = self.data[s + l];
            }
        }
        Ok(out)
    }
}

impl Drop for Bricks {
    fn drop(&mut self) {
        if let Some((_, path)) = &self.file {
            let _ = std::fs::remove_file(path);
        }
    }
}

/// The scratch file of the bricks, `cut.bricks` in `scratch` (created, or truncated).
fn scratch_file(scratch: &Path) -> Result<(File, PathBuf), GridError> {
    std::fs::create_dir_all(scratch).map_err(|e| GridError::Io {
        path: scratch.to_path_buf(),
        source: e,
    })?;
    let path = scratch.join("cut.bricks");
    let f = File::options()
        .read(true)
        .write(true)
        .create(true)
        .truncate(true)
        .open(&path)
        .map_err(|e| GridError::Io {
            path: path.clone(),
            source: e,
        })?;
    Ok((f, path))
}
