//! The rules that give one voxel its direction from its neighbours': the
//! semi-Lagrangian step along the tracer's field ([`Region::follow`]), the one-cell
//! upwind rule ([`upwind`]), and the mean of the neighbours for voxels without an
//! upwind neighbour ([`mean_of_neighbours`]).

use glam::DVec3;

use super::directions::{get, is_target, known};
use crate::math::floor;
use crate::trace::field::Tile;
use crate::trace::integrate::StopBall;

/// What a rule gives a voxel.
pub(super) enum Upwind {
    /// From the upwind neighbours.
    Value(DVec3),
    /// Inside the stop ball: the direction from the center.
    Ball(DVec3),
    /// Set from the neighbours (no upwind neighbour).
    Filled(DVec3),
    /// An upwind neighbour has no direction yet.
    Wait,
    /// No neighbour has a higher u.
    Flat,
    /// The voxel needs data beyond what this visit read (a voxel of the halo).
    Skip,
}

/// Length (voxels) of each midpoint step of the short streamline a voxel follows before
/// it interpolates the direction, and the number of steps.
const STEP: f64 = 2.0;
const STEPS: usize = 1;

/// What a visit holds: u and labels with the halo, and the tracer's direction field.
pub(super) struct Region<'a> {
    /// u with the halo.
    pub(super) u: &'a [f64],
    /// Labels with the halo.
    pub(super) lab: &'a [u8],
    /// The shape of the block with its halo.
    pub(super) hs: [usize; 3],
    /// Grid index [z, y, x] of local voxel 0.
    pub(super) origin: [i64; 3],
    /// The tracer's direction field over the block and its halo.
    pub(super) tile: &'a Tile,
    /// The stop ball.
    pub(super) ball: &'a StopBall,
}

impl Region<'_> {
    /// Whether the cells within `m` voxels of the cell of `q` all lie in the tile.
    #[inline]
    fn safe(&self, q: DVec3, m: i64) -> bool {
        let c = [floor(q.z), floor(q.y), floor(q.x)];
        (0..3).all(|a| {
            c[a] - m >= self.tile.origin[a]
                && c[a] + m + 1 < self.tile.origin[a] + self.tile.shape[a] as i64
        })
    }

    /// The semi-Lagrangian step: follow the streamline through `p` (u = `ux`) uphill
    /// in u for `STEPS` midpoint steps with the tracer's field, then interpolate the
    /// direction trilinearly at the foot from the corners of its cell, which all lie
    /// higher in u (else Flat, and the caller takes the one-cell upwind rule). A path
    /// that enters the stop ball takes the direction of its entry point.
    #[inline]
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    pub(super) fn follow(&self, d: &[[f32; 3]], p: DVec3, ux: f64) -> Upwind {
        let reach = STEP.ceil() as i64;
        let mut q = p;
        for _ in 0..STEPS {
            if !self.safe(q, reach) {
                return Upwind::Skip;
            }
            // At the voxel itself the node's own direction; later the interpolant.
            let first = if q == p {
                self.tile
                    .node([q.z as i64, q.y as i64, q.x as i64])
                    .map_or_else(|| self.tile.direction(q), Ok)
            } else {
                self.tile.direction(q)
            };
            let Ok(k1) = first else { break };
            let Ok(k2) = self.tile.direction(q + 0.5 * STEP * k1) else {
                break;
            };
            let next = q + STEP * k2;
            if let Some(e) = self.ball.entry(q, next) {
                let r = e - self.ball.center;
                return if r.length() > 0.0 {
                    Upwind::Value(r.normalize())
                } else {
                    Upwind::Flat
                };
            }
            q = next;
        }
        if q == p || !self.safe(q, 0) {
            return Upwind::Flat;
        }
        let f = [floor(q.z) as f64, floor(q.y) as f64, floor(q.x) as f64];
        let t = [q.z - f[0], q.y - f[1], q.x - f[2]];
        let l: [usize; 3] = std::array::from_fn(|a| (f[a] as i64 - self.origin[a]) as usize);
        let mut acc = DVec3::ZERO;
        let mut wsum = 0.0;
        for k in 0..8 {
            let o = [k >> 2, (k >> 1) & 1, k & 1];
            let w = crate::math::corner_weight(t, o);
            let n = ((l[0] + o[0]) * self.hs[1] + l[1] + o[1]) * self.hs[2] + l[2] + o[2];
            if w == 0.0 || !is_target(self.lab[n]) {
                continue;
            }
            if self.u[n] <= ux {
                return Upwind::Flat;
            }
            if !known(d, n) {
                return Upwind::Wait;
            }
            acc += w * get(d, n);
            wsum += w;
        }
        let len = acc.length();
        if wsum == 0.0 || len < 1e-3 * wsum {
            return Upwind::Flat;
        }
        Upwind::Value(acc / len)
    }
}

/// The one-cell upwind rule for voxel `i` (u = `ux`): on each axis the neighbour of
/// higher u, weighted by the difference.
#[inline]
pub(super) fn upwind(
    u: &[f64],
    lab: &[u8],
    d: &[[f32; 3]],
    i: usize,
    ux: f64,
    strides: [usize; 3],
) -> Upwind {
    let mut acc = DVec3::ZERO;
    let mut any = false;
    let mut strongest = (0.0, DVec3::ZERO);
    for s in strides {
        let (lo, hi) = (i - s, i + s);
        let pick = match (
            is_target(lab[lo]) && u[lo] > ux,
            is_target(lab[hi]) && u[hi] > ux,
        ) {
            (true, true) => Some(if u[hi] > u[lo] { hi } else { lo }),
            (true, false) => Some(lo),
            (false, true) => Some(hi),
            (false, false) => None,
        };
        if let Some(n) = pick {
            if !known(d, n) {
                return Upwind::Wait;
            }
            let w = u[n] - ux;
            let dn = get(d, n);
            acc += w * dn;
            any = true;
            if w > strongest.0 {
                strongest = (w, dn);
            }
        }
    }
    if !any {
        return Upwind::Flat;
    }
    let len = acc.length();
    // Opposite neighbours can cancel (a ridge between two arrival regions): take the
    // steepest one rather than an arbitrary direction.
    Upwind::Value(if len > 1e-3 * strongest.0 {
        acc / len
    } else {
        strongest.1.normalize()
    })
}

/// The mean direction of the 26 neighbours of voxel `i` that have one, if any does.
#[inline]
pub(super) fn mean_of_neighbours(
    lab: &[u8],
    d: &[[f32; 3]],
    i: usize,
    strides: [usize; 3],
) -> Option<DVec3> {
    let mut acc = DVec3::ZERO;
    let mut any = None;
    for dz in -1i64..=1 {
        for dy in -1i64..=1 {
            for dx in -1i64..=1 {
                if (dz, dy, dx) == (0, 0, 0) {
                    continue;
                }
                let off = dz * strides[0] as i64 + dy * strides[1] as i64 + dx;
                let n = (i as i64 + off) as usize;
                if is_target(lab[n]) && known(d, n) {
                    let g = get(d, n);
                    acc += g;
                    any.get_or_insert(g);
                }
            }
        }
    }
    let first = any?;
    let len = acc.length();
    Some(if len > 1e-6 {
        acc / len
    } else {
        first.normalize()
    })
}
