//! The tracer's inner loops on a synthetic tile: the solid ball of radius 60 voxels with
//! the harmonic u = 1 - phi of a point sink (u falls like 1/r outward), exterior layers
//! and NaN beyond, in one tile of 74^3 nodes (a 64^3 core and the default halo), as
//! `harmap trace` builds them.
//!
//! - `tile build`: [`Tile::from_u`], the node directions with the boundary's sub-voxel
//!   values (the fixed cost of every tile);
//! - `field chain`: 1,000 evaluations of the field, each at a point that depends on the
//!   one before, as RK45's stages do (the latency of an evaluation);
//! - `lines`: 256 streamlines from the sphere of radius 55 to the stop ball, one at a
//!   time ([`advance`]) and two at a time ([`advance_all`]), which take the same steps.
//!
//! `harmap bench trace` gives the whole command's figures on the 256^3 ball.

// criterion_group! and criterion_main! generate undocumented functions.
#![allow(missing_docs)]

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use glam::DVec3;
use harmap::grid::Block;
use harmap::trace::field::{Tile, U_MARGIN};
use harmap::trace::integrate::{advance, advance_all, Advance, Line, Rk45, Stop, StopBall};

const N: usize = 74;
const R: f64 = 60.0;

fn center() -> DVec3 {
    DVec3::splat(N as f64 / 2.0)
}

/// u over the tile's box with its margin: 1 - phi of a point sink inside the ball, 0 on
/// the boundary voxels, the exterior layers below 0, NaN beyond them.
#[allow(clippy::many_single_char_names)] // the grid's axes z, y, x and the sink's coordinates
fn u_block() -> Block<f64> {
    let m = U_MARGIN as i64;
    let n = N + 2 * U_MARGIN;
    let mut u = Block::filled([-m; 3], [n; 3], f64::NAN);
    let c = center();
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                let p = DVec3::new(x as f64, y as f64, z as f64) - m as f64;
                let r = (p - c + DVec3::splat(20.0)).length();
                let o = u.offset(z, y, x);
                u.data[o] = if r < R - 1.0 {
                    (R / r.max(2.0) - 1.0) / (R / 2.0 - 1.0)
                } else if r < R {
                    0.0
                } else if r < R + 4.0 {
                    -1e-4 * (r - R + 1.0).floor()
                } else {
                    f64::NAN
                };
            }
        }
    }
    u
}

#[allow(clippy::many_single_char_names)] // the grid's axes z, y, x and the sink's coordinates
fn bench(c: &mut Criterion) {
    let u = u_block();
    let mut g = c.benchmark_group("tracing");
    g.sample_size(20);
    g.throughput(Throughput::Elements((N * N * N) as u64));
    g.bench_function("tile build (nodes)", |b| {
        b.iter(|| Tile::from_u(&u, [0; 3], [N; 3], None));
    });
    let tile = Tile::from_u(&u, [0; 3], [N; 3], None);
    g.throughput(Throughput::Elements(1000));
    g.bench_function("field chain (evaluations)", |b| {
        b.iter(|| {
            let mut q = DVec3::new(40.0, 45.0, 50.0);
            for _ in 0..1000 {
                q += 1e-3 * tile.direction(q).unwrap_or(DVec3::X);
            }
            q
        });
    });
    let rk = Rk45::default();
    let ball = StopBall {
        center: center() - DVec3::splat(20.0),
        radius: 8.0,
    };
    // Seeds on the part of the sphere of radius 55 inside the tile (a Fibonacci lattice).
    let lines: Vec<Line> = (0..4096u32)
        .filter_map(|i| {
            let t = (1.0 - 2.0 * (f64::from(i) + 0.5) / 4096.0).acos();
            let p = f64::from(i) * std::f64::consts::PI * (3.0 - 5f64.sqrt());
            let d = DVec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos());
            let q = ball.center + 55.0 * d;
            (q.min_element() > 8.0 && q.max_element() < (N - 8) as f64).then_some(q)
        })
        .take(256)
        .enumerate()
        .map(|(i, q)| Line::new(i as u32, q, &rk))
        .collect();
    let (lo, hi) = ([0i64; 3], [N as i64; 3]);
    let two_at_a_time = |done: &mut dyn FnMut(Line, Advance, Vec<DVec3>)| {
        advance_all(
            lines.iter().copied(),
            &tile,
            lo,
            hi,
            &rk,
            &ball,
            false,
            done,
        );
    };
    // The set-up must be what it says: 256 lines, all of which reach the stop ball.
    let mut reached = 0;
    two_at_a_time(&mut |_, a, _| {
        reached += usize::from(matches!(a, Advance::Done(Stop::Reached, _)));
    });
    assert_eq!((lines.len(), reached), (256, 256), "lines, reached");
    g.throughput(Throughput::Elements(lines.len() as u64));
    g.bench_function("lines one at a time", |b| {
        b.iter(|| {
            let mut steps = 0;
            for &l in &lines {
                let mut l = l;
                advance(&mut l, &tile, lo, hi, &rk, &ball, None);
                steps += l.steps;
            }
            steps
        });
    });
    g.bench_function("lines two at a time", |b| {
        b.iter(|| {
            let mut steps = 0;
            two_at_a_time(&mut |l, _, _| steps += l.steps);
            steps
        });
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
