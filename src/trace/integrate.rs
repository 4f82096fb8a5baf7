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
    /// Stepping on levels of ln u (u = 1 - phi), 0 for off: after [`LEVEL_AFTER`]
    /// voxels on its own steps, a streamline takes fixed steps of this much ln u (4th
    /// order Runge-Kutta), each ending on the level `ln u = k * level_step`, so that
    /// neighbouring streamlines stay level with each other (see [`advance`]).
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
    /// Next step length to try (voxels); on levels, the ln u still to go to the next
    /// level.
    pub h: f64,
    /// Accepted steps.
    pub steps: u32,
    /// Arc length so far (voxels).
    pub length: f64,
    /// Escapes from flat sheets so far (see [`advance`]).
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

/// What both ways of stepping work with: the tile, its core `[lo, hi)`, the integrator
/// and the stop ball (see [`advance`]).
#[derive(Clone, Copy)]
struct Core<'a> {
    tile: &'a Tile,
    lo: [i64; 3],
    hi: [i64; 3],
    rk: &'a Rk45,
    ball: &'a StopBall,
}

/// How one way of stepping left a streamline.
enum Leg {
    /// As [`advance`] returns it.
    Ended(Advance),
    /// It goes on with the other way of stepping (`line.level` says which).
    Switch,
}

/// Advance `line` inside `tile` while it stays in the core `[lo, hi)` (grid indices of
/// cells owned by this tile). `tile` must hold every cell within [`Rk45::reach`] of the
/// core. `path`, when given, receives every accepted point.
///
/// A streamline takes its own RK45 steps, with error control. With a
/// [`Rk45::level_step`], after [`LEVEL_AFTER`] voxels it steps on levels of ln u
/// instead ([`on_levels`]), and back on its own steps wherever it cannot.
pub fn advance(
    line: &mut Line,
    tile: &Tile,
    lo: [i64; 3],
    hi: [i64; 3],
    rk: &Rk45,
    ball: &StopBall,
    path: Option<&mut Vec<DVec3>>,
) -> Advance {
    let core = Core {
        tile,
        lo,
        hi,
        rk,
        ball,
    };
    let mut end = None;
    let record = path.is_some();
    drive::<1>(&core, std::iter::once(*line), record, |l, a, points| {
        *line = l;
        end = Some((a, points));
    });
    let (a, points) = end.expect("the line ends or moves");
    if let Some(p) = path {
        p.extend(points);
    }
    a
}

/// [`advance`] for each of `lines`, two at a time: the stages of their RK45 steps are
/// evaluated in turn, so that the processor overlaps the two chains of dependent
/// operations that evaluating the field is (each stage needs the one before it).
/// benches/tracing.rs: 1.7 times the lines per second of one line after the other;
/// three or four at a time were no faster. Every line takes exactly the steps
/// [`advance`] takes; `done` receives each line as it ends or leaves the core, with
/// how, and its accepted points when `record`.
#[allow(clippy::too_many_arguments)]
pub fn advance_all(
    lines: impl IntoIterator<Item = Line>,
    tile: &Tile,
    lo: [i64; 3],
    hi: [i64; 3],
    rk: &Rk45,
    ball: &StopBall,
    record: bool,
    done: impl FnMut(Line, Advance, Vec<DVec3>),
) {
    let core = Core {
        tile,
        lo,
        hi,
        rk,
        ball,
    };
    drive::<2>(&core, lines, record, done);
}

/// A streamline on its own RK45 steps, between two attempts.
#[derive(Clone, Copy)]
struct Own {
    /// The field at its point: the first stage of its next step.
    k1: DVec3,
    /// Consecutive accepted steps shorter than 1e-3 voxel.
    tiny: u32,
}

/// A line in flight in [`drive`].
struct Lane {
    line: Line,
    own: Own,
    path: Vec<DVec3>,
}

