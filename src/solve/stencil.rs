//! The 7-point stencil at one voxel, which every kernel computes through (boxes in
//! [`super::boxops`], whole arrays in [`super::flat`], the Jacobi pass), so that they
//! give the same bytes; and the over-relaxation factor of red-black SOR.

/// The optimal SOR factor for the model problem on a domain about `n` voxels across:
/// `2 / (1 + sin(pi / n))`.
#[must_use]
pub fn optimal_omega(n: f64) -> f64 {
    2.0 / (1.0 + (std::f64::consts::PI / n.max(2.0)).sin())
}

/// The defect `f + nb - 6 u` of a voxel whose value is `u` and whose six neighbours sum
/// to `nb`, added in the order x-, x+, y-, y+, z-, z+. Every kernel computes through
/// this and [`full_weighting`], so they give the same bytes.
#[inline]
#[must_use]
pub fn defect_of(f: f64, nb: f64, u: f64) -> f64 {
    f + nb - 6.0 * u
}

/// The defect at offset `i` of a C-order array with strides `sy`, `sz`.
#[inline]
#[must_use]
pub fn defect_at(u: &[f64], f: Option<&[f64]>, i: usize, sy: usize, sz: usize) -> f64 {
    let nb = u[i - 1] + u[i + 1] + u[i - sy] + u[i + sy] + u[i - sz] + u[i + sz];
    defect_of(f.map_or(0.0, |f| f[i]), nb, u[i])
}

/// Full weighting with the coarse-level scaling at the fine offset `c` of the defect
/// array `d` (strides `sy`, `sz`): `4 * sum_d w(d) D(c + d)` with `w` = 1/8 at the
/// center, 1/16 on faces, 1/32 on edges, 1/64 at corners, summed z, y, x.
#[inline]
#[must_use]
pub fn full_weighting(d: &[f64], c: usize, sy: usize, sz: usize) -> f64 {
    const W: [f64; 3] = [0.5, 1.0, 0.5];
    let mut s = 0.0;
    for (dz, wz) in W.iter().enumerate() {
        for (dy, wy) in W.iter().enumerate() {
            for (dx, wx) in W.iter().enumerate() {
                let i = c + dz * sz + dy * sy + dx - sz - sy - 1;
                s += wz * wy * wx * d[i];
            }
        }
    }
    // Weights above sum to 8; full weighting's sum to 1; times 4.
    s * 0.5
}

/// The term of `c . A c` at an unknown with correction `c` and neighbour sum `nb`.
#[inline]
#[must_use]
pub fn energy_term(c: f64, nb: f64) -> f64 {
    c * (6.0 * c - nb)
}
