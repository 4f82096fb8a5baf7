//! The sub-voxel boundary of mesh and molecule runs: the crossings the voxelizer stores
//! (`cuts`) against the exact sphere, and the solve's second-order accuracy on
//! concentric spheres built from a mesh and from one atom (the label-volume ball keeps
//! the staircase: tests/solve.rs).

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use harmap::grid::BlockStore;
use harmap::input::InputOptions;
use harmap::input::TriMesh;
use harmap::math::Vec3;
use harmap::pipeline::{voxelize_new_run, Source};
use harmap::progress::Silent;
use harmap::run::RunDir;
use harmap::solve::driver::{Method, StopReason};
use harmap::solve::{solve, SolveOptions};
use harmap::voxelize::cuts::{arm, LEVELS};
use harmap::voxelize::labels::{BOUNDARY, CENTER, INTERIOR, LAYER1};
use harmap::voxelize::spheres::MolSurface;
use harmap::voxelize::VoxelizeOptions;

use crate::common::read_labels;

/// The icosphere of `level` subdivisions of the icosahedron, radius `r` about the origin,
/// outward normals.
fn icosphere(r: f64, level: usize) -> TriMesh {
    let p = f64::midpoint(1.0, 5f64.sqrt());
    let mut v: Vec<Vec3> = [
        (-1.0, p, 0.0),
        (1.0, p, 0.0),
        (-1.0, -p, 0.0),
        (1.0, -p, 0.0),
        (0.0, -1.0, p),
        (0.0, 1.0, p),
        (0.0, -1.0, -p),
        (0.0, 1.0, -p),
        (p, 0.0, -1.0),
        (p, 0.0, 1.0),
        (-p, 0.0, -1.0),
        (-p, 0.0, 1.0),
    ]
    .iter()
    .map(|&(x, y, z)| Vec3::new(x, y, z).normalize())
    .collect();
    let mut t: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..level {
        let mut mid = std::collections::HashMap::new();
        let mut next = Vec::with_capacity(4 * t.len());
        for f in &t {
            let m = [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])].map(|(a, b)| {
                *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                    v.push(((v[a as usize] + v[b as usize]) * 0.5).normalize());
                    (v.len() - 1) as u32
                })
            });
            next.extend([
                [f[0], m[0], m[2]],
                [f[1], m[1], m[0]],
                [f[2], m[2], m[1]],
                [m[0], m[1], m[2]],
            ]);
        }
        t = next;
    }
    TriMesh {
        vertices: v.iter().map(|&p| p * r).collect(),
        triangles: t,
    }
}

/// A mesh run of concentric spheres about `n` voxels across (the standard problem's N):
/// the icosphere of radius 1 on an odd grid, so that its center is a voxel center, with
/// the center ball of radius `R / 4.5` (0.1 N for R = 0.45 N) there. Returns the run,
/// R and the sink radius in voxels.
fn concentric(dir: &Path, n: u64, level: usize, chunk: u64) -> (PathBuf, f64, f64) {
    let mesh = icosphere(1.0, level);
    // The icosphere reaches the poles: its extent is 2 along every axis. Across it
    // `odd - 1/2` voxels round up to an odd count, and the padding keeps it odd.
    let odd = {
        let k = (0.9 * n as f64).ceil() as u64;
        k + 1 - k % 2
    };
    let h = 2.0 / (odd as f64 - 0.5);
    let big_r = 1.0 / h;
    let r0 = big_r / 4.5;
    let opts = VoxelizeOptions {
        spacing: Some(h),
        center: Some([0.0; 3]),
        center_radius: r0,
        chunk,
        ..VoxelizeOptions::default()
    };
    let out = dir.join(format!("spheres{n}-{chunk}.harmap"));
    voxelize_new_run(
        &Source::Mesh(&mesh, "icosphere"),
        &opts,
        &out,
        true,
        &Silent,
    )
    .unwrap();
    (out, big_r, r0)
}

