//! Where the upwind map squeezes: how fast its direction turns across the flow.
//!
//! The arrival direction d is constant along a streamline, so its Jacobian (d d / d x,
//! by central differences) has one singular value near 0 (along the flow) and two
//! across it. The smaller of those two, sigma_2 (radians per voxel), says how far apart
//! two voxels are whose directions differ by a given angle: an angular error e of the
//! upwind map moves the inverse map's point by about e / sigma_2 voxels. The upwind
//! map's angle is off by about 1e-3 radians (0.06 degrees in the median on spot at
//! 128, 0.3 at the 90th percentile on cactus10k); where sigma_2 is below
//! [`SQUEEZE_BELOW`] that is more than a third of a voxel, and the hybrid map traces
//! those voxels exactly.

use glam::DVec3;

use super::upwind::is_set;

/// The hybrid map traces a streamline from every voxel where the upwind direction turns
/// by less than this across the flow (sigma_2, radians per voxel). On the standard
/// ball sigma_2 is 1 / r (r the distance from the center in voxels), above this up
/// to r = 333.
pub const SQUEEZE_BELOW: f64 = 0.003;

/// Whether sigma_2 of the direction field `d` at voxel `i` (as `sigma2` in the tests) is at least
/// `tau`, without the eigenvalues: the Gram matrix less tau^2 has at least two positive
/// eigenvalues, counted (its roots being real) by the sign changes of its
/// characteristic polynomial's coefficients. False where voxel `i` has no direction.
#[must_use]
#[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
pub fn turns_at_least(d: &[[f32; 3]], i: usize, strides: [usize; 3], tau: f64) -> bool {
    let Some(cols) = columns(d, i, strides) else {
        return false;
    };
    let t2 = tau * tau;
    let g = |a: usize, b: usize| cols[a].dot(cols[b]) - if a == b { t2 } else { 0.0 };
    let (m00, m11, m22, m01, m02, m12) = (g(0, 0), g(1, 1), g(2, 2), g(0, 1), g(0, 2), g(1, 2));
    let tr = m00 + m11 + m22;
    let c2 = m00 * m11 - m01 * m01 + m00 * m22 - m02 * m02 + m11 * m22 - m12 * m12;
    let det = m00 * (m11 * m22 - m12 * m12) - m01 * (m01 * m22 - m12 * m02)
        + m02 * (m01 * m12 - m11 * m02);
    // lambda^3 - tr lambda^2 + c2 lambda - det: sign changes = positive roots.
    let mut changes = 0;
    let mut last = 1.0f64;
    for c in [-tr, c2, -det] {
        if c != 0.0 {
            if c.signum() != last.signum() {
                changes += 1;
            }
            last = c;
        }
    }
    changes >= 2
}

/// The Jacobian's columns at voxel `i` of `d` (see `sigma2` in the tests); None where it has no
/// direction.
#[inline]
#[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
fn columns(d: &[[f32; 3]], i: usize, strides: [usize; 3]) -> Option<[DVec3; 3]> {
    let get = |j: usize| is_set(d[j]).then(|| DVec3::from_array(d[j].map(f64::from)));
    let c = get(i)?;
    let mut cols = [DVec3::ZERO; 3];
    for (k, col) in cols.iter_mut().enumerate() {
        let s = strides[k];
        *col = match (get(i - s), get(i + s)) {
            (Some(a), Some(b)) => (b - a) * 0.5,
            (None, Some(b)) => b - c,
            (Some(a), None) => c - a,
            (None, None) => DVec3::ZERO,
        };
    }
    Some(cols)
}

/// sigma_2 of the direction field `d` (x, y, z per voxel, all zero where there is none)
/// at voxel `i`, from its neighbours at `i -/+ strides[k]` (one per axis, any order):
/// central differences, one-sided where a neighbour has none, zero on an axis where
/// both lack one. None where voxel `i` itself has no direction.
#[cfg(test)]
#[must_use]
pub fn sigma2(d: &[[f32; 3]], i: usize, strides: [usize; 3]) -> Option<f64> {
    columns(d, i, strides).map(middle_singular_value)
}

