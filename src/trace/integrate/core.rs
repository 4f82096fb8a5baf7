//! What both ways of stepping (a line's own RK45 steps and steps on levels) share: the
//! tile and its core, how a leg ended, and taking a step.

use glam::DVec3;

use super::{Advance, Line, Rk45, StopBall};
use crate::trace::field::Tile;

/// Does `tile` own `p`: is the cell of `p` in the tile's core `[lo, hi)` (grid indices
/// `[z, y, x]`)?
#[inline]
pub(super) fn owns(lo: [i64; 3], hi: [i64; 3], p: DVec3) -> bool {
    let c = [p.z.floor() as i64, p.y.floor() as i64, p.x.floor() as i64];
    (0..3).all(|a| c[a] >= lo[a] && c[a] < hi[a])
}

/// What both ways of stepping work with: the tile, its core `[lo, hi)`, the integrator
/// and the stop ball (see [`advance`](super::advance)).
#[derive(Clone, Copy)]
pub(super) struct Core<'a> {
    pub(super) tile: &'a Tile,
    pub(super) lo: [i64; 3],
    pub(super) hi: [i64; 3],
    pub(super) rk: &'a Rk45,
    pub(super) ball: &'a StopBall,
}

/// How one way of stepping left a streamline.
pub(super) enum Leg {
    /// As [`advance`](super::advance) returns it.
    Ended(Advance),
    /// It goes on with the other way of stepping (`line.level` says which).
    Switch,
}

/// Count a step of `line` to `q` and take it.
pub(super) fn move_to(line: &mut Line, q: DVec3) {
    line.steps += 1;
    line.length += (q - line.p).length();
    line.p = q;
}

/// After a step `from -> q`: where it enters the ball, if it does (the streamline ends
/// there). The entry, or else `q`, goes on the path.
pub(super) fn arrive(
    from: DVec3,
    q: DVec3,
    ball: &StopBall,
    path: Option<&mut Vec<DVec3>>,
) -> Option<DVec3> {
    let entry = ball.entry(from, q);
    if let Some(path) = path {
        path.push(entry.unwrap_or(q));
    }
    entry
}