fn read_all<T: harmap::grid::Scalar>(run: &Path, name: &str, outside: T) -> Vec<T> {
    let r = RunDir::open(run).unwrap();
    let s = r.open_image::<T>(name).unwrap();
    let shape = s.spec().shape.map(|c| c as usize);
    s.read_region([0, 0, 0], shape, outside).unwrap().data
}

/// RMS and largest error of phi against `(1/r0 - 1/r) / (1/r0 - 1/R)` over the solid
/// voxels outside the center ball, and the count.
fn errors(run: &Path, big_r: f64, r0: f64) -> (f64, f64, usize) {
    let (spec, labels) = read_labels(run);
    let phi = read_all::<f64>(run, "phi", f64::NAN);
    let [nz, ny, nx] = spec.shape.map(|c| c as usize);
    let c = [(nz - 1) / 2, (ny - 1) / 2, (nx - 1) / 2];
    assert_eq!(labels[(c[0] * ny + c[1]) * nx + c[2]], CENTER);
    let (mut sq, mut max, mut cnt) = (0.0, 0.0f64, 0usize);
    for (i, &l) in labels.iter().enumerate() {
        if l != INTERIOR && l != BOUNDARY {
            continue;
        }
        let g = [i / (ny * nx), (i / nx) % ny, i % nx];
        let r = (0..3)
            .map(|a| (g[a] as f64 - c[a] as f64).powi(2))
            .sum::<f64>()
            .sqrt();
        let exact = (1.0 / r0 - 1.0 / r) / (1.0 / r0 - 1.0 / big_r);
        let e = phi[i] - exact;
        sq += e * e;
        max = max.max(e.abs());
        cnt += 1;
    }
    ((sq / cnt as f64).sqrt(), max, cnt)
}

fn solve_run(run: &Path, method: Method) {
    let opts = SolveOptions {
        method,
        rtol: 1e-10,
        max_iter: 200_000,
        ..SolveOptions::default()
    };
    let rep = solve(
        &RunDir::open(run).unwrap(),
        &opts,
        &AtomicBool::new(false),
        &Silent,
    )
    .unwrap();
    assert_eq!(rep.stopped_by, StopReason::Residual, "{rep:?}");
}

