//! What stepping on levels of ln u reads from a tile: the f64 spline of the node
//! directions, of u and of its gradient; ln u and the velocity per unit of ln u.

use glam::DVec3;

use super::Tile;

/// The f64 quadratic B-spline of a tile's node values at a point.
struct LevelSpline {
    /// Of the node directions (not unit length).
    dir: DVec3,
    /// Of u, with the exterior layers' negative values taken as 0.
    u: f64,
    /// The gradient of `u`.
    grad: DVec3,
}

impl Tile {
    /// The quadratic B-spline at `p` of the node directions, of u (negative u, on the
    /// exterior layers, taken as 0) and the gradient of the latter, all in f64, if the
    /// tile holds the 27 nodes and all have a value. What stepping on levels of ln u
    /// reads ([`Tile::level`], [`Tile::level_velocity`]): there, neighbouring streamlines
    /// can lie 1e-6 voxel apart, and the f32 sum of [`Tile::spline`] rounds each
    /// evaluation by about 1e-8, differently for each.
    #[must_use]
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn level_spline(&self, p: DVec3) -> Option<LevelSpline> {
        let (base, t) = self.stencil(p)?;
        let strides = self.strides();
        let mut w = [[0.0f64; 3]; 3];
        let mut dw = [[0.0f64; 3]; 3];
        for a in 0..3 {
            let (lo, hi) = (0.5 - t[a], 0.5 + t[a]);
            w[a] = [0.5 * lo * lo, 0.75 - t[a] * t[a], 0.5 * hi * hi];
            // d/dt of the weights.
            dw[a] = [-lo, -2.0 * t[a], hi];
        }
        let mut dir = DVec3::ZERO;
        let (mut u, mut gx, mut gy, mut gz) = (0.0, 0.0, 0.0, 0.0);
        for dz in 0..3 {
            for dy in 0..3 {
                let row = &self.nodes[base + dz * strides[0] + dy * strides[1]..][..3];
                // Sums along x of the row: weighted, and weighted by the derivative.
                let (mut d, mut su, mut sdu) = (DVec3::ZERO, 0.0, 0.0);
                for (dx, n) in row.iter().enumerate() {
                    let v = f64::from(n.w);
                    if v.is_nan() {
                        return None;
                    }
                    let v = v.max(0.0);
                    d += n.truncate().as_dvec3() * w[2][dx];
                    su += v * w[2][dx];
                    sdu += v * dw[2][dx];
                }
                let wzy = w[0][dz] * w[1][dy];
                dir += d * wzy;
                u += su * wzy;
                gx += sdu * wzy;
                gy += su * w[0][dz] * dw[1][dy];
                gz += su * dw[0][dz] * w[1][dy];
            }
        }
        Some(LevelSpline {
            dir,
            u,
            grad: DVec3::new(gx, gy, gz),
        })
    }

    /// ln u at `p` and its gradient, from the quadratic B-spline of u (exterior layers
    /// at 0), where that is positive: the levels that surface seeds step on.
    #[must_use]
    pub fn level(&self, p: DVec3) -> Option<(f64, DVec3)> {
        let s = self.level_spline(p)?;
        (s.u > 0.0).then(|| (s.u.ln(), s.grad / s.u))
    }

    /// The velocity along the field's streamline through `p` per unit of ln u: the unit
    /// direction of the node-direction spline divided by the rate at which ln u rises
    /// along it. None where ln u has no value or rises too slowly along the direction
    /// (less than 1e-3 of its gradient): a streamline there cannot step on levels.
    #[must_use]
    pub fn level_velocity(&self, p: DVec3) -> Option<DVec3> {
        let s = self.level_spline(p)?;
        let f = s.dir.try_normalize()?;
        let rise = f.dot(s.grad);
        (s.u > 0.0 && rise > 1e-3 * s.grad.length()).then(|| f * (s.u / rise))
    }
}
