//! Dormand–Prince RK45 along the unit direction field, with error control.
//!
//! The streamline is parameterized by arc length (the field is a unit vector), so the
//! step `h` is a length in voxels. Every decision (accept, reject, shrink, stop) depends
//! only on the field values at the points the method visits, never on which tile holds
//! them: a streamline is the same whatever the tiling or the thread that runs it.

//!
//! Files: `settings` ([`Rk45`]), `line` (a streamline in flight, [`Stop`], [`Advance`]),
//! `ball` ([`StopBall`]), `tableau` (the Dormand–Prince coefficients), `core` (what both
//! ways of stepping share), `state` (the line state machine of one RK45 attempt), `levels` (stepping on levels of ln u),
//! `driver` ([`advance`], [`advance_all`]: one or two lines at a time).

mod ball;
mod core;
mod driver;
mod levels;
mod line;
mod settings;
mod state;
mod tableau;

pub use ball::StopBall;
pub use driver::{advance, advance_all};
pub use levels::{
    finishes_level, level_advance, level_step, level_substep, onto_level, LevelEnd, LevelField,
};
use line::STUCK_STEPS;
pub use line::{Advance, Line, Stop, ESCAPE_RADIUS, MAX_ESCAPES};
pub use settings::{Rk45, LEVEL_AFTER, MAX_H_MAX, MAX_LEVEL_STEP, MIN_LEVEL_STEP};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Block;
    use crate::trace::field::Tile;
    use crate::trace::field::U_MARGIN;
    use glam::DVec3;

    /// A tile of `n`^3 nodes whose u is `f` of the distance from c: streamlines are
    /// straight rays to c where f falls.
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
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
        #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
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