#[test]
fn mesh_crossings_are_the_sphere_within_the_facets_sag() {
    let dir = tempfile::tempdir().unwrap();
    let level = 4;
    let (run, big_r, r0) = concentric(dir.path(), 24, level, 16);
    let (spec, labels) = read_labels(&run);
    let cuts = read_all::<u64>(&run, "cuts", 0);
    let [nz, ny, nx] = spec.shape.map(|c| c as usize);
    let c = [(nz - 1) / 2, (ny - 1) / 2, (nx - 1) / 2].map(|v| v as f64);
    // Facets of the icosphere lie inside its sphere by at most R minus the smallest
    // distance of a facet's plane from the center; an arm's fraction is rounded to
    // 1/1023.
    let m = icosphere(1.0, level);
    let nearest_plane = m
        .triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| m.vertices[i as usize]);
            (b - a).cross(c - a).normalize().dot(a).abs()
        })
        .fold(f64::INFINITY, f64::min);
    let tol = big_r * (1.0 - nearest_plane) + 0.5 / LEVELS + 1e-9;
    let (mut outer, mut inner) = (0, 0);
    for (i, &l) in labels.iter().enumerate() {
        let g = [i / (ny * nx), (i / nx) % ny, i % nx];
        let p = cuts[i];
        if l != INTERIOR && l != BOUNDARY {
            assert_eq!(p, 0, "a fixed voxel {g:?} has arms");
            continue;
        }
        for a in 0..3 {
            for up in [false, true] {
                let k = 2 * (2 - a) + usize::from(up);
                let mut h = g;
                h[a] = if up { h[a] + 1 } else { h[a] - 1 };
                let nl = labels[(h[0] * ny + h[1]) * nx + h[2]];
                let t = arm(p, k);
                // Where along the arm |x - c| = radius, nearest to the voxel.
                let d: Vec<f64> = (0..3).map(|b| g[b] as f64 - c[b]).collect();
                let rest: f64 = (0..3).filter(|&b| b != a).map(|b| d[b] * d[b]).sum();
                let dir = if up { 1.0 } else { -1.0 };
                let along = |radius: f64| {
                    let s = (radius * radius - rest).max(0.0).sqrt();
                    // Roots d_a + dir t = +-s; the smallest t >= 0.
                    [s - d[a], -s - d[a]]
                        .iter()
                        .map(|&x| x * dir)
                        .filter(|&t| t >= -1e-9)
                        .fold(f64::INFINITY, f64::min)
                };
                if nl == CENTER {
                    inner += 1;
                    let want = along(r0);
                    assert!(
                        (t - want).abs() <= 0.5 / LEVELS + 1e-9,
                        "{g:?} arm {k}: {t} vs {want}"
                    );
                } else if nl == 0 || nl >= LAYER1 {
                    outer += 1;
                    // The crossing lies on a facet: within the sag inside the sphere,
                    // radially (along a grazing arm the distance along it is larger).
                    let mut x = d.clone();
                    x[a] += dir * t;
                    let r = x.iter().map(|v| v * v).sum::<f64>().sqrt();
                    assert!(
                        r <= big_r + 0.5 / LEVELS + 1e-9 && r >= big_r - tol,
                        "{g:?} arm {k}: {t} puts the crossing at radius {r}, the sphere is {big_r} (tolerance {tol})"
                    );
                } else {
                    assert!(t == 0.0, "{g:?} arm {k} to an unknown is cut");
                }
            }
        }
    }
    assert!(outer > 1000 && inner > 50, "{outer} {inner}");
}

/// Subdivisions of the icosphere for the accuracy tests: its facets lie within 0.001
/// voxel of the sphere at N = 129 (the depth of a facet, about 0.24 R / 4^level,
/// enters phi as the gradient there times it: 5e-6 here).
const FINE: usize = 7;

/// Solve the mesh spheres at N and return the RMS and largest error.
fn spheres_error(dir: &Path, n: u64) -> (f64, f64, f64) {
    let (run, big_r, r0) = concentric(dir, n, FINE, 32);
    solve_run(&run, Method::Multigrid);
    let (rms, max, _) = errors(&run, big_r, r0);
    (big_r / 0.45, rms, max)
}

#[test]
fn concentric_mesh_spheres_are_second_order() {
    // phi(r) = (1/r0 - 1/r) / (1/r0 - 1/R) between the center ball (r0 = 0.1 N) and the
    // icosphere (R = 0.45 N). With the boundary where the mesh is, the error over the
    // unknowns falls about four times per doubling of N.
    let dir = tempfile::tempdir().unwrap();
    let a = spheres_error(dir.path(), 33);
    let b = spheres_error(dir.path(), 65);
    // N is not doubled exactly (the grid is odd): the fall per doubling is
    // (e_a / e_b)^(ln 2 / ln(N_b / N_a)).
    let per_doubling = (a.1 / b.1).powf(2f64.ln() / (b.0 / a.0).ln());
    eprintln!("N, RMS, max: {a:?} {b:?}; RMS falls {per_doubling:.2}x per doubling");
    assert!(per_doubling >= 3.5, "{a:?} {b:?}: {per_doubling}");
    assert!(a.1 < 0.01 && b.1 < 0.003, "{a:?} {b:?}");
}

