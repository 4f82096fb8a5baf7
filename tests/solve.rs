//! The solve stage on the standard problem: accuracy against the analytic solution,
//! agreement of the three methods and of a direct solve, grid independence of
//! multigrid, determinism, checkpoints and resume.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use harmap::grid::{BlockStore, MemBudget};
use harmap::pipeline::standard_ball_run;
use harmap::progress::Silent;
use harmap::run::RunDir;
use harmap::solve::driver::{Method, StopReason};
use harmap::solve::{solve, Cycle, CycleOptions, SolveOptions, SolveReport};
use harmap::voxelize::labels::{BOUNDARY, CENTER, EXTERIOR, INTERIOR};
use harmap::voxelize::StandardBall;

use crate::common::read_labels;

/// A standard-problem run at N with the given sink radius and block edge.
fn ball(dir: &Path, n: u64, sink: f64, chunk: u64) -> PathBuf {
    let out = dir.join(format!("ball{n}-{sink}-{chunk}.harmap"));
    let p = StandardBall {
        n,
        sink_radius: sink,
        chunk,
        mem: MemBudget::default(),
    };
    standard_ball_run(&p, &out, true, &Silent).unwrap();
    out
}

fn run_solve(run: &Path, opts: &SolveOptions) -> SolveReport {
    let r = RunDir::open(run).unwrap();
    solve(&r, opts, &AtomicBool::new(false), &Silent).unwrap()
}

fn read_phi(run: &Path) -> Vec<f64> {
    let r = RunDir::open(run).unwrap();
    let s = r.open_image::<f64>("phi").unwrap();
    let shape = s.spec().shape.map(|c| c as usize);
    s.read_region([0, 0, 0], shape, f64::NAN).unwrap().data
}

fn opts(method: Method, rtol: f64) -> SolveOptions {
    SolveOptions {
        method,
        rtol,
        max_iter: 200_000,
        ..SolveOptions::default()
    }
}

