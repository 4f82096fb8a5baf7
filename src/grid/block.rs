//! `Block`: an owned box of voxels at a known place in the grid, possibly with a halo.

use crate::math::Idx3;

/// An owned C-order box of voxels `[z, y, x]` whose first voxel sits at grid index
/// `origin` (which may be negative, or run past the grid, when the box carries a halo).
#[derive(Clone, Debug, PartialEq)]
pub struct Block<T> {
    /// Grid index of the first voxel of the box; negative where a halo runs off the grid.
    pub origin: [i64; 3],
    /// Extent of the box, `[z, y, x]`.
    pub shape: [usize; 3],
    /// The voxels, C order.
    pub data: Vec<T>,
}

impl<T: Copy> Block<T> {
    /// A box of `shape` at `origin` filled with `value`.
    #[must_use]
    pub fn filled(origin: [i64; 3], shape: [usize; 3], value: T) -> Self {
        Self {
            origin,
            shape,
            data: vec![value; shape[0] * shape[1] * shape[2]],
        }
    }

    /// Offset of local `(z, y, x)`.
    #[inline]
    #[must_use]
    pub fn offset(&self, z: usize, y: usize, x: usize) -> usize {
        (z * self.shape[1] + y) * self.shape[2] + x
    }

    /// The value at global grid index `g` (must lie inside the box).
    #[inline]
    #[must_use]
    pub fn at_global(&self, g: [i64; 3]) -> T {
        let l = [0, 1, 2].map(|a| (g[a] - self.origin[a]) as usize);
        self.data[self.offset(l[0], l[1], l[2])]
    }

    /// Copy the inner box `[start, start + shape)` (local coordinates) out.
    #[must_use]
    pub fn crop(&self, start: [usize; 3], shape: [usize; 3]) -> Vec<T> {
        let mut out = Vec::with_capacity(shape[0] * shape[1] * shape[2]);
        for z in 0..shape[0] {
            for y in 0..shape[1] {
                let o = self.offset(start[0] + z, start[1] + y, start[2]);
                out.extend_from_slice(&self.data[o..o + shape[2]]);
            }
        }
        out
    }
}

/// Copy the overlap of a source box into a destination box, both in grid coordinates.
pub fn copy_overlap<T: Copy>(
    src: &[T],
    src_origin: [i64; 3],
    src_shape: [usize; 3],
    dst: &mut Block<T>,
) {
    let lo = [0, 1, 2].map(|a| src_origin[a].max(dst.origin[a]));
    let hi = [0, 1, 2]
        .map(|a| (src_origin[a] + src_shape[a] as i64).min(dst.origin[a] + dst.shape[a] as i64));
    if (0..3).any(|a| lo[a] >= hi[a]) {
        return;
    }
    let n = (hi[2] - lo[2]) as usize;
    for z in lo[0]..hi[0] {
        for y in lo[1]..hi[1] {
            let s = ((((z - src_origin[0]) as usize) * src_shape[1]
                + (y - src_origin[1]) as usize)
                * src_shape[2])
                + (lo[2] - src_origin[2]) as usize;
            let d = dst.offset(
                (z - dst.origin[0]) as usize,
                (y - dst.origin[1]) as usize,
                (lo[2] - dst.origin[2]) as usize,
            );
            dst.data[d..d + n].copy_from_slice(&src[s..s + n]);
        }
    }
}

/// Convert a `u64` index triple to a `usize` shape.
#[must_use]
pub fn to_usize(v: Idx3) -> [usize; 3] {
    v.map(|c| c as usize)
}