/// A molecule run of concentric spheres about `n` voxels across: one atom of radius 10
/// at the origin (an `.xyzr` file) whose `surface` is the outer sphere (the vdW ball and
/// the SES are the atom's ball, the SAS its ball grown by the probe of 1.4), on an odd
/// grid about it, with the center ball of `R / 4.5` at its center. Returns the run, R
/// and the sink radius in voxels.
fn one_atom(dir: &Path, n: u64, surface: MolSurface) -> (PathBuf, f64, f64) {
    let xyzr = dir.join("one-atom.xyzr");
    std::fs::write(&xyzr, "0 0 0 10\n").unwrap();
    let probe = 1.4;
    // The grid spans the atom's ball grown by the probe (SAS, SES) or its ball (vdW).
    let reach = if surface == MolSurface::Vdw {
        10.0
    } else {
        10.0 + probe
    };
    let outer = if surface == MolSurface::Sas {
        10.0 + probe
    } else {
        10.0
    };
    let odd = {
        let k = (0.9 * n as f64 * reach / outer).ceil() as u64;
        k + 1 - k % 2
    };
    let h = 2.0 * reach / (odd as f64 - 0.5);
    let big_r = outer / h;
    let r0 = big_r / 4.5;
    let opts = VoxelizeOptions {
        spacing: Some(h),
        center: Some([0.0; 3]),
        center_radius: r0,
        chunk: 32,
        surface,
        probe,
        ..VoxelizeOptions::default()
    };
    let out = dir.join(format!("atom{n}-{surface:?}.harmap"));
    let iopts = InputOptions::default();
    voxelize_new_run(&Source::File(&xyzr, &iopts), &opts, &out, true, &Silent).unwrap();
    assert!(out.join("cuts").exists(), "a molecule run has cuts");
    (out, big_r, r0)
}

/// Solve the one-atom spheres at N and return N, the RMS and the largest error.
fn atom_error(dir: &Path, n: u64, surface: MolSurface) -> (f64, f64, f64) {
    let (run, big_r, r0) = one_atom(dir, n, surface);
    solve_run(&run, Method::Multigrid);
    let (rms, max, _) = errors(&run, big_r, r0);
    (big_r / 0.45, rms, max)
}

#[test]
fn concentric_spheres_from_one_atom_are_second_order() {
    // The same analytic phi as the mesh spheres, the outer sphere now the molecular
    // surface of one atom: exact chords for the vdW and SAS balls, the probe balls'
    // first contact (sphere tracing over the sampled probe centers) for the SES.
    let dir = tempfile::tempdir().unwrap();
    for surface in [MolSurface::Vdw, MolSurface::Sas, MolSurface::Ses] {
        let a = atom_error(dir.path(), 33, surface);
        let b = atom_error(dir.path(), 65, surface);
        let per_doubling = (a.1 / b.1).powf(2f64.ln() / (b.0 / a.0).ln());
        eprintln!(
            "{surface:?}: N, RMS, max: {a:?} {b:?}; RMS falls {per_doubling:.2}x per doubling"
        );
        assert!(
            per_doubling >= 3.5,
            "{surface:?}: {a:?} {b:?}: {per_doubling}"
        );
        assert!(a.1 < 0.01 && b.1 < 0.003, "{surface:?}: {a:?} {b:?}");
    }
}

/// The same run solved on the staircase (its `cuts` removed): phi = 1 on the boundary
/// voxels, as label volumes are solved.
fn staircase_error(dir: &Path, n: u64) -> (f64, f64, f64) {
    let (run, big_r, r0) = concentric(dir, n, FINE, 32);
    std::fs::remove_dir_all(run.join("cuts")).unwrap();
    solve_run(&run, Method::Multigrid);
    let (rms, max, _) = errors(&run, big_r, r0);
    (big_r / 0.45, rms, max)
}

