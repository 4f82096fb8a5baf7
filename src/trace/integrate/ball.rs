//! The stop ball around the center, where streamlines end.

use glam::DVec3;

/// The stop ball.
#[derive(Clone, Copy, Debug)]
pub struct StopBall {
    /// Center (voxel coordinates x, y, z).
    pub center: DVec3,
    /// Radius (voxels).
    pub radius: f64,
}

impl StopBall {
    /// The first point of segment `a -> b` inside the ball, if any.
    #[must_use]
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    pub fn entry(&self, a: DVec3, b: DVec3) -> Option<DVec3> {
        let r2 = self.radius * self.radius;
        let d = b - a;
        let f = a - self.center;
        if f.length_squared() <= r2 {
            return Some(a);
        }
        let dd = d.length_squared();
        if dd == 0.0 {
            return None;
        }
        // |f + t d|^2 = r^2, smallest t in [0, 1].
        let bq = f.dot(d);
        let c = f.length_squared() - r2;
        // From outside, a segment that does not head for the center cannot enter (its
        // smaller root is negative), nor one whose end is still clearly outside and
        // whose nearest point to the center lies beyond its end (both roots beyond 1).
        // Most segments, the steps toward the center of every streamline, end here
        // without the square root. "Clearly": the end's value |f + d|^2 - r^2 exceeds
        // 1e-9 bq^2 / dd, far above the rounding of the formula's t near 1 (about
        // 1e-16 bq^2 / dd relative), for steps of any length.
        if bq >= 0.0 || (-bq >= dd && (c + 2.0 * bq + dd) * dd > 1e-9 * bq * bq) {
            return None;
        }
        let disc = bq * bq - dd * c;
        if disc < 0.0 {
            return None;
        }
        let t = (-bq - disc.sqrt()) / dd;
        (0.0..=1.0).contains(&t).then(|| a + t * d)
    }
}