fn max_diff(a: &[f64], b: &[f64], labels: &[u8]) -> f64 {
    a.iter()
        .zip(b)
        .zip(labels)
        .filter(|(_, &l)| l == INTERIOR)
        .map(|((x, y), _)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// The largest and the mean error of phi against the concentric spheres' analytic
/// solution, phi(r) = (1/r0 - 1/r) / (1/r0 - 1/R) between the sink (r0 = 0.1 N) and the
/// boundary (R = 0.45 N), over the unknowns.
fn spheres_error(run: &Path, n: u64) -> (f64, f64) {
    let phi = read_phi(run);
    let (_, labels) = read_labels(run);
    let c = (n as f64 - 1.0) / 2.0;
    let (r0, big_r) = (0.1 * n as f64, 0.45 * n as f64);
    let (mut max, mut sum, mut cnt) = (0.0f64, 0.0, 0.0);
    let nu = n as usize;
    for (i, &l) in labels.iter().enumerate() {
        if l != INTERIOR {
            continue;
        }
        let (z, y, x) = (i / (nu * nu), (i / nu) % nu, i % nu);
        let r = [z, y, x]
            .iter()
            .map(|&v| (v as f64 - c).powi(2))
            .sum::<f64>()
            .sqrt();
        let exact = (1.0 / r0 - 1.0 / r) / (1.0 / r0 - 1.0 / big_r);
        let e = (phi[i] - exact).abs();
        max = max.max(e);
        sum += e;
        cnt += 1.0;
    }
    (max, sum / cnt)
}

#[test]
fn concentric_spheres_error_falls_with_refinement() {
    // The staircased spheres make the pointwise error near them O(h) in the solution's
    // units; the error over the interior falls as N doubles.
    let dir = tempfile::tempdir().unwrap();
    let mut errs = Vec::new();
    for n in [32u64, 64, 96] {
        let run = ball(dir.path(), n, 0.1 * n as f64, 32);
        let rep = run_solve(&run, &opts(Method::Multigrid, 1e-10));
        assert_eq!(rep.stopped_by, StopReason::Residual);
        let (max, mean) = spheres_error(&run, n);
        errs.push((n, max, mean));
    }
    eprintln!("N, max error, mean error: {errs:?}");
    for w in errs.windows(2) {
        assert!(w[1].1 < w[0].1, "max error did not fall: {errs:?}");
        assert!(w[1].2 < 0.75 * w[0].2, "mean error did not fall: {errs:?}");
    }
    assert!(errs[2].1 < 0.1 && errs[2].2 < 0.01, "{errs:?}");
}

#[test]
fn full_multigrid_stops_within_the_discretization_error() {
    // Full multigrid with --rtol 0 (its discretization stop) against the converged
    // solve on the concentric spheres: the same error against the analytic solution, an
    // algebraic error (the difference of the two) well under it, in few fine-grid
    // sweeps.
    let dir = tempfile::tempdir().unwrap();
    for n in [32u64, 64, 96] {
        let run = ball(dir.path(), n, 0.1 * n as f64, 32);
        let fmg = run_solve(&run, &opts(Method::Multigrid, 0.0));
        assert_eq!(fmg.stopped_by, StopReason::Discretization, "N = {n}");
        let phi_fmg = read_phi(&run);
        let e_fmg = spheres_error(&run, n);
        let conv = run_solve(&run, &opts(Method::Multigrid, 1e-10));
        let e_conv = spheres_error(&run, n);
        let (_, labels) = read_labels(&run);
        let alg = max_diff(&phi_fmg, &read_phi(&run), &labels);
        eprintln!(
            "N = {n}: fmg {} iterations, {:.1} sweeps, residual {:.1e}, error (max, mean) {e_fmg:?}; converged ({} sweeps) {e_conv:?}; algebraic {alg:.2e}",
            fmg.iterations, fmg.sweep_equivalents, fmg.relative_residual, conv.sweep_equivalents
        );
        assert!(fmg.sweep_equivalents <= 20.0, "{}", fmg.sweep_equivalents);
        assert!(fmg.sweep_equivalents < 0.5 * conv.sweep_equivalents);
        assert!(alg < 0.1 * e_conv.0, "algebraic {alg} vs {e_conv:?}");
        assert!(e_fmg.0 <= 1.05 * e_conv.0 && e_fmg.1 <= 1.05 * e_conv.1);
    }
}

#[test]
fn multigrid_sor_and_jacobi_agree_when_converged() {
    let dir = tempfile::tempdir().unwrap();
    let (_, labels) = read_labels(&ball(dir.path(), 24, 2.0, 16));
    let mut answers = Vec::new();
    for m in [Method::Multigrid, Method::Sor, Method::Jacobi] {
        let run = ball(dir.path(), 24, 2.0, 16);
        let rep = run_solve(&run, &opts(m, 1e-11));
        assert_eq!(rep.stopped_by, StopReason::Residual, "{m:?}");
        assert!(rep.relative_residual < 1e-11);
        answers.push((m, rep.iterations, read_phi(&run)));
    }
    for (m, it, phi) in &answers[1..] {
        let d = max_diff(&answers[0].2, phi, &labels);
        assert!(
            d < 1e-7,
            "{m:?} ({it} iterations) differs from multigrid by {d}"
        );
    }
    // Multigrid needs far fewer iterations than SOR, which needs far fewer than Jacobi.
    assert!(answers[0].1 * 5 < answers[1].1 && answers[1].1 * 5 < answers[2].1);
}

/// Solve the 7-point system on the unknowns directly (dense Cholesky).
fn direct_solve(labels: &[u8], n: usize, eps: f64) -> Vec<f64> {
    let idx: Vec<Option<usize>> = {
        let mut k = 0;
        labels
            .iter()
            .map(|&l| {
                (l == INTERIOR).then(|| {
                    k += 1;
                    k - 1
                })
            })
            .collect()
    };
    let m = idx.iter().flatten().count();
    let mut a = vec![0.0f64; m * m];
    let mut b = vec![0.0f64; m];
    let fixed = |l: u8| match l {
        BOUNDARY => 1.0,
        CENTER => 0.0,
        EXTERIOR => panic!("an unknown touches the exterior"),
        k => 1.0 + f64::from(k - 3) * eps,
    };
    for (i, &l) in labels.iter().enumerate() {
        let Some(r) = idx[i] else { continue };
        assert_eq!(l, INTERIOR);
        a[r * m + r] = 6.0;
        for d in [1, n, n * n] {
            for j in [i - d, i + d] {
                match idx[j] {
                    Some(c) => a[r * m + c] -= 1.0,
                    None => b[r] += fixed(labels[j]),
                }
            }
        }
    }
    // Cholesky A = L L^T in place (lower triangle).
    for j in 0..m {
        let mut d = a[j * m + j];
        for k in 0..j {
            d -= a[j * m + k] * a[j * m + k];
        }
        let d = d.sqrt();
        a[j * m + j] = d;
        for i in j + 1..m {
            let mut s = a[i * m + j];
            for k in 0..j {
                s -= a[i * m + k] * a[j * m + k];
            }
            a[i * m + j] = s / d;
        }
    }
    for i in 0..m {
        let mut s = b[i];
        for k in 0..i {
            s -= a[i * m + k] * b[k];
        }
        b[i] = s / a[i * m + i];
    }
    for i in (0..m).rev() {
        let mut s = b[i];
        for k in i + 1..m {
            s -= a[k * m + i] * b[k];
        }
        b[i] = s / a[i * m + i];
    }
    idx.iter().map(|o| o.map_or(f64::NAN, |r| b[r])).collect()
}

#[test]
fn multigrid_matches_a_direct_sparse_solve() {
    // The same discrete system assembled independently and solved by elimination.
    let dir = tempfile::tempdir().unwrap();
    let run = ball(dir.path(), 16, 2.0, 8);
    // A large eps so that the exterior layers' values matter to the answer.
    let mut o = opts(Method::Multigrid, 1e-12);
    o.eps = 5e-3;
    run_solve(&run, &o);
    let (_, labels) = read_labels(&run);
    let direct = direct_solve(&labels, 16, 5e-3);
    let phi = read_phi(&run);
    let d = max_diff(&direct, &phi, &labels);
    assert!(d < 1e-9, "multigrid vs direct: {d}");
    // Outside the problem phi is NaN; fixed voxels hold their values.
    for (l, p) in labels.iter().zip(&phi) {
        match *l {
            EXTERIOR => assert!(p.is_nan()),
            BOUNDARY => assert_eq!(p.to_bits(), 1f64.to_bits()),
            CENTER => assert_eq!(p.to_bits(), 0f64.to_bits()),
            INTERIOR => assert!((0.0..=1.0).contains(p)),
            k => assert_eq!(p.to_bits(), (1.0 + f64::from(k - 3) * 5e-3).to_bits()),
        }
    }
}

#[test]
fn multigrid_cycles_do_not_grow_with_the_grid() {
    let dir = tempfile::tempdir().unwrap();
    let mut cycles = Vec::new();
    for n in [32u64, 64, 96] {
        let run = ball(dir.path(), n, 2.0, 32);
        cycles.push(run_solve(&run, &opts(Method::Multigrid, 1e-6)).iterations);
    }
    let (lo, hi) = (cycles.iter().min().unwrap(), cycles.iter().max().unwrap());
    assert!(
        hi - lo <= 2 && *hi <= 10,
        "cycles per N = 32, 64, 96: {cycles:?}"
    );
}

#[test]
fn max_change_criterion_stops_slow_iterations_far_from_the_answer() {
    // The paper's zeta: Jacobi stops on a small change while the residual is still
    // large, and its answer is far from the converged one.
    let dir = tempfile::tempdir().unwrap();
    let run = ball(dir.path(), 32, 2.0, 16);
    let (_, labels) = read_labels(&run);
    let mut o = opts(Method::Jacobi, 0.0);
    o.tol = 1e-4;
    let rep = run_solve(&run, &o);
    assert_eq!(rep.stopped_by, StopReason::MaxChange);
    let loose = read_phi(&run);
    run_solve(&run, &opts(Method::Multigrid, 1e-10));
    let d = max_diff(&loose, &read_phi(&run), &labels);
    assert!(rep.relative_residual > 1e-3, "{}", rep.relative_residual);
    assert!(d > 20.0 * o.tol, "error {d} with zeta {}", o.tol);
}

#[test]
fn phi_is_the_same_bytes_for_any_thread_count_and_budget() {
    let dir = tempfile::tempdir().unwrap();
    // Full multigrid to its own stop (--rtol 0) and to a residual, and V-cycles.
    let v = SolveOptions {
        cycle: CycleOptions {
            kind: Cycle::V,
            ..CycleOptions::default()
        },
        ..opts(Method::Multigrid, 1e-8)
    };
    for base in [
        opts(Method::Multigrid, 0.0),
        opts(Method::Multigrid, 1e-8),
        v,
    ] {
        let mut outs = Vec::new();
        for (threads, mem) in [(1, "1GiB"), (2, "1GiB"), (2, "30MiB")] {
            let run = ball(dir.path(), 80, 2.0, 16);
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let o = SolveOptions {
                mem: mem.parse().unwrap(),
                ..base.clone()
            };
            let rep = pool.install(|| run_solve(&run, &o));
            if mem == "30MiB" {
                assert!(!rep.in_memory[0], "the small budget should put phi on disk");
            }
            let bits: Vec<u64> = read_phi(&run).iter().map(|v| v.to_bits()).collect();
            outs.push((rep.iterations, rep.residual_history, bits));
        }
        assert_eq!(outs[0], outs[1], "1 vs 2 threads, {:?}", base.cycle.kind);
        assert_eq!(
            outs[1], outs[2],
            "in memory vs memory-mapped scratch, {:?}",
            base.cycle.kind
        );
    }
}

#[test]
fn full_multigrid_interrupted_and_resumed_gives_the_same_bytes() {
    // Asked to stop from the start: the coarse phase runs, the first decision
    // checkpoints its result and stops; the resume goes on with V-cycles.
    let dir = tempfile::tempdir().unwrap();
    let run = ball(dir.path(), 48, 2.0, 16);
    let whole = run_solve(&run, &SolveOptions::default());
    let expected = phi_bytes(&run);
    let r = RunDir::open(&run).unwrap();
    let stop = AtomicBool::new(true);
    let e = solve(&r, &SolveOptions::default(), &stop, &Silent).unwrap_err();
    assert!(e.to_string().contains("--resume"), "{e}");
    let resumed = solve(
        &r,
        &SolveOptions {
            resume: true,
            ..SolveOptions::default()
        },
        &AtomicBool::new(false),
        &Silent,
    )
    .unwrap();
    assert_eq!(resumed.resumed_at, Some(1));
    assert_eq!(phi_bytes(&run), expected, "resumed phi differs");
    assert_eq!(resumed.residual_history, whole.residual_history);
    assert_eq!(
        resumed.sweep_equivalents.to_bits(),
        whole.sweep_equivalents.to_bits()
    );
}

fn bin() -> std::process::Command {
    std::process::Command::new(env!("CARGO_BIN_EXE_harmap"))
}

fn phi_bytes(run: &Path) -> Vec<u64> {
    read_phi(run).iter().map(|v| v.to_bits()).collect()
}

/// A slow solve (Jacobi to a tight residual, checkpoints every 20 ms), so that kills land
/// in the middle of it.
fn slow_solve(run: &Path, resume: bool) -> std::process::Command {
    slow_solve_every(run, resume, "0.02s")
}

fn slow_solve_every(run: &Path, resume: bool, every: &str) -> std::process::Command {
    let mut c = bin();
    c.args(["-q", "solve"])
        .arg(run)
        .args([
            "--method",
            "jacobi",
            "--rtol",
            "1e-9",
            "--max-iter",
            "100000",
        ])
        .args(["--checkpoint-every", every]);
    if resume {
        c.arg("--resume");
    }
    c
}

fn wait_for(p: &Path) {
    let t = std::time::Instant::now();
    while !p.exists() {
        assert!(t.elapsed().as_secs() < 60, "{} never appeared", p.display());
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
}

#[test]
fn killed_three_times_and_resumed_gives_the_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let whole = ball(dir.path(), 40, 2.0, 16);
    let o = slow_solve(&whole, false).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let expected = phi_bytes(&whole);

    let run = ball(dir.path(), 40, 2.0, 16);
    let manifest = run.join("solve/manifest.json");
    // SIGKILL at three moments: right after the first checkpoint, a little later, and
    // later still (some of them land while a checkpoint is being written).
    for (k, extra_ms) in [0u64, 37, 151].into_iter().enumerate() {
        let mut child = slow_solve(&run, k > 0).spawn().unwrap();
        if k == 0 {
            wait_for(&manifest);
        }
        std::thread::sleep(std::time::Duration::from_millis(extra_ms + 30));
        let _ = child.kill(); // SIGKILL
        let st = child.wait().unwrap();
        assert!(!st.success() || run.join("phi").exists());
        assert!(
            !run.join("phi").exists(),
            "finished before kill {k}; make it slower"
        );
    }
    let o = slow_solve(&run, true).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(phi_bytes(&run), expected, "resumed phi differs");
    let attrs = RunDir::open(&run).unwrap().attrs().unwrap();
    assert!(
        attrs
            .pointer("/stages/solve/result/resumed_at")
            .unwrap()
            .as_u64()
            .unwrap()
            > 0
    );
    assert!(!run.join("solve").exists(), "solver state left behind");
}

#[test]
fn sigint_checkpoints_and_exits_130_and_bad_resumes_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let run = ball(dir.path(), 40, 2.0, 16);
    let child = slow_solve_every(&run, false, "0")
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(300));
    // SIGINT as Ctrl-C sends it.
    let ok = std::process::Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(ok.success());
    let o = child.wait_with_output().unwrap();
    assert_eq!(
        o.status.code(),
        Some(130),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--resume"), "{err}");
    assert!(run.join("solve/manifest.json").exists());
    assert!(!run.join("phi").exists());

    // Other options than the checkpoint's: refused with exit code 2.
    let o = bin()
        .args(["-q", "solve"])
        .arg(&run)
        .args(["--method", "sor", "--resume"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("other labels or other solve options"));

    // A damaged newest generation: the previous checkpoint is used, or (with none) a
    // clear refusal.
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(run.join("solve/manifest.json")).unwrap()).unwrap();
    let g = run.join(format!("solve/g{}.bin", m["generation"]));
    let mut bytes = std::fs::read(&g).unwrap();
    bytes[100] ^= 0xff;
    std::fs::write(&g, bytes).unwrap();
    let o = slow_solve(&run, true).output().unwrap();
    if run.join("solve/manifest.prev.json").exists() {
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        assert!(String::from_utf8_lossy(&o.stderr).contains("damaged"));
    } else {
        assert_eq!(o.status.code(), Some(2));
        assert!(String::from_utf8_lossy(&o.stderr).contains("checksum mismatch"));
    }
}

/// Interrupt a slow solve once two checkpoints exist, then damage the newest generation in
/// `damage`'s way: the resume must say so, use the previous checkpoint, and still give
/// the bytes of an uninterrupted run.
fn resume_after_damage(damage: impl Fn(&Path)) {
    let dir = tempfile::tempdir().unwrap();
    let whole = ball(dir.path(), 40, 2.0, 16);
    let o = slow_solve(&whole, false).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let expected = phi_bytes(&whole);

    let run = ball(dir.path(), 40, 2.0, 16);
    let mut child = slow_solve(&run, false).spawn().unwrap();
    wait_for(&run.join("solve/manifest.prev.json"));
    // SIGINT rather than SIGKILL, so that both checkpoints are whole before one is
    // damaged (a kill could land while the older generation is being overwritten).
    let ok = std::process::Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(ok.success());
    assert_eq!(child.wait().unwrap().code(), Some(130));
    assert!(!run.join("phi").exists(), "finished before the interrupt");
    // Which generation the newest manifest names, and which the previous one does.
    let gen = |name: &str| -> u64 {
        let m: serde_json::Value =
            serde_json::from_slice(&std::fs::read(run.join("solve").join(name)).unwrap()).unwrap();
        m["generation"].as_u64().unwrap()
    };
    let (newest, prev) = (gen("manifest.json"), gen("manifest.prev.json"));
    assert_ne!(newest, prev);
    damage(&run.join(format!("solve/g{newest}.bin")));

    let o = slow_solve(&run, true).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("damaged") && err.contains("previous"), "{err}");
    assert_eq!(phi_bytes(&run), expected, "resumed phi differs");
}

