//! The integrator's settings: tolerances, step limits, and stepping on levels.

use serde::{Deserialize, Serialize};

use crate::trace::seeds::SeedKind;

/// Integrator settings (lengths in voxels).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Rk45 {
    /// Local error allowed per step (voxels).
    pub atol: f64,
    /// Local error allowed per voxel of step: a step of h voxels may err by
    /// `atol + rtol * h` voxels. (Positions have no natural scale, so the relative
    /// tolerance is to the step's length, not to the coordinates.)
    #[serde(default)]
    pub rtol: f64,
    /// Smallest step; a streamline that needs a smaller one stops.
    pub h_min: f64,
    /// Largest step.
    pub h_max: f64,
    /// Steps allowed per streamline.
    pub max_steps: u32,
    /// Stepping on levels of ln u (u = 1 - phi), 0 for off: after [`LEVEL_AFTER`]
    /// voxels on its own steps, a streamline takes fixed steps of this much ln u (4th
    /// order Runge-Kutta), each ending on the level `ln u = k * level_step`, so that
    /// neighbouring streamlines stay level with each other (see [`advance`](super::advance)).
    #[serde(default)]
    pub level_step: f64,
    /// Arc length (voxels) on RK45's own steps before a streamline steps on levels
    /// ([`LEVEL_AFTER`] by default; 0 for seeds inside the solid, as the exact map's).
    #[serde(default = "level_after")]
    pub level_after: f64,
}

fn level_after() -> f64 {
    LEVEL_AFTER
}

impl Default for Rk45 {
    fn default() -> Self {
        Self {
            atol: 1e-6,
            rtol: 0.0,
            h_min: 1e-6,
            h_max: 2.0,
            max_steps: 20_000,
            level_step: 0.0,
            level_after: LEVEL_AFTER,
        }
    }
}

/// The smallest nonzero [`Rk45::level_step`]: levels are counted in i32, and ln u of the
/// f64 spline of u is above -746 where it is positive.
pub const MIN_LEVEL_STEP: f64 = 1e-4;
/// The largest [`Rk45::level_step`].
pub const MAX_LEVEL_STEP: f64 = 1.0;
/// Arc length (voxels) a streamline runs on its own RK45 steps before it steps on levels
/// of ln u (when [`Rk45::level_step`] is not 0). Below the surface, ln u of the B-spline
/// still reads the exterior layers; two voxels in, the streamlines of a thin arm have
/// hardly begun to converge.
pub const LEVEL_AFTER: f64 = 2.0;

/// The largest `h_max` allowed: a tile holds 1.5 h_max + 2 nodes of halo.
pub const MAX_H_MAX: f64 = 16.0;

impl Rk45 {
    /// Local error per step (voxels) by default for surface seeds: the vertices of a
    /// mesh, whose sphere triangles can be as small as 1e-10 of the sphere. Their
    /// orientation needs neighbouring streamlines that do not differ by the step
    /// control's noise: on spot at resolution 128, 14 triangles flip at 1e-8 against 60
    /// at 1e-6, with about the field evaluations the trilinear field took at 1e-6.
    pub const SURFACE_ATOL: f64 = 1e-8;

    /// Step in ln u by default for surface seeds, which step on levels: cactus10k at
    /// resolution 128 has no flipped triangle with it (1,779 without), at 419 steps per
    /// line; 0.02 gives the same counts at 2.4 times the steps.
    pub const SURFACE_LEVEL_STEP: f64 = 0.05;

    /// The default integrator for `seeds`: [`Rk45::default`], with an atol of
    /// [`Rk45::SURFACE_ATOL`] for surface seeds.
    #[must_use]
    pub fn for_seeds(seeds: SeedKind) -> Self {
        match seeds {
            SeedKind::Boundary => Self::default(),
            SeedKind::Surface => Self {
                atol: Self::SURFACE_ATOL,
                level_step: Self::SURFACE_LEVEL_STEP,
                ..Self::default()
            },
        }
    }

    /// Why these settings cannot work (naming the `harmap trace` flags), if they cannot.
    #[must_use]
    pub fn problem(&self) -> Option<String> {
        let finite = [
            self.atol,
            self.rtol,
            self.h_min,
            self.h_max,
            self.level_step,
        ]
        .iter()
        .all(|v| v.is_finite());
        if !finite {
            return Some(format!(
                "--atol {} --rtol {} --h-min {} --h-max {} --level-step {}: give finite numbers",
                self.atol, self.rtol, self.h_min, self.h_max, self.level_step
            ));
        }
        if self.atol < 0.0 || self.rtol < 0.0 || self.atol + self.rtol <= 0.0 {
            return Some(format!(
                "--atol {} --rtol {}: give tolerances that are zero or more, not both zero",
                self.atol, self.rtol
            ));
        }
        if !(self.h_min > 0.0 && self.h_min <= self.h_max && self.h_max <= MAX_H_MAX) {
            return Some(format!(
                "--h-min {} --h-max {}: give 0 < h-min <= h-max <= {MAX_H_MAX} voxels",
                self.h_min, self.h_max
            ));
        }
        if self.level_step != 0.0 && !(MIN_LEVEL_STEP..=MAX_LEVEL_STEP).contains(&self.level_step) {
            return Some(format!(
                "--level-step {}: give 0 (off) or a step in ln u from {MIN_LEVEL_STEP} to {MAX_LEVEL_STEP}",
                self.level_step
            ));
        }
        if self.level_after < 0.0 {
            return Some(format!(
                "level_after {}: give a length of zero or more",
                self.level_after
            ));
        }
        if self.max_steps == 0 {
            return Some("--max-steps 0: allow at least one step".into());
        }
        None
    }

    /// The first step a streamline tries, and tries again after an escape or on leaving
    /// the levels (voxels).
    #[must_use]
    pub fn first_h(&self) -> f64 {
        0.5_f64.clamp(self.h_min, self.h_max)
    }

    /// The error a step of length `h` may make.
    #[inline]
    #[must_use]
    pub fn tolerance(&self, h: f64) -> f64 {
        self.atol + self.rtol * h
    }

    /// How far (voxels, per axis) from a step's start its stage points may lie: steps
    /// whose stages stray farther are rejected, so a tile needs this many nodes of halo
    /// around the points it owns, plus the spline's reach ([`Tiling::halo_for`](crate::trace::tiles::Tiling::halo_for)).
    #[must_use]
    pub fn reach(&self) -> f64 {
        1.5 * self.h_max
    }
}
