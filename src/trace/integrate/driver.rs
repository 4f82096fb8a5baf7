//! The driver: streamlines advanced through a tile one at a time ([`advance`]) or two
//! at a time with their RK45 stages interleaved ([`advance_all`]).

use glam::DVec3;

use super::core::{Core, Leg};
use super::state::{after, resume, stage, start, Own};
use super::{Advance, Line, Rk45, Stop, StopBall};
use crate::trace::field::{NoDirection, Tile};

/// Advance `line` inside `tile` while it stays in the core `[lo, hi)` (grid indices of
/// cells owned by this tile). `tile` must hold every cell within [`Rk45::reach`] of the
/// core. `path`, when given, receives every accepted point.
///
/// A streamline takes its own RK45 steps, with error control. With a
/// [`Rk45::level_step`], after [`LEVEL_AFTER`](super::LEVEL_AFTER) voxels it steps on levels of ln u
/// instead ([`on_levels`](super::levels::on_levels)), and back on its own steps wherever it cannot.
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

/// A line in flight in [`drive`].
struct Lane {
    line: Line,
    own: Own,
    path: Vec<DVec3>,
}

/// Run `lines` through `core`, up to `N` at a time with their RK45 attempts interleaved
/// ([`advance_all`]).
#[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
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
