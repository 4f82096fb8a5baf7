//! Stepping on levels of ln u: classic RK4 steps in ln u, each landed on its level by
//! Newton steps; the sequence the exact map takes and the inverse map undoes.

use glam::DVec3;

use super::core::{arrive, move_to, owns, Core, Leg};
use super::{Advance, Line, Rk45, Stop, StopBall, LEVEL_AFTER};
use crate::trace::field::Tile;

/// Whether `line` may go on levels where it is: not on them yet, levels on, and far
/// enough along.
pub(super) fn may_start_levels(line: &Line, rk: &Rk45) -> bool {
    line.level.is_none() && rk.level_step > 0.0 && line.length >= line.level_from
}

/// Put `line` on levels, heading to the first level at or above ln u at its point, if
/// it can step on levels there.
pub(super) fn start_levels(line: &mut Line, tile: &Tile, rk: &Rk45) -> bool {
    let Some((l, _)) = tile.level(line.p) else {
        return false;
    };
    let k = (l / rk.level_step).ceil();
    if tile.level_velocity(line.p).is_none()
        || !(k >= f64::from(i32::MIN) && k < f64::from(i32::MAX))
    {
        return false;
    }
    line.level = Some(k as i32);
    line.h = k * rk.level_step - l;
    true
}

/// Back to the streamline's own steps, for [`LEVEL_AFTER`] voxels at least.
pub(super) fn leave_levels(line: &mut Line, rk: &Rk45) -> Leg {
    line.level = None;
    line.level_from = line.length + LEVEL_AFTER;
    line.h = rk.first_h();
    Leg::Switch
}

/// Steps on levels of ln u: the streamline's equation with ln u as its parameter
/// ([`Tile::level_velocity`]), classic 4th-order Runge-Kutta, fixed steps of
/// [`Rk45::level_step`] in ln u (split where one would be longer than `h_max` voxels),
/// each ending with a Newton correction onto its level.
///
/// Why: the streamlines from a thin arm converge exponentially, to 1e-6 voxel apart
/// and less, while two of them at the same step count can lie a voxel apart along the
/// flow. On its own steps each streamline's error depends on where it is along the flow,
/// and a voxel's difference there leaks across into their tiny separation: their order
/// on the sphere turns random (cactus10k: 1,779 flipped triangles at atol 1e-8, 912 with
/// fixed steps of 0.1 voxel). Stepping on levels, every step of every streamline ends on
/// the same level, so neighbours differ only across the flow, and the numbers that
/// decide their order there are computed relative to their separation (cactus10k: none
/// flipped).
pub(super) fn on_levels(
    line: &mut Line,
    core: &Core<'_>,
    mut path: Option<&mut Vec<DVec3>>,
) -> Leg {
    let (rk, mut field) = (core.rk, core.tile);
    loop {
        if line.steps >= rk.max_steps {
            return Leg::Ended(Advance::Done(Stop::StepLimit, line.p));
        }
        let Some(level) = line.level else {
            return leave_levels(line, rk);
        };
        let p = line.p;
        let target = f64::from(level) * rk.level_step;
        let Some((q, left, landed)) = level_advance(&mut field, p, line.h, target, rk) else {
            return leave_levels(line, rk);
        };
        if landed {
            // (None only past i32::MAX: the next round leaves the levels.)
            line.level = level.checked_add(1);
            line.h = rk.level_step;
        } else {
            line.h = left;
        }
        move_to(line, q);
        if let Some(e) = arrive(p, q, core.ball, path.as_deref_mut()) {
            return Leg::Ended(Advance::Done(Stop::Reached, e));
        }
        if !owns(core.lo, core.hi, q) {
            return Leg::Ended(Advance::Moved);
        }
    }
}

/// What stepping on levels reads: ln u and the velocity per unit of ln u
/// ([`Tile::level`], [`Tile::level_velocity`]), from one tile or from whichever tile
/// holds the point (the values are the same).
pub trait LevelField {
    /// ln u and its gradient at `q`.
    fn level(&mut self, q: DVec3) -> Option<(f64, DVec3)>;
    /// dx / d(ln u) along the streamline through `q`.
    fn velocity(&mut self, q: DVec3) -> Option<DVec3>;
}