#[test]
fn a_corrupted_newest_checkpoint_falls_back_to_the_previous_one() {
    resume_after_damage(|g| {
        let mut bytes = std::fs::read(g).unwrap();
        let k = bytes.len() / 2;
        bytes[k] ^= 0x40;
        std::fs::write(g, bytes).unwrap();
    });
}

#[test]
fn a_torn_newest_checkpoint_falls_back_to_the_previous_one() {
    resume_after_damage(|g| {
        let f = std::fs::OpenOptions::new().write(true).open(g).unwrap();
        let n = f.metadata().unwrap().len();
        f.set_len(n / 3).unwrap();
    });
}

/// The built-in starfish at resolution `res`, voxelized (a mesh run: its arms are thin,
/// u falls below 1e-16 in them).
fn starfish(dir: &Path, name: &str, res: u64) -> PathBuf {
    use harmap::pipeline::{voxelize_new_run, Source};
    use harmap::voxelize::VoxelizeOptions;
    let out = dir.join(name);
    let vo = VoxelizeOptions {
        resolution: Some(res),
        center: Some([0.0, 0.0, 0.0]),
        ..VoxelizeOptions::default()
    };
    voxelize_new_run(&Source::Starfish, &vo, &out, true, &Silent).unwrap();
    out
}

/// u over the grid, and which voxels are unknowns of the solve (finite, not fixed).
fn read_u(run: &Path) -> Vec<f64> {
    let r = RunDir::open(run).unwrap();
    let s = r.open_image::<f64>("u").unwrap();
    let shape = s.spec().shape.map(|c| c as usize);
    s.read_region([0, 0, 0], shape, f64::NAN).unwrap().data
}

