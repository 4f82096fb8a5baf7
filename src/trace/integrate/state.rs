//! The line state machine: a streamline's RK45 attempts in a tile (accept, reject,
//! shrink, escape a flat sheet, stop, leave the tile, switch to levels).

use glam::DVec3;

use super::core::{arrive, move_to, owns, Core, Leg};
use super::levels::{may_start_levels, on_levels, start_levels};
use super::tableau::{A, E};
use super::{Advance, Line, Stop, ESCAPE_RADIUS, MAX_ESCAPES, STUCK_STEPS};
use crate::trace::field::NoDirection;

/// A streamline on its own RK45 steps, between two attempts.
#[derive(Clone, Copy)]
pub(super) struct Own {
    /// The field at its point: the first stage of its next step.
    pub(super) k1: DVec3,
    /// Consecutive accepted steps shorter than 1e-3 voxel.
    pub(super) tiny: u32,
}

/// A line's first moves in a tile: ended already (in the stop ball), or on levels
/// until it ends or needs its own steps ([`resume`]).
pub(super) fn start(
    line: &mut Line,
    core: &Core<'_>,
    path: Option<&mut Vec<DVec3>>,
) -> Result<Own, Advance> {
    if let Some(e) = core.ball.entry(line.p, line.p) {
        return Err(Advance::Done(Stop::Reached, e));
    }
    // A seed may start on levels where it is (level_after 0); a line that moved here on
    // its own steps was tried where it is already, with the same answer.
    if line.steps == 0 && may_start_levels(line, core.rk) {
        start_levels(line, core.tile, core.rk);
    }
    resume(line, core, path)
}

/// Steps on levels while the line is on them ([`on_levels`]), then the field at its
/// point for its own steps: the line ready for an RK45 attempt, or how it ended.
pub(super) fn resume(
    line: &mut Line,
    core: &Core<'_>,
    mut path: Option<&mut Vec<DVec3>>,
) -> Result<Own, Advance> {
    loop {
        if line.level.is_some() {
            match on_levels(line, core, path.as_deref_mut()) {
                Leg::Ended(a) => return Err(a),
                Leg::Switch => continue,
            }
        }
        let k1 = match core.tile.direction(line.p) {
            Ok(k) => k,
            Err(e) => escape_or_stop(line, core, e, path)?,
        };
        return Ok(Own { k1, tiny: 0 });
    }
}

/// Stage `s` (1 to 6) of an RK45 step of `h` from `p`, with the stages before it in
/// `k`: the field at the stage point, or why there is none (Outside for a point more
/// than [`Rk45::reach`](super::Rk45::reach) from `p`, beyond what the tile must hold).
#[inline]
#[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
pub(super) fn stage(
    core: &Core<'_>,
    p: DVec3,
    h: f64,
    k: &[DVec3; 7],
    s: usize,
) -> Result<DVec3, NoDirection> {
    let mut q = p;
    for (j, kj) in k.iter().enumerate().take(s) {
        q += (h * A[s][j]) * *kj;
    }
    if (q - p).abs().max_element() > core.rk.reach() {
        return Err(NoDirection::Outside);
    }
    core.tile.direction(q)
}

/// Where a thin sheet stalls a streamline ([`after`]) or a line has no field: it moves
/// straight to the nearest node within [`ESCAPE_RADIUS`] where phi is lower than
/// anywhere around it, and goes on from there with the field there; or it ends, for `e`.
pub(super) fn escape_or_stop(
    line: &mut Line,
    core: &Core<'_>,
    e: NoDirection,
    path: Option<&mut Vec<DVec3>>,
) -> Result<DVec3, Advance> {
    let Core {
        tile,
        lo,
        hi,
        rk,
        ball,
    } = *core;
    let target = (e == NoDirection::Flat && line.escapes < MAX_ESCAPES)
        .then(|| tile.escape(line.p, ESCAPE_RADIUS))
        .flatten();
    let Some(q) = target else {
        return Err(Advance::Done(Stop::from(e), line.p));
    };
    let from = line.p;
    line.escapes += 1;
    move_to(line, q);
    line.h = rk.first_h();
    if let Some(en) = arrive(from, q, ball, path) {
        return Err(Advance::Done(Stop::Reached, en));
    }
    if !owns(lo, hi, q) {
        return Err(Advance::Moved);
    }
    tile.direction(line.p)
        .map_err(|e| Advance::Done(Stop::from(e), line.p))
}

