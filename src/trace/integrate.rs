//! Dormand–Prince RK45 along the unit direction field, with error control.
//!
//! The streamline is parameterized by arc length (the field is a unit vector), so the
//! step `h` is a length in voxels. Every decision (accept, reject, shrink, stop) depends
//! only on the field values at the points the method visits, never on which tile holds
//! them: a streamline is the same whatever the tiling or the thread that runs it.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use super::field::{NoDirection, Tile};
use super::seeds::SeedKind;

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
}

impl Default for Rk45 {
    fn default() -> Self {
        Self {
            atol: 1e-6,
            rtol: 0.0,
            h_min: 1e-6,
            h_max: 2.0,
            max_steps: 20_000,
        }
    }
}

/// The largest `h_max` allowed: a tile holds 1.5 h_max + 2 nodes of halo.
pub const MAX_H_MAX: f64 = 16.0;

impl Rk45 {
    /// Local error per step (voxels) by default for surface seeds: the vertices of a
    /// mesh, whose sphere triangles can be as small as 1e-10 of the sphere. Their
    /// orientation needs neighbouring streamlines that do not differ by the step
    /// control's noise: on spot at resolution 128, 14 triangles flip at 1e-8 against 60
    /// at 1e-6, with about the field evaluations the trilinear field took at 1e-6.
    pub const SURFACE_ATOL: f64 = 1e-8;

    /// The default integrator for `seeds`: [`Rk45::default`], with an atol of
    /// [`Rk45::SURFACE_ATOL`] for surface seeds.
    #[must_use]
    pub fn for_seeds(seeds: SeedKind) -> Self {
        match seeds {
            SeedKind::Boundary => Self::default(),
            SeedKind::Surface => Self {
                atol: Self::SURFACE_ATOL,
                ..Self::default()
            },
        }
    }

    /// Why these settings cannot work (naming the `harmap trace` flags), if they cannot.
    #[must_use]
    pub fn problem(&self) -> Option<String> {
        let finite = [self.atol, self.rtol, self.h_min, self.h_max]
            .iter()
            .all(|v| v.is_finite());
        if !finite {
            return Some(format!(
                "--atol {} --rtol {} --h-min {} --h-max {}: give finite numbers",
                self.atol, self.rtol, self.h_min, self.h_max
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
        if self.max_steps == 0 {
            return Some("--max-steps 0: allow at least one step".into());
        }
        None
    }

    /// The error a step of length `h` may make.
    #[inline]
    #[must_use]
    pub fn tolerance(&self, h: f64) -> f64 {
        self.atol + self.rtol * h
    }

    /// How far (voxels, per axis) from a step's start its stage points may lie: steps
    /// whose stages stray farther are rejected, so a tile needs this many nodes of halo
    /// around the points it owns, plus the spline's reach ([`super::tiles::Tiling::halo_for`]).
    #[must_use]
    pub fn reach(&self) -> f64 {
        1.5 * self.h_max
    }
}

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

    fn from(e: NoDirection) -> Self {
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
    /// Next step length to try.
    pub h: f64,
    /// Accepted steps.
    pub steps: u32,
    /// Arc length so far (voxels).
    pub length: f64,
    /// Escapes from flat sheets so far (see [`advance`]).
    pub escapes: u16,
}

/// Escapes allowed per streamline.
pub const MAX_ESCAPES: u16 = 32;
/// How far (voxels) an escape looks for lower phi; with the cell, within a tile's halo.
pub const ESCAPE_RADIUS: i64 = 3;
/// Consecutive steps shorter than 1e-3 voxel that count as stalling.
const STUCK_STEPS: u32 = 64;

/// Where a streamline's advance in one tile ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Advance {
    /// It stopped at `end` (the entry point into the stop ball when reached).
    Done(Stop, DVec3),
    /// It left the tile's own region; continue in the tile that owns `line.p`.
    Moved,
}

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
        let disc = bq * bq - dd * c;
        if disc < 0.0 {
            return None;
        }
        let t = (-bq - disc.sqrt()) / dd;
        (0.0..=1.0).contains(&t).then(|| a + t * d)
    }
}

// Dormand–Prince 5(4) tableau (the nodes c are implied by the rows of A).
const A: [[f64; 6]; 7] = [
    [0.0; 6],
    [0.2, 0.0, 0.0, 0.0, 0.0, 0.0],
    [3.0 / 40.0, 9.0 / 40.0, 0.0, 0.0, 0.0, 0.0],
    [44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0, 0.0, 0.0, 0.0],
    [
        19372.0 / 6561.0,
        -25360.0 / 2187.0,
        64448.0 / 6561.0,
        -212.0 / 729.0,
        0.0,
        0.0,
    ],
    [
        9017.0 / 3168.0,
        -355.0 / 33.0,
        46732.0 / 5247.0,
        49.0 / 176.0,
        -5103.0 / 18656.0,
        0.0,
    ],
    [
        35.0 / 384.0,
        0.0,
        500.0 / 1113.0,
        125.0 / 192.0,
        -2187.0 / 6784.0,
        11.0 / 84.0,
    ],
];
/// 5th-order weights minus 4th-order weights (the error estimate).
const E: [f64; 7] = [
    35.0 / 384.0 - 5179.0 / 57600.0,
    0.0,
    500.0 / 1113.0 - 7571.0 / 16695.0,
    125.0 / 192.0 - 393.0 / 640.0,
    -2187.0 / 6784.0 + 92097.0 / 339_200.0,
    11.0 / 84.0 - 187.0 / 2100.0,
    -1.0 / 40.0,
];