impl LevelField for &Tile {
    fn level(&mut self, q: DVec3) -> Option<(f64, DVec3)> {
        Tile::level(self, q)
    }
    fn velocity(&mut self, q: DVec3) -> Option<DVec3> {
        self.level_velocity(q)
    }
}

/// One classic RK4 step on levels from `p`, over `rest` of ln u or as much of it as
/// keeps the step within h_max voxels: the new point and the ln u stepped. None where
/// a stage has no velocity or strays more than [`Rk45::reach`] from `p`.
pub fn level_substep<F: LevelField>(
    f: &mut F,
    p: DVec3,
    rest: f64,
    rk: &Rk45,
) -> Option<(DVec3, f64)> {
    let reach = rk.reach();
    let mut stage = |q: DVec3| {
        if (q - p).abs().max_element() > reach {
            None
        } else {
            f.velocity(q)
        }
    };
    let k1 = stage(p)?;
    let d = rest.min(rk.h_max / k1.length());
    let k2 = stage(p + (0.5 * d) * k1)?;
    let k3 = stage(p + (0.5 * d) * k2)?;
    let k4 = stage(p + d * k3)?;
    let q = p + (d / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
    ((q - p).abs().max_element() <= reach).then_some((q, d))
}

/// One sub-step on levels from `p`, `rest` of ln u short of the level `target` (ln u),
/// landed on the level by [`onto_level`] when it reaches it: the new point, the ln u
/// left, and whether it landed. The one sequence both [`on_levels`] and
/// [`level_step`] (which the inverse map undoes) take, so that they agree to the bit.
pub fn level_advance<F: LevelField>(
    f: &mut F,
    p: DVec3,
    rest: f64,
    target: f64,
    rk: &Rk45,
) -> Option<(DVec3, f64, bool)> {
    let (q, d) = level_substep(f, p, rest, rk)?;
    let left = rest - d;
    if finishes_level(left, rk) {
        Some((onto_level(f, q, target), left, true))
    } else {
        Some((q, left, false))
    }
}

/// Whether `rest` of ln u left after a sub-step means the level is reached.
#[must_use]
pub fn finishes_level(rest: f64, rk: &Rk45) -> bool {
    rest <= 1e-9 * rk.level_step
}

/// `q` moved onto ln u = `target` by two Newton steps along grad(ln u) (each skipped
/// where it would move more than half a voxel, or where ln u has no value).
#[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
pub fn onto_level<F: LevelField>(f: &mut F, mut q: DVec3, target: f64) -> DVec3 {
    for _ in 0..2 {
        let Some((l, g)) = f.level(q) else { break };
        let m = (l - target) / g.length_squared();
        if !m.is_finite() || (m * g).length() > 0.5 {
            break;
        }
        q -= m * g;
    }
    q
}

/// Where a streamline on levels ends up: on its level, or entering the ball.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LevelEnd {
    /// On the level (ln u = target).
    Level(DVec3),
    /// The point where it entered the stop ball.
    Ball(DVec3),
}

impl LevelEnd {
    /// The point on the level, if the streamline got there before the ball.
    #[must_use]
    pub fn on_level(self) -> Option<DVec3> {
        match self {
            LevelEnd::Level(p) => Some(p),
            LevelEnd::Ball(_) => None,
        }
    }
}

/// The sub-steps of [`on_levels`] from `p`, `rest` of ln u short of the level `target`
/// (ln u), without the tiles: where the streamline lands on that level, or where it
/// enters `ball` first. What the inverse map undoes.
pub fn level_step<F: LevelField>(
    f: &mut F,
    mut p: DVec3,
    mut rest: f64,
    target: f64,
    rk: &Rk45,
    ball: &StopBall,
) -> Option<LevelEnd> {
    for _ in 0..1000 {
        let (q, left, landed) = level_advance(f, p, rest, target, rk)?;
        if let Some(e) = ball.entry(p, q) {
            return Some(LevelEnd::Ball(e));
        }
        if landed {
            return Some(LevelEnd::Level(q));
        }
        (p, rest) = (q, left);
    }
    None
}