/// The largest relative difference of `a` from `b` over the unknowns where `b` is above
/// the polish's floor (1e-24), and how many of them are below 1e-11.
fn largest_relative_difference(a: &[f64], b: &[f64], labels: &[u8]) -> (f64, usize) {
    let mut worst = 0.0f64;
    let mut deep = 0;
    for ((&x, &y), &l) in a.iter().zip(b).zip(labels) {
        if l == INTERIOR && y > 1e-24 {
            worst = worst.max(((x - y) / y).abs());
            deep += usize::from(y < 1e-11);
        }
    }
    (worst, deep)
}

/// cactus10k (../shared/data; skipped without it, failing under `CI=true`) voxelized at
/// resolution 64: u falls below 1e-16 down its arms (74 values below 1e-11).
fn cactus(dir: &Path, name: &str) -> Option<PathBuf> {
    let mesh = crate::common::shared_data("meshes/cactus10k.obj")?;
    let out = dir.join(name);
    let vo = harmap::voxelize::VoxelizeOptions {
        resolution: Some(64),
        ..harmap::voxelize::VoxelizeOptions::default()
    };
    let io = harmap::input::InputOptions::default();
    let source = harmap::pipeline::Source::File(&mesh, &io);
    harmap::pipeline::voxelize_new_run(&source, &vo, &out, false, &Silent).unwrap();
    Some(out)
}

