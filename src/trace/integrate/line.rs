//! A streamline in flight, why one stops, and where an advance in a tile ended.

use glam::DVec3;
use serde::Serialize;

use super::Rk45;
use crate::trace::field::NoDirection;

/// Why a streamline stopped. Stored as u8 in `RUN/seeds/stop` (docs/format.md).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
#[repr(u8)]
pub enum Stop {
    /// It entered the stop ball around the center.
    Reached = 0,
    /// It reached a cell without phi (outside the solved region or the grid).
    LeftDomain = 1,
    /// The gradient vanished.
    Stalled = 2,
    /// It used the steps allowed.
    StepLimit = 3,
}

impl Stop {
    /// Every reason, in code order.
    pub const ALL: [Stop; 4] = [
        Stop::Reached,
        Stop::LeftDomain,
        Stop::Stalled,
        Stop::StepLimit,
    ];

    /// The name used in reports.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Stop::Reached => "reached",
            Stop::LeftDomain => "left_domain",
            Stop::Stalled => "stalled",
            Stop::StepLimit => "step_limit",
        }
    }

    pub(super) fn from(e: NoDirection) -> Self {
        match e {
            NoDirection::Outside => Stop::LeftDomain,
            NoDirection::Flat => Stop::Stalled,
        }
    }
}

/// A streamline in flight.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Line {
    /// Seed number.
    pub id: u32,
    /// Current point (voxel coordinates x, y, z).
    pub p: DVec3,
    /// Next step length to try (voxels); on levels, the ln u still to go to the next
    /// level.
    pub h: f64,
    /// Accepted steps.
    pub steps: u32,
    /// Arc length so far (voxels).
    pub length: f64,
    /// Escapes from flat sheets so far (see [`advance`](super::advance)).
    pub escapes: u16,
    /// On levels: the level k (ln u = k * level_step) the line is stepping to.
    pub level: Option<i32>,
    /// Arc length from which the line may step on levels.
    pub level_from: f64,
}

impl Line {
    /// A streamline from seed `id` at `p`, before its first step.
    #[must_use]
    pub fn new(id: u32, p: DVec3, rk: &Rk45) -> Self {
        Self {
            id,
            p,
            h: rk.first_h(),
            steps: 0,
            length: 0.0,
            escapes: 0,
            level: None,
            level_from: rk.level_after,
        }
    }
}

/// Escapes allowed per streamline.
pub const MAX_ESCAPES: u16 = 32;
/// How far (voxels) an escape looks for lower phi; with the cell, within a tile's halo.
pub const ESCAPE_RADIUS: i64 = 3;
/// Consecutive steps shorter than 1e-3 voxel that count as stalling.
pub(super) const STUCK_STEPS: u32 = 64;

/// Where a streamline's advance in one tile ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Advance {
    /// It stopped at `end` (the entry point into the stop ball when reached).
    Done(Stop, DVec3),
    /// It left the tile's own region; continue in the tile that owns `line.p`.
    Moved,
}