/// Run `lines` through `core`, up to `N` at a time with their RK45 attempts interleaved
/// ([`advance_all`]).
fn drive<const N: usize>(
    core: &Core<'_>,
    lines: impl IntoIterator<Item = Line>,
    record: bool,
    mut done: impl FnMut(Line, Advance, Vec<DVec3>),
) {
    let rk = core.rk;
    let mut input = lines.into_iter();
    let mut lanes: Vec<Lane> = Vec::with_capacity(N);
    loop {
        while lanes.len() < N {
            let Some(mut line) = input.next() else { break };
            let mut path = Vec::new();
            match start(&mut line, core, record.then_some(&mut path)) {
                Ok(own) => lanes.push(Lane { line, own, path }),
                Err(a) => done(line, a, path),
            }
        }
        if lanes.is_empty() {
            return;
        }
        // Lines at their step limit end here.
        let mut i = 0;
        while i < lanes.len() {
            if lanes[i].line.steps >= rk.max_steps {
                let l = lanes.swap_remove(i);
                done(l.line, Advance::Done(Stop::StepLimit, l.line.p), l.path);
            } else {
                i += 1;
            }
        }
        // One attempt for each line, stage by stage across the lines.
        let mut k = [[DVec3::ZERO; 7]; N];
        let mut failed: [Option<NoDirection>; N] = [None; N];
        let n = lanes.len();
        for (j, lane) in lanes.iter().enumerate() {
            k[j][0] = lane.own.k1;
        }
        for s in 1..7 {
            for j in 0..n {
                if failed[j].is_none() {
                    let (p, h) = (lanes[j].line.p, lanes[j].line.h);
                    match stage(core, p, h, &k[j], s) {
                        Ok(v) => k[j][s] = v,
                        Err(e) => failed[j] = Some(e),
                    }
                }
            }
        }
        let mut j = n;
        while j > 0 {
            j -= 1;
            let lane = &mut lanes[j];
            let attempt = match failed[j] {
                Some(e) => Err(e),
                None => Ok(&k[j]),
            };
            let path = record.then_some(&mut lane.path);
            let ended = match after(&mut lane.line, &mut lane.own, core, attempt, path) {
                None => None,
                Some(Leg::Ended(a)) => Some(a),
                Some(Leg::Switch) => {
                    let path = record.then_some(&mut lane.path);
                    match resume(&mut lane.line, core, path) {
                        Ok(own) => {
                            lane.own = own;
                            None
                        }
                        Err(a) => Some(a),
                    }
                }
            };
            if let Some(a) = ended {
                let l = lanes.swap_remove(j);
                done(l.line, a, l.path);
            }
        }
    }
}