/// The multigrid stages on the regions where u is tiny give the values that the polish
/// gets by thousands of sweeps run to convergence: relative accuracy down to 1e-24.
/// Without the stages (the polish only below their reach) the deep values are wrong by
/// far more than themselves, so the comparison would see it.
#[test]
fn multigrid_on_the_tiny_regions_gives_u_to_relative_accuracy() {
    use harmap::solve::{DeepenOptions, PolishOptions};
    let dir = tempfile::tempdir().unwrap();
    let Some(run) = cactus(dir.path(), "cactus.harmap") else {
        return;
    };
    let solve_with = |name: &str, o: &SolveOptions| {
        let copy = dir.path().join(name);
        copy_dir(&run, &copy);
        let rep = run_solve(&copy, o);
        (read_u(&copy), rep, copy)
    };
    let base = SolveOptions {
        checkpoint_every: 0.0,
        ..SolveOptions::default()
    };
    let no_stages = DeepenOptions {
        first: 0.0,
        ..DeepenOptions::default()
    };
    // The reference: no stages, the polish over every value below 1e-6 from zero, run
    // to a change of 1e-13 of themselves per sweep.
    let reference = SolveOptions {
        deepen: no_stages,
        polish: PolishOptions {
            rel_change: 1e-13,
            max_sweeps: 1_000_000,
            ..PolishOptions::default()
        },
        ..base.clone()
    };
    let (u_ref, rep_ref, run) = solve_with("ref.harmap", &reference);
    let (u, rep, _) = solve_with("staged.harmap", &base);
    let (_, labels) = read_labels(&run);
    let (worst, deep) = largest_relative_difference(&u, &u_ref, &labels);
    eprintln!(
        "cactus10k 64: {deep} values below 1e-11; stages {:?}; polish {} voxels {} sweeps (reference {} sweeps); largest relative difference {worst:.2e}",
        rep.deepen.stages, rep.polish.voxels, rep.polish.sweeps, rep_ref.polish.sweeps
    );
    assert!(deep >= 50, "{deep}: the case has too few tiny values");
    assert!(rep.deepen.stages.len() >= 3, "{:?}", rep.deepen);
    assert!(worst < 1e-4, "{worst}");
    assert_eq!(rep.polish.negative[1], 0);
    // Without the stages, the polish below their reach alone leaves the values
    // between 1e-26 and 1e-6 as the solve's absolute error left them.
    let without = SolveOptions {
        deepen: no_stages,
        polish: PolishOptions {
            threshold: 1e-26,
            ..PolishOptions::default()
        },
        ..base.clone()
    };
    let (u_bad, _, _) = solve_with("without.harmap", &without);
    let (bad, _) = largest_relative_difference(&u_bad, &u_ref, &labels);
    assert!(bad > 0.1, "{bad}: the unstaged solve is already accurate");
}

