//! Shared numeric aliases and index helpers.
//!
//! Axis order is `[z, y, x]` for every index triple; points are `(x, y, z)` in world
//! units. Grid indices are `u64`: grids of 10^9 voxels and more are the normal case.

/// A point or vector in world units, `(x, y, z)`.
pub type Vec3 = glam::DVec3;

/// A voxel or block index `[z, y, x]`.
pub type Idx3 = [u64; 3];

/// The trilinear weight of the cell corner `corner` (0 or 1 per axis) for a point at
/// fractions `t` of its cell, in the same axis order: the product, first axis first.
#[inline]
#[must_use]
pub fn corner_weight(t: [f64; 3], corner: [usize; 3]) -> f64 {
    (0..3)
        .map(|a| if corner[a] == 1 { t[a] } else { 1.0 - t[a] })
        .product()
}

/// Product of the three extents, as `u64`.
#[must_use]
pub fn volume(shape: Idx3) -> u64 {
    shape[0] * shape[1] * shape[2]
}

/// floor(x) as an integer without a libm call (x finite and well inside i64).
#[inline]
#[must_use]
pub fn floor(x: f64) -> i64 {
    let i = x as i64;
    i - i64::from((i as f64) > x)
}

/// Small deterministic pseudo-random numbers for tests (xorshift64).
#[cfg(test)]
pub(crate) struct TestRng(pub(crate) u64);

#[cfg(test)]
impl TestRng {
    /// The next value, in [0, 1). The state must not be zero.
    pub(crate) fn next_f64(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}