/// Does `tile` own `p`: is the cell of `p` in the tile's core `[lo, hi)` (grid indices
/// `[z, y, x]`)?
#[inline]
fn owns(lo: [i64; 3], hi: [i64; 3], p: DVec3) -> bool {
    let c = [p.z.floor() as i64, p.y.floor() as i64, p.x.floor() as i64];
    (0..3).all(|a| c[a] >= lo[a] && c[a] < hi[a])
}

/// Advance `line` inside `tile` while it stays in the core `[lo, hi)` (grid indices of
/// cells owned by this tile). `tile` must hold every cell within [`Rk45::reach`] of the
/// core. `path`, when given, receives every accepted point.
pub fn advance(
    line: &mut Line,
    tile: &Tile,
    lo: [i64; 3],
    hi: [i64; 3],
    rk: &Rk45,
    ball: &StopBall,
    mut path: Option<&mut Vec<DVec3>>,
) -> Advance {
    if let Some(e) = ball.entry(line.p, line.p) {
        return Advance::Done(Stop::Reached, e);
    }
    let reach = rk.reach();
    let field = |q: DVec3| -> Result<DVec3, NoDirection> { tile.direction(q) };
    // Where the solid is one or two voxels thick, every voxel is boundary: phi is exactly
    // 1 there and has no gradient, and streamlines stall on the sheet's midplane. Such a
    // streamline moves straight to the nearest node within ESCAPE_RADIUS where phi is
    // lower than anywhere around it, and goes on from there.
    macro_rules! escape_or_stop {
        ($e:expr) => {{
            let e: NoDirection = $e;
            let target = (e == NoDirection::Flat && line.escapes < MAX_ESCAPES)
                .then(|| tile.escape(line.p, ESCAPE_RADIUS))
                .flatten();
            let Some(q) = target else {
                return Advance::Done(Stop::from(e), line.p);
            };
            let from = line.p;
            line.escapes += 1;
            line.steps += 1;
            line.length += (q - from).length();
            line.p = q;
            line.h = 0.5_f64.clamp(rk.h_min, rk.h_max);
            if let Some(en) = ball.entry(from, q) {
                if let Some(path) = path.as_deref_mut() {
                    path.push(en);
                }
                return Advance::Done(Stop::Reached, en);
            }
            if let Some(path) = path.as_deref_mut() {
                path.push(q);
            }
            if !owns(lo, hi, q) {
                return Advance::Moved;
            }
            match field(line.p) {
                Ok(k) => k,
                Err(e) => return Advance::Done(Stop::from(e), line.p),
            }
        }};
    }
    let mut k1 = match field(line.p) {
        Ok(k) => k,
        Err(e) => escape_or_stop!(e),
    };
    let mut tiny = 0u32;
    loop {
        if line.steps >= rk.max_steps {
            return Advance::Done(Stop::StepLimit, line.p);
        }
        let h = line.h;
        let mut k = [DVec3::ZERO; 7];
        k[0] = k1;
        let mut failed = None;
        for s in 1..7 {
            let mut q = line.p;
            for (j, kj) in k.iter().enumerate().take(s) {
                q += (h * A[s][j]) * *kj;
            }
            let d = q - line.p;
            if d.abs().max_element() > reach {
                failed = Some(NoDirection::Outside);
                break;
            }
            match field(q) {
                Ok(v) => k[s] = v,
                Err(e) => {
                    failed = Some(e);
                    break;
                }
            }
        }
        if let Some(e) = failed {
            // A stage left the field (or met a flat spot): try a shorter step.
            line.h = 0.5 * h;
            if line.h < rk.h_min {
                k1 = escape_or_stop!(e);
            }
            continue;
        }
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
            continue;
        }
        let from = line.p;
        line.steps += 1;
        line.length += (q - from).length();
        line.p = q;
        line.h = (h * factor).clamp(rk.h_min, rk.h_max);
        k1 = k[6];
        // Zigzagging across a one-voxel sheet with tiny steps is stalling too.
        tiny = if h < 1e-3 { tiny + 1 } else { 0 };
        if tiny >= STUCK_STEPS {
            tiny = 0;
            k1 = escape_or_stop!(NoDirection::Flat);
            continue;
        }
        if let Some(e) = ball.entry(from, q) {
            if let Some(path) = path.as_deref_mut() {
                path.push(e);
            }
            return Advance::Done(Stop::Reached, e);
        }
        if let Some(path) = path.as_deref_mut() {
            path.push(q);
        }
        if !owns(lo, hi, q) {
            return Advance::Moved;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Block;
    use crate::trace::field::U_MARGIN;

    /// phi = |x - c| - 1000 (a cone, u = 1 - phi, positive: all solid): streamlines are
    /// straight rays to c.
    fn cone(n: usize, c: DVec3) -> Tile {
        let m = U_MARGIN;
        let mut phi = Block::filled([-(m as i64); 3], [n + 2 * m; 3], 0.0f64);
        for z in 0..n + 2 * m {
            for y in 0..n + 2 * m {
                for x in 0..n + 2 * m {
                    let p = DVec3::new(x as f64, y as f64, z as f64) - m as f64;
                    let o = phi.offset(z, y, x);
                    phi.data[o] = 1000.0 - (p - c).length();
                }
            }
        }
        Tile::from_u(&phi, [0, 0, 0], [n; 3])
    }

    #[test]
    fn rays_of_a_cone_reach_the_center_along_straight_lines() {
        let n = 40;
        let c = DVec3::new(20.0, 20.0, 20.0);
        let tile = cone(n, c);
        let ball = StopBall {
            center: c,
            radius: 3.0,
        };
        let rk = Rk45::default();
        for start in [
            DVec3::new(35.2, 21.0, 19.5),
            DVec3::new(5.5, 33.1, 8.25),
            DVec3::new(20.1, 4.0, 36.0),
        ] {
            let mut line = Line {
                id: 0,
                p: start,
                h: 0.5,
                steps: 0,
                length: 0.0,
                escapes: 0,
            };
            let mut path = Vec::new();
            let r = advance(
                &mut line,
                &tile,
                [0; 3],
                [n as i64; 3],
                &rk,
                &ball,
                Some(&mut path),
            );
            let Advance::Done(Stop::Reached, end) = r else {
                panic!("{r:?}")
            };
            assert!(((end - c).length() - 3.0).abs() < 1e-9);
            let angle = (end - c).normalize().angle_between((start - c).normalize());
            // Node gradients of a cone are not exactly radial; well inside they are close.
            assert!(angle.to_degrees() < 0.5, "{} degrees", angle.to_degrees());
            let dist = (start - c).length() - 3.0;
            assert!((line.length - dist).abs() < 0.05 * dist);
            assert!(line.steps < 60, "{} steps", line.steps);
        }
    }

    #[test]
    fn leaving_the_field_and_the_step_limit_are_reported() {
        let n = 20;
        let c = DVec3::new(-30.0, 10.0, 10.0); // sink outside the tile: lines run out -x
        let tile = cone(n, c);
        let ball = StopBall {
            center: c,
            radius: 1.0,
        };
        let mut line = Line {
            id: 0,
            p: DVec3::new(10.0, 10.0, 10.0),
            h: 0.5,
            steps: 0,
            length: 0.0,
            escapes: 0,
        };
        // Core = the whole tile: the line must stop when its stages leave the nodes.
        let r = advance(
            &mut line,
            &tile,
            [0; 3],
            [n as i64; 3],
            &Rk45::default(),
            &ball,
            None,
        );
        assert!(matches!(r, Advance::Done(Stop::LeftDomain, _)), "{r:?}");
        assert!(line.p.x < 1.0 && line.p.x >= 0.0, "{}", line.p);

        let mut line = Line {
            id: 0,
            p: DVec3::new(15.0, 10.0, 10.0),
            h: 0.5,
            steps: 0,
            length: 0.0,
            escapes: 0,
        };
        let rk = Rk45 {
            max_steps: 3,
            ..Rk45::default()
        };
        let r = advance(&mut line, &tile, [0; 3], [n as i64; 3], &rk, &ball, None);
        assert!(matches!(r, Advance::Done(Stop::StepLimit, _)), "{r:?}");
        assert_eq!(line.steps, 3);
    }

    #[test]
    fn a_segment_through_the_ball_enters_it_at_the_first_crossing() {
        let ball = StopBall {
            center: DVec3::ZERO,
            radius: 1.0,
        };
        let e = ball
            .entry(DVec3::new(-3.0, 0.0, 0.0), DVec3::new(3.0, 0.0, 0.0))
            .unwrap();
        assert!((e - DVec3::new(-1.0, 0.0, 0.0)).length() < 1e-12);
        assert!(ball
            .entry(DVec3::new(-3.0, 2.0, 0.0), DVec3::new(3.0, 2.0, 0.0))
            .is_none());
        assert!(ball
            .entry(DVec3::new(-3.0, 0.0, 0.0), DVec3::new(-2.0, 0.0, 0.0))
            .is_none());
    }
}