/// The stages on the tiny regions give the same bytes of u for any thread count and
/// budget (a mesh run: the finest level goes block by block either way).
#[test]
fn tiny_regions_give_the_same_bytes_for_any_thread_count_and_budget() {
    let dir = tempfile::tempdir().unwrap();
    let mut outs = Vec::new();
    for (i, (threads, mem)) in [(1, "1GiB"), (2, "1GiB"), (2, "40MiB")]
        .into_iter()
        .enumerate()
    {
        let run = starfish(dir.path(), &format!("s{i}.harmap"), 48);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let o = SolveOptions {
            mem: mem.parse().unwrap(),
            checkpoint_every: 0.0,
            ..SolveOptions::default()
        };
        let rep = pool.install(|| run_solve(&run, &o));
        assert!(!rep.deepen.stages.is_empty(), "{:?}", rep.deepen);
        if mem == "40MiB" {
            eprintln!("40MiB: in memory {:?}", rep.in_memory);
        }
        let bits: Vec<u64> = read_u(&run).iter().map(|v| v.to_bits()).collect();
        outs.push((rep.deepen, bits));
    }
    assert_eq!(outs[0], outs[1], "1 vs 2 threads");
    assert_eq!(outs[1], outs[2], "in memory vs memory-mapped scratch");
}

/// A copy of the run directory `from` at `to`.
fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let dst = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &dst);
        } else {
            std::fs::copy(e.path(), &dst).unwrap();
        }
    }
}