/// What an RK45 attempt of `line.h` (its stages, or why one has no field) does to the
/// line: None when it goes on with another attempt (a rejected or shortened step, or an
/// accepted one that stays in the core), else how it ended or that it switches to
/// levels.
///
/// Where the solid is one or two voxels thick, every voxel is boundary: phi is exactly
/// 1 there and has no gradient, and streamlines stall on the sheet's midplane; such a
/// streamline escapes ([`escape_or_stop`]).
pub(super) fn after(
    line: &mut Line,
    own: &mut Own,
    core: &Core<'_>,
    attempt: Result<&[DVec3; 7], NoDirection>,
    mut path: Option<&mut Vec<DVec3>>,
) -> Option<Leg> {
    let Core {
        tile,
        lo,
        hi,
        rk,
        ball,
    } = *core;
    let h = line.h;
    let k = match attempt {
        Ok(k) => k,
        Err(e) => {
            // A stage left the field (or met a flat spot): try a shorter step.
            line.h = 0.5 * h;
            if line.h < rk.h_min {
                match escape_or_stop(line, core, e, path) {
                    Ok(k1) => own.k1 = k1,
                    Err(a) => return Some(Leg::Ended(a)),
                }
            }
            return None;
        }
    };
    // The 7th stage is at the 5th-order solution (FSAL).
    let mut q = line.p;
    for (j, kj) in k.iter().enumerate().take(6) {
        q += (h * A[6][j]) * *kj;
    }
    let mut err = DVec3::ZERO;
    for (j, kj) in k.iter().enumerate() {
        err += (h * E[j]) * *kj;
    }
    let ratio = err.abs().max_element() / rk.tolerance(h);
    // 0.9 ratio^(-1/5), clamped to [0.2, 5]; at the ends no power is needed, nor
    // where a step already at h_max grows (the factor is then over 1.0001 and the
    // next step is h_max whatever it is: most steps, in smooth regions).
    let factor = if ratio <= (0.9f64 / 5.0).powi(5) {
        5.0
    } else if ratio >= (0.9f64 / 0.2).powi(5) {
        0.2
    } else if ratio < 0.59 && h >= rk.h_max {
        1.0
    } else {
        0.9 * ratio.powf(-0.2)
    };
    // Too large an error: retry shorter (at the smallest step, accept it anyway).
    if ratio > 1.0 && h > rk.h_min {
        line.h = (h * factor).max(rk.h_min);
        return None;
    }
    let from = line.p;
    move_to(line, q);
    line.h = (h * factor).clamp(rk.h_min, rk.h_max);
    own.k1 = k[6];
    // (The step goes on the path, and a step into the ball ends the line, before the
    // check for stalling: a stalled line's last step could enter the ball.)
    if let Some(e) = arrive(from, q, ball, path.as_deref_mut()) {
        return Some(Leg::Ended(Advance::Done(Stop::Reached, e)));
    }
    // Zigzagging across a one-voxel sheet with tiny steps is stalling too.
    own.tiny = if h < 1e-3 { own.tiny + 1 } else { 0 };
    if own.tiny >= STUCK_STEPS {
        own.tiny = 0;
        match escape_or_stop(line, core, NoDirection::Flat, path) {
            Ok(k1) => own.k1 = k1,
            Err(a) => return Some(Leg::Ended(a)),
        }
        return None;
    }
    let leveled = may_start_levels(line, rk) && start_levels(line, tile, rk);
    if !owns(lo, hi, q) {
        return Some(Leg::Ended(Advance::Moved));
    }
    leveled.then_some(Leg::Switch)
}
