//! The out-of-core relaxation on the standard problem: blocked sweeps equal the
//! unblocked one bit for bit, for any thread count and backend, and converge.

use harmap::grid::{fill_with, BlockStore, GridSpec, MemBudget, MemStore, MmapStore};
use harmap::pipeline::standard_ball_run;
use harmap::progress::Silent;
use harmap::solve::relax::{initialize, relax_sor, RelaxOptions, StopReason};
use harmap::voxelize::StandardBall;

use crate::common::read_labels;

/// The standard problem's labels at N, as a store with blocks of `chunk`.
fn labels(n: u64, chunk: u64) -> (GridSpec, MemStore<u8>) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ball.harmap");
    let p = StandardBall {
        n,
        sink_radius: 2.0,
        chunk: 16,
        mem: MemBudget::default(),
    };
    standard_ball_run(&p, &out, false, &Silent).unwrap();
    let (mut spec, lab) = read_labels(&out);
    spec.chunk = [chunk; 3];
    let store = MemStore::new(spec.clone(), 0u8);
    fill_with(&store, 1, |[z, y, x]| lab[((z * n + y) * n + x) as usize]).unwrap();
    (spec, store)
}

fn whole(store: &dyn BlockStore<f64>) -> Vec<u64> {
    let s = store.spec().shape.map(|c| c as usize);
    store
        .read_region([0, 0, 0], s, 0.0)
        .unwrap()
        .data
        .iter()
        .map(|v| v.to_bits())
        .collect()
}

fn relax(
    lab: &dyn BlockStore<u8>,
    a: &dyn BlockStore<f64>,
    b: &dyn BlockStore<f64>,
    iters: u64,
    threads: usize,
) -> Vec<u64> {
    let opts = RelaxOptions {
        rtol: 0.0,
        max_iter: iters,
        ..RelaxOptions::default()
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        initialize(lab, a, opts.eps, usize::MAX).unwrap();
        relax_sor(lab, a, b, &opts, &Silent).unwrap();
    });
    whole(a)
}

#[test]
fn blocked_sweeps_equal_the_unblocked_sweep_bit_for_bit() {
    let n = 28;
    let (spec1, one_block) = labels(n, 32);
    let (spec8, blocks) = labels(n, 8);
    let reference = relax(
        &one_block,
        &MemStore::new(spec1.clone(), 0.0),
        &MemStore::new(spec1, 0.0),
        25,
        1,
    );
    let blocked = relax(
        &blocks,
        &MemStore::new(spec8.clone(), 0.0),
        &MemStore::new(spec8.clone(), 0.0),
        25,
        2,
    );
    assert_eq!(reference, blocked);
    let dir = tempfile::tempdir().unwrap();
    let a = MmapStore::<f64>::create(&dir.path().join("g0"), spec8.clone()).unwrap();
    let b = MmapStore::<f64>::create(&dir.path().join("g1"), spec8).unwrap();
    assert_eq!(
        reference,
        relax(&blocks, &a, &b, 25, 1),
        "memory-mapped generations, 1 thread"
    );
}

#[test]
fn relaxation_converges_on_the_standard_problem() {
    let (spec, lab) = labels(24, 8);
    let (a, b) = (
        MemStore::new(spec.clone(), 0.0),
        MemStore::new(spec.clone(), 0.0),
    );
    let opts = RelaxOptions {
        rtol: 1e-8,
        ..RelaxOptions::default()
    };
    initialize(&lab, &a, opts.eps, usize::MAX).unwrap();
    let r = relax_sor(&lab, &a, &b, &opts, &Silent).unwrap();
    assert_eq!(r.stopped_by, StopReason::Residual);
    assert!(r.iterations < 200, "{} iterations", r.iterations);
    assert!(*r.residual_history.last().unwrap() < 1e-8);
    let phi = a.read_region([0, 0, 0], [24; 3], 0.0).unwrap().data;
    let l = lab.read_region([0, 0, 0], [24; 3], 0).unwrap().data;
    for (p, &l) in phi.iter().zip(&l) {
        match l {
            0 => assert!(p.is_nan()),
            // Fixed values are never touched: bit for bit.
            1 => assert_eq!(p.to_bits(), 1f64.to_bits()),
            3 => assert_eq!(p.to_bits(), 0f64.to_bits()),
            2 => assert!((0.0..=1.0).contains(p), "interior phi {p}"),
            k => assert!((*p - (1.0 + f64::from(k - 3) * opts.eps)).abs() < 1e-15),
        }
    }
    // The paper's criterion alone, with a loose zeta, stops far earlier and farther from
    // the answer: the reason the residual criterion exists.
    let loose = RelaxOptions {
        rtol: 0.0,
        tol: 1e-3,
        ..RelaxOptions::default()
    };
    initialize(&lab, &a, loose.eps, usize::MAX).unwrap();
    let r2 = relax_sor(&lab, &a, &b, &loose, &Silent).unwrap();
    assert_eq!(r2.stopped_by, StopReason::MaxChange);
    assert!(r2.iterations < r.iterations && *r2.residual_history.last().unwrap() > 1e-8);
}
