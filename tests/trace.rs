//! The trace stage: arrival directions on the ball, stop reasons, determinism over
//! threads, tiles and budgets, surface seeds and their bijectivity numbers, errors.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use glam::DVec3;
use harmap::grid::MemBudget;
use harmap::pipeline::standard_ball_run;
use harmap::progress::Silent;
use harmap::run::RunDir;
use harmap::solve::{solve, SolveOptions};
use harmap::trace::{read_seeds, trace, SeedTable, TraceOptions, TraceReport};
use harmap::voxelize::StandardBall;

/// The standard ball at N, solved to rtol 1e-8.
fn solved_ball(dir: &Path, n: u64, chunk: u64) -> PathBuf {
    let out = dir.join(format!("ball{n}-{chunk}.harmap"));
    let p = StandardBall {
        n,
        sink_radius: 2.0,
        chunk,
        mem: MemBudget::default(),
    };
    standard_ball_run(&p, &out, true, &Silent).unwrap();
    let run = RunDir::open(&out).unwrap();
    let opts = SolveOptions {
        rtol: 1e-8,
        checkpoint_every: 0.0,
        ..SolveOptions::default()
    };
    solve(&run, &opts, &AtomicBool::new(false), &Silent).unwrap();
    out
}

fn run_trace(run: &Path, opts: &TraceOptions) -> (TraceReport, SeedTable) {
    let r = RunDir::open(run).unwrap();
    let rep = trace(&r, opts, &Silent).unwrap();
    (rep, read_seeds(&r).unwrap())
}

fn center(run: &Path) -> DVec3 {
    let a = RunDir::open(run).unwrap().attrs().unwrap();
    let c: [f64; 3] = serde_json::from_value(a["center"].clone()).unwrap();
    DVec3::from_array(c)
}

/// Angles (degrees) between each seed's own direction from the center and its arrival
/// direction, sorted.
fn radial_errors(run: &Path, t: &SeedTable) -> Vec<f64> {
    let c = center(run);
    let mut v: Vec<f64> = (0..t.position.len())
        .map(|i| {
            let s = t.sphere(i).expect("reached");
            s.angle_between(t.position[i] - c).to_degrees()
        })
        .collect();
    v.sort_by(f64::total_cmp);
    v
}

/// On the ball every streamline is (nearly) a radius: the arrival direction is the
/// seed's own. What remains is the staircase of the voxelized sphere bending streamlines
/// in their first voxels (docs/trace.md), which shrinks as the grid is refined.
#[test]
fn ball_seeds_arrive_along_their_own_direction() {
    let dir = tempfile::tempdir().unwrap();
    let mut stats = Vec::new();
    for n in [48u64, 96] {
        let run = solved_ball(dir.path(), n, 32);
        let (rep, t) = run_trace(&run, &TraceOptions::default());
        assert_eq!(rep.stops["reached"], rep.seeds, "{:?}", rep.stops);
        assert_eq!(rep.seeds, rep.seeds_available);
        assert!(
            t.phi.iter().all(|&p| (p - 1.0).abs() < 1e-6),
            "boundary seeds have phi 1"
        );
        let e = radial_errors(&run, &t);
        let (med, max) = (e[e.len() / 2], e[e.len() - 1]);
        eprintln!(
            "N={n}: {} seeds, median {med:.3} max {max:.3} degrees",
            rep.seeds
        );
        stats.push((med, max));
    }
    // Both fall with refinement; at N = 96, a fifth of a degree typically, 1 at most.
    assert!(
        stats[1].0 < stats[0].0 && stats[1].1 < stats[0].1,
        "{stats:?}"
    );
    assert!(stats[1].0 < 0.2 && stats[1].1 < 1.0, "{stats:?}");
}

/// Every column of two tables, bit for bit.
fn same_table(a: &SeedTable, b: &SeedTable) -> bool {
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    let pts = |v: &[DVec3]| {
        v.iter()
            .flat_map(|p| p.to_array().map(f64::to_bits))
            .collect::<Vec<_>>()
    };
    pts(&a.position) == pts(&b.position)
        && bits(&a.theta) == bits(&b.theta)
        && bits(&a.psi) == bits(&b.psi)
        && bits(&a.phi) == bits(&b.phi)
        && a.stop == b.stop
        && a.steps == b.steps
        && bits(&a.length) == bits(&b.length)
        && pts(&a.end) == pts(&b.end)
}

#[test]
fn tables_are_the_same_for_any_threads_tiles_and_budget() {
    let dir = tempfile::tempdir().unwrap();
    let run = solved_ball(dir.path(), 64, 32);
    let mut tables = Vec::new();
    for (threads, tile, mem) in [
        (2, None, MemBudget::default()),
        (1, None, MemBudget::default()),
        (2, Some(16), MemBudget::default()),
        (2, Some(24), MemBudget::default()),
        // Room for three tiles of 16 and eight chunks: tiles are evicted and built again.
        (2, Some(16), MemBudget(28 << 20)),
    ] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let o = TraceOptions {
            tile,
            mem,
            sample: Some(3000),
            ..TraceOptions::default()
        };
        let (rep, t) = pool.install(|| run_trace(&run, &o));
        tables.push((threads, tile, mem, rep, t));
    }
    let (_, _, _, r0, t0) = &tables[0];
    assert_eq!(r0.seeds, 3000);
    for (threads, tile, mem, rep, t) in &tables[1..] {
        assert!(
            same_table(t0, t),
            "{threads} threads, tile {tile:?}, --mem {mem}: table differs"
        );
        assert_eq!(rep.stops, r0.stops);
    }
    let small = &tables[4].3;
    assert!(
        small.tiles.tiles_built > small.cache[0] as u64,
        "the small budget should rebuild evicted tiles: {:?}",
        small.tiles
    );
    assert!(tables[2].3.tiles.handoffs > 0);
}

#[test]
fn every_seed_gets_a_stop_reason() {
    let dir = tempfile::tempdir().unwrap();
    let run = solved_ball(dir.path(), 40, 16);
    // A stop ball inside the sink, where phi is flat: streamlines stall there.
    let o = TraceOptions {
        stop_radius: Some(0.2),
        sample: Some(500),
        ..TraceOptions::default()
    };
    let (rep, t) = run_trace(&run, &o);
    assert_eq!(rep.stops.values().sum::<u64>(), rep.seeds);
    assert!(rep.stops["stalled"] > 0, "{:?}", rep.stops);
    for i in 0..t.stop.len() {
        assert_eq!(
            t.theta[i].is_nan(),
            t.stop[i] != 0,
            "theta is NaN exactly where unreached"
        );
    }
    // Too few steps allowed: the step limit.
    let mut o = TraceOptions {
        sample: Some(200),
        ..TraceOptions::default()
    };
    o.rk.max_steps = 2;
    let (rep, _) = run_trace(&run, &o);
    assert_eq!(rep.stops["step_limit"], 200, "{:?}", rep.stops);
}