#[test]
#[ignore = "N = 129: a minute of solve; run by hand for docs/correctness.md"]
fn concentric_mesh_spheres_at_129() {
    let dir = tempfile::tempdir().unwrap();
    for n in [33, 65, 129] {
        eprintln!(
            "staircase N, RMS, max: {:?}",
            staircase_error(dir.path(), n)
        );
    }
    let a = spheres_error(dir.path(), 65);
    let b = spheres_error(dir.path(), 129);
    let per_doubling = (a.1 / b.1).powf(2f64.ln() / (b.0 / a.0).ln());
    eprintln!("N, RMS, max: {a:?} {b:?}; RMS falls {per_doubling:.2}x per doubling");
    assert!(per_doubling >= 3.5 && b.1 < 0.002, "{a:?} {b:?}");
}

fn phi_bits(run: &Path) -> Vec<u64> {
    read_all::<f64>(run, "phi", f64::NAN)
        .iter()
        .map(|v| v.to_bits())
        .collect()
}

#[test]
fn mesh_runs_are_the_same_bytes_for_any_thread_count_and_budget() {
    let dir = tempfile::tempdir().unwrap();
    let mut outs = Vec::new();
    for (threads, mem) in &[(1, "1GiB"), (2, "1GiB"), (2, "32MiB")] {
        let (run, _, _) = concentric(dir.path(), 80, 4, 16);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(*threads)
            .build()
            .unwrap();
        let opts = SolveOptions {
            rtol: 1e-8,
            mem: mem.parse().unwrap(),
            ..SolveOptions::default()
        };
        let rep = pool
            .install(|| {
                solve(
                    &RunDir::open(&run).unwrap(),
                    &opts,
                    &AtomicBool::new(false),
                    &Silent,
                )
            })
            .unwrap();
        if *mem == "32MiB" {
            assert!(!rep.in_memory[0], "the small budget should put phi on disk");
        }
        outs.push((rep.iterations, rep.residual_history, phi_bits(&run)));
    }
    assert_eq!(outs[0], outs[1], "1 vs 2 threads");
    assert_eq!(outs[1], outs[2], "in memory vs memory-mapped scratch");
}

#[test]
fn mesh_runs_solve_alike_with_every_method_and_resume_to_the_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let (run, big_r, r0) = concentric(dir.path(), 20, 4, 8);
    let mut answers = Vec::new();
    for m in [Method::Multigrid, Method::Sor, Method::Jacobi] {
        solve_run(&run, m);
        answers.push((m, read_all::<f64>(&run, "phi", f64::NAN)));
    }
    let (_, labels) = read_labels(&run);
    for (m, phi) in &answers[1..] {
        let d = phi
            .iter()
            .zip(&answers[0].1)
            .zip(&labels)
            .filter(|(_, &l)| l == INTERIOR || l == BOUNDARY)
            .map(|((a, b), _)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(d < 1e-7, "{m:?} differs from multigrid by {d}");
    }
    // The boundary voxels are unknowns now: phi < 1 there, and in (0, 1) throughout
    // (the maximum principle).
    let phi = &answers[0].1;
    for (i, &l) in labels.iter().enumerate() {
        if l == BOUNDARY || l == INTERIOR {
            assert!(phi[i] > 0.0 && phi[i] < 1.0, "phi {} at {i} ({l})", phi[i]);
        }
    }
    let (rms, _, _) = errors(&run, big_r, r0);
    assert!(rms < 0.01, "{rms}");

    // Interrupted at once (the state is checkpointed), then resumed: the same bytes as
    // the solve straight through.
    let opts = SolveOptions {
        method: Method::Jacobi,
        rtol: 1e-10,
        max_iter: 200_000,
        ..SolveOptions::default()
    };
    let r = RunDir::open(&run).unwrap();
    solve(&r, &opts, &AtomicBool::new(false), &Silent).unwrap();
    let straight = phi_bits(&run);
    assert!(solve(&r, &opts, &AtomicBool::new(true), &Silent).is_err());
    let resumed = SolveOptions {
        resume: true,
        ..opts
    };
    solve(&r, &resumed, &AtomicBool::new(false), &Silent).unwrap();
    assert!(phi_bits(&run) == straight, "resumed phi differs");
}