/// The middle singular value of the 3 x 3 matrix with columns `cols`: the square root
/// of the middle eigenvalue of its Gram matrix (closed form for symmetric 3 x 3).
#[cfg(test)]
#[must_use]
#[allow(clippy::many_single_char_names)] // the names of the formulas (q, p, r, b)
pub fn middle_singular_value(cols: [DVec3; 3]) -> f64 {
    let m = [
        [
            cols[0].dot(cols[0]),
            cols[0].dot(cols[1]),
            cols[0].dot(cols[2]),
        ],
        [0.0, cols[1].dot(cols[1]), cols[1].dot(cols[2])],
        [0.0, 0.0, cols[2].dot(cols[2])],
    ];
    let p1 = m[0][1] * m[0][1] + m[0][2] * m[0][2] + m[1][2] * m[1][2];
    let e2 = if p1 == 0.0 {
        let mut d = [m[0][0], m[1][1], m[2][2]];
        d.sort_by(f64::total_cmp);
        d[1]
    } else {
        let q = (m[0][0] + m[1][1] + m[2][2]) / 3.0;
        let p2 = (m[0][0] - q).powi(2) + (m[1][1] - q).powi(2) + (m[2][2] - q).powi(2) + 2.0 * p1;
        let p = (p2 / 6.0).sqrt();
        let b = |r: usize, c: usize| {
            let (r, c) = (r.min(c), r.max(c));
            (m[r][c] - if r == c { q } else { 0.0 }) / p
        };
        let det = b(0, 0) * (b(1, 1) * b(2, 2) - b(1, 2) * b(1, 2))
            - b(0, 1) * (b(0, 1) * b(2, 2) - b(1, 2) * b(0, 2))
            + b(0, 2) * (b(0, 1) * b(1, 2) - b(1, 1) * b(0, 2));
        let phi = (det / 2.0).clamp(-1.0, 1.0).acos() / 3.0;
        let e1 = q + 2.0 * p * phi.cos();
        let e3 = q + 2.0 * p * (phi + 2.0 * std::f64::consts::FRAC_PI_3).cos();
        3.0 * q - e1 - e3
    };
    e2.max(0.0).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn middle_singular_value_of_known_matrices() {
        // Diagonal, in any order.
        let v = middle_singular_value([DVec3::X * 3.0, DVec3::Y * 0.5, DVec3::Z * 2.0]);
        assert!((v - 2.0).abs() < 1e-12, "{v}");
        // A rotation of diag(1e-2, 1e-5, 0): columns R diag R^T.
        let (c, s) = (0.6f64, 0.8f64);
        let r = [DVec3::new(c, s, 0.0), DVec3::new(-s, c, 0.0), DVec3::Z];
        let sv = [1e-2, 1e-5, 0.0];
        let cols: [DVec3; 3] = std::array::from_fn(|j| {
            (0..3).fold(DVec3::ZERO, |acc, k| acc + r[k] * sv[k] * r[k][j])
        });
        let v = middle_singular_value(cols);
        assert!((v - 1e-5).abs() < 1e-9, "{v}");
    }

    #[test]
    fn sigma2_of_a_radial_field_is_one_over_r() {
        // Directions from the center (0, 0, 0) on a 3^3 box around (x, y, z) = (0, 0, 20).
        let mut d = vec![[0f32; 3]; 27];
        for z in 0..3 {
            for y in 0..3 {
                for x in 0..3 {
                    let p = DVec3::new(x as f64 - 1.0, y as f64 - 1.0, z as f64 + 19.0);
                    let n = p.normalize();
                    d[(z * 3 + y) * 3 + x] = [n.x as f32, n.y as f32, n.z as f32];
                }
            }
        }
        let s = sigma2(&d, 13, [1, 3, 9]).expect("set");
        assert!((s - 0.05).abs() < 1e-3, "{s}");
        assert!(turns_at_least(&d, 13, [1, 3, 9], 0.049));
        assert!(!turns_at_least(&d, 13, [1, 3, 9], 0.051));
        d[13] = [0.0; 3];
        assert!(sigma2(&d, 13, [1, 3, 9]).is_none());
        assert!(!turns_at_least(&d, 13, [1, 3, 9], 0.0));
    }

    #[test]
    fn the_sign_count_agrees_with_the_eigenvalues() {
        // Pseudo-random direction fields on 3^3 boxes: the fast test against sigma2.
        let mut x = 0x2545_f491_4f6c_dd1du64;
        let mut rnd = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let mut checked = 0;
        for _ in 0..2000 {
            let scale = 10f64.powf(-4.0 * rnd().abs() * 2.0);
            let base = DVec3::new(rnd(), rnd(), rnd() + 2.0).normalize();
            let d: Vec<[f32; 3]> = (0..27)
                .map(|_| {
                    let v = (base + DVec3::new(rnd(), rnd(), rnd()) * scale).normalize();
                    [v.x as f32, v.y as f32, v.z as f32]
                })
                .collect();
            let s = sigma2(&d, 13, [1, 3, 9]).expect("set");
            for tau in [1e-4, 1e-3, 3e-3, 1e-2, 1e-1] {
                // Away from the threshold (where rounding may decide either way).
                if (s - tau).abs() > 1e-6 * tau.max(s) {
                    assert_eq!(
                        turns_at_least(&d, 13, [1, 3, 9], tau),
                        s >= tau,
                        "{s} {tau}"
                    );
                    checked += 1;
                }
            }
        }
        assert!(checked > 9000);
    }
}