/// A line's first moves in a tile: ended already (in the stop ball), or on levels
/// until it ends or needs its own steps ([`resume`]).
fn start(line: &mut Line, core: &Core<'_>, path: Option<&mut Vec<DVec3>>) -> Result<Own, Advance> {
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
fn resume(
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
/// than [`Rk45::reach`] from `p`, beyond what the tile must hold).
#[inline]
fn stage(
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
fn escape_or_stop(
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
fn after(
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

/// Count a step of `line` to `q` and take it.
fn move_to(line: &mut Line, q: DVec3) {
    line.steps += 1;
    line.length += (q - line.p).length();
    line.p = q;
}

/// After a step `from -> q`: where it enters the ball, if it does (the streamline ends
/// there). The entry, or else `q`, goes on the path.
fn arrive(from: DVec3, q: DVec3, ball: &StopBall, path: Option<&mut Vec<DVec3>>) -> Option<DVec3> {
    let entry = ball.entry(from, q);
    if let Some(path) = path {
        path.push(entry.unwrap_or(q));
    }
    entry
}

/// Whether `line` may go on levels where it is: not on them yet, levels on, and far
/// enough along.
fn may_start_levels(line: &Line, rk: &Rk45) -> bool {
    line.level.is_none() && rk.level_step > 0.0 && line.length >= line.level_from
}

/// Put `line` on levels, heading to the first level at or above ln u at its point, if
/// it can step on levels there.
fn start_levels(line: &mut Line, tile: &Tile, rk: &Rk45) -> bool {
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
fn leave_levels(line: &mut Line, rk: &Rk45) -> Leg {
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
fn on_levels(line: &mut Line, core: &Core<'_>, mut path: Option<&mut Vec<DVec3>>) -> Leg {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Block;
    use crate::trace::field::U_MARGIN;

    /// A tile of `n`^3 nodes whose u is `f` of the distance from c: streamlines are
    /// straight rays to c where f falls.
    fn radial(n: usize, c: DVec3, f: impl Fn(f64) -> f64) -> Tile {
        let m = U_MARGIN;
        let mut u = Block::filled([-(m as i64); 3], [n + 2 * m; 3], 0.0f64);
        for z in 0..n + 2 * m {
            for y in 0..n + 2 * m {
                for x in 0..n + 2 * m {
                    let p = DVec3::new(x as f64, y as f64, z as f64) - m as f64;
                    let o = u.offset(z, y, x);
                    u.data[o] = f((p - c).length());
                }
            }
        }
        Tile::from_u(&u, [0, 0, 0], [n; 3], None)
    }

    /// phi = |x - c| - 1000 (a cone, u = 1 - phi, positive: all solid).
    fn cone(n: usize, c: DVec3) -> Tile {
        radial(n, c, |r| 1000.0 - r)
    }

    /// Trace from `start` over the whole `n`^3 tile, which must bring the line into the
    /// ball: the line and its entry point. Accepted points go on `path`.
    fn reach(
        tile: &Tile,
        n: usize,
        ball: &StopBall,
        rk: &Rk45,
        start: DVec3,
        path: &mut Vec<DVec3>,
    ) -> (Line, DVec3) {
        let mut line = Line::new(0, start, rk);
        let r = advance(&mut line, tile, [0; 3], [n as i64; 3], rk, ball, Some(path));
        let Advance::Done(Stop::Reached, end) = r else {
            panic!("{r:?}")
        };
        (line, end)
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
            let (line, end) = reach(&tile, n, &ball, &rk, start, &mut Vec::new());
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
    fn steps_on_levels_end_on_their_level_and_follow_the_rays() {
        // u = exp(-r / 4): ln u = -r / 4, so levels 0.05 apart lie 0.2 voxel apart.
        let n = 40;
        let c = DVec3::new(20.0, 20.0, 20.0);
        let tile = radial(n, c, |r| (-r / 4.0).exp());
        let ball = StopBall {
            center: c,
            radius: 3.1,
        };
        let rk = Rk45 {
            level_step: 0.05,
            ..Rk45::default()
        };
        for start in [DVec3::new(35.2, 21.0, 19.5), DVec3::new(5.5, 33.1, 8.25)] {
            let mut path = vec![start];
            let (line, end) = reach(&tile, n, &ball, &rk, start, &mut path);
            let angle = (end - c).normalize().angle_between((start - c).normalize());
            assert!(angle.to_degrees() < 0.5, "{} degrees", angle.to_degrees());
            // Own steps for the first LEVEL_AFTER voxels, then on levels: every point
            // after the first level (but the entry into the ball) lies on a level.
            let mut walked = 0.0;
            let mut on_levels = 0;
            for w in path.windows(2) {
                walked += (w[1] - w[0]).length();
                let (l, _) = tile.level(w[1]).unwrap();
                let k = l / rk.level_step;
                if walked > LEVEL_AFTER + 2.0 && w[1] != end {
                    assert!((k - k.round()).abs() < 1e-9, "{} at {walked} voxels", w[1]);
                    on_levels += 1;
                }
            }
            let levels = ((start - c).length() - 3.1 - LEVEL_AFTER - 2.0) / 0.2;
            assert!(
                (f64::from(on_levels) - levels).abs() < 2.0,
                "{on_levels} points on levels, expected about {levels}"
            );
            assert!(line.level.is_some(), "it arrived on levels");
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
        let mut line = Line::new(0, DVec3::new(10.0, 10.0, 10.0), &Rk45::default());
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
        // On levels too: the line goes back to its own steps where a stage leaves the
        // nodes, and they tell that it left.
        let rk = Rk45 {
            level_step: 0.05,
            ..Rk45::default()
        };
        let mut line = Line::new(0, DVec3::new(10.0, 10.0, 10.0), &rk);
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
        assert!(matches!(r, Advance::Done(Stop::LeftDomain, _)), "{r:?}");
        assert!(line.p.x < 1.0 && line.p.x >= 0.0, "{}", line.p);
        assert!(
            line.level.is_none() && line.level_from > LEVEL_AFTER,
            "{line:?}"
        );

        let mut line = Line::new(0, DVec3::new(15.0, 10.0, 10.0), &Rk45::default());
        let rk = Rk45 {
            max_steps: 3,
            ..Rk45::default()
        };
        let r = advance(&mut line, &tile, [0; 3], [n as i64; 3], &rk, &ball, None);
        assert!(matches!(r, Advance::Done(Stop::StepLimit, _)), "{r:?}");
        assert_eq!(line.steps, 3);
    }

    /// Lines advanced two at a time ([`advance_all`]) take exactly the steps of each
    /// advanced alone: same end, same state, same points, for lines that reach the
    /// ball, leave the nodes, hit the step limit, leave the core or step on levels.
    #[test]
    fn two_at_a_time_is_one_at_a_time() {
        let n = 40;
        let c = DVec3::new(20.0, 20.0, 20.0);
        let ball = StopBall {
            center: c,
            radius: 3.0,
        };
        let cases = [
            (cone(n, c), Rk45::default()),
            (cone(n, DVec3::new(-30.0, 10.0, 10.0)), Rk45::default()),
            (
                cone(n, c),
                Rk45 {
                    max_steps: 7,
                    ..Rk45::default()
                },
            ),
            (
                radial(n, c, |r| (-r / 4.0).exp()),
                Rk45 {
                    level_step: 0.05,
                    ..Rk45::default()
                },
            ),
        ];
        // A core smaller than the tile: some lines leave it.
        let (lo, hi) = ([0i64; 3], [n as i64, n as i64, 30]);
        let mut ends = std::collections::BTreeSet::new();
        let mut on_levels = false;
        for (tile, rk) in &cases {
            let lines: Vec<Line> = (0..23)
                .map(|i| {
                    let t = f64::from(i);
                    let p = DVec3::new(
                        4.0 + (t * 7.3) % 31.0,
                        4.0 + (t * 3.1) % 31.0,
                        4.0 + (t * 5.7) % 31.0,
                    );
                    Line::new(i, p, rk)
                })
                .collect();
            let alone: Vec<(Line, Advance, Vec<DVec3>)> = lines
                .iter()
                .map(|&l| {
                    let mut l = l;
                    let mut path = Vec::new();
                    let a = advance(&mut l, tile, lo, hi, rk, &ball, Some(&mut path));
                    (l, a, path)
                })
                .collect();
            let mut paired: Vec<(Line, Advance, Vec<DVec3>)> = Vec::new();
            advance_all(lines, tile, lo, hi, rk, &ball, true, |l, a, p| {
                paired.push((l, a, p));
            });
            paired.sort_by_key(|r| r.0.id);
            assert_eq!(alone, paired, "{rk:?}");
            for (l, a, _) in &alone {
                ends.insert(match a {
                    Advance::Done(s, _) => s.name(),
                    Advance::Moved => "moved",
                });
                on_levels |= l.level.is_some();
            }
        }
        assert_eq!(
            ends.len(),
            4,
            "every way of ending should be tried: {ends:?}"
        );
        assert!(on_levels, "some line should be on levels");
    }

    /// The early exits of [`StopBall::entry`] give the quadratic formula's answer:
    /// segments of every direction and length around a ball, many ending near its
    /// sphere, against the formula alone.
    #[test]
    fn the_ball_entry_shortcut_is_the_formula() {
        fn formula(ball: &StopBall, a: DVec3, b: DVec3) -> Option<DVec3> {
            let r2 = ball.radius * ball.radius;
            let (d, f) = (b - a, a - ball.center);
            if f.length_squared() <= r2 {
                return Some(a);
            }
            let dd = d.length_squared();
            if dd == 0.0 {
                return None;
            }
            let (bq, c) = (f.dot(d), f.length_squared() - r2);
            let disc = bq * bq - dd * c;
            if disc < 0.0 {
                return None;
            }
            let t = (-bq - disc.sqrt()) / dd;
            (0.0..=1.0).contains(&t).then(|| a + t * d)
        }
        let ball = StopBall {
            center: DVec3::new(10.0, -3.0, 7.5),
            radius: 8.0,
        };
        let mut rng = crate::math::TestRng(0x2545_f491_4f6c_dd1d);
        let mut next = || rng.next_f64() * 2.0 - 1.0;
        let (mut entered, mut missed) = (0, 0);
        for i in 0..300_000 {
            let dir = DVec3::new(next(), next(), next()).normalize();
            let mut a = ball.center + (8.0 + 12.0 * next().abs()) * dir;
            let b = match i % 3 {
                // Aimed at the sphere, to end within about 2e-6 of it.
                0 => {
                    let end = ball.center + (8.0 + 1e-6 * next()) * dir;
                    a + (end - a) * (1.0 + 1e-7 * next())
                }
                // Short steps (1e-9 to 1e-5 voxel), mostly inward, that end 1e-15 to
                // 1e-9 voxel outside the sphere or inside it.
                1 => {
                    let len = 10f64.powf(-9.0 + 4.0 * next().abs());
                    let gap = 10f64.powf(-15.0 + 6.0 * next().abs()) * next().signum();
                    let b = ball.center + (8.0 + gap) * dir;
                    let wobble = DVec3::new(next(), next(), next());
                    a = b - len * (wobble - 1.5 * dir).normalize();
                    b
                }
                _ => a + DVec3::new(next(), next(), next()) * 3.0,
            };
            let want = formula(&ball, a, b);
            assert_eq!(ball.entry(a, b), want, "{a} -> {b}");
            if want.is_some() {
                entered += 1;
            } else {
                missed += 1;
            }
        }
        assert!(
            entered > 10_000 && missed > 10_000,
            "{entered} entered, {missed} missed"
        );
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
